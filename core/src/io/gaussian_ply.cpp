#include "fslam/core/io/gaussian_ply.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"

namespace fslam::core {
namespace {

static_assert(std::numeric_limits<float>::is_iec559 && sizeof(float) == 4,
              "PLY float is IEEE-754 binary32");

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
constexpr bool kHostBigEndian = true;
#else
constexpr bool kHostBigEndian = false;
#endif

// A header longer than this is not a Gaussian PLY (ours is ~2 KB at degree 3, D = 16).
constexpr std::size_t kMaxHeaderBytes = 1 << 20;

float load_le_float(const char* bytes) {
  std::uint32_t u;
  std::memcpy(&u, bytes, 4);
  if (kHostBigEndian) u = __builtin_bswap32(u);
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}

void store_le_float(float f, char* bytes) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  if (kHostBigEndian) u = __builtin_bswap32(u);
  std::memcpy(bytes, &u, 4);
}

// Property names in the order we write them: the standard 3DGS ones, then ours.
std::vector<std::string> property_names(int sh_coeffs, int feature_dim) {
  std::vector<std::string> names = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (int j = 0; j < 3 * (sh_coeffs - 1); ++j) names.push_back("f_rest_" + std::to_string(j));
  for (const char* name :
       {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    names.push_back(name);
  for (int j = 0; j < feature_dim; ++j) names.push_back("feat_" + std::to_string(j));
  names.push_back("filter_3d");
  return names;
}

// ---- header ----------------------------------------------------------------------------------

struct PlyProperty {
  std::string name;
  std::string type;        // as written in the header
  std::size_t size = 0;    // bytes
  std::size_t offset = 0;  // bytes from the start of a binary row
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::size_t stride = 0;  // bytes per binary row
  std::vector<PlyProperty> properties;
};

struct PlyHeader {
  bool ascii = false;
  std::vector<PlyElement> elements;
  std::uint64_t data_offset = 0;  // bytes from the file start to the first data byte
};

// Byte size of a PLY scalar type, 0 for an unknown name.
std::size_t scalar_size(const std::string& type) {
  static const std::pair<const char*, std::size_t> kTypes[] = {
      {"char", 1},   {"int8", 1},    {"uchar", 1},  {"uint8", 1},  {"short", 2}, {"int16", 2},
      {"ushort", 2}, {"uint16", 2},  {"int", 4},    {"int32", 4},  {"uint", 4},  {"uint32", 4},
      {"float", 4},  {"float32", 4}, {"double", 8}, {"float64", 8}};
  for (const auto& [name, size] : kTypes) {
    if (type == name) return size;
  }
  return 0;
}

// One header line without its '\n' (or "\r\n"); false at end of file or past `max_bytes`.
bool read_line(std::istream& in, std::string* line, std::size_t max_bytes) {
  line->clear();
  char c;
  while (in.get(c)) {
    if (c == '\n') {
      if (!line->empty() && line->back() == '\r') line->pop_back();
      return true;
    }
    if (line->size() >= max_bytes) return false;
    line->push_back(c);
  }
  return false;
}

bool parse_count(const std::string& text, std::uint64_t* value) {
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return ec == std::errc() && ptr == end;
}

bool read_header(std::istream& in, const std::string& path, PlyHeader* header, std::string* why) {
  std::string line;
  if (!read_line(in, &line, 16) || line != "ply")
    return fail(why, path + ": not a PLY file (bad magic: first line must be 'ply')");
  bool have_format = false;
  std::size_t header_bytes = line.size();
  while (true) {
    if (!read_line(in, &line, kMaxHeaderBytes) ||
        (header_bytes += line.size() + 1) > kMaxHeaderBytes)
      return fail(why, path + ": PLY header has no end_header line");
    std::istringstream fields(line);
    std::vector<std::string> tokens;
    for (std::string token; fields >> token;) tokens.push_back(token);
    if (tokens.empty() || tokens[0] == "comment" || tokens[0] == "obj_info") continue;
    const std::string& keyword = tokens[0];
    if (keyword == "end_header") break;
    if (keyword == "format") {
      if (tokens.size() != 3) return fail(why, path + ": bad format line '" + line + "'");
      if (tokens[1] == "binary_big_endian")
        return fail(why, path +
                             ": big-endian PLY is not supported (use binary_little_endian "
                             "or ascii)");
      if (tokens[1] != "binary_little_endian" && tokens[1] != "ascii")
        return fail(why, path + ": unknown PLY format '" + tokens[1] + "'");
      if (tokens[2] != "1.0")
        return fail(why, path + ": unsupported PLY version '" + tokens[2] + "'");
      header->ascii = tokens[1] == "ascii";
      have_format = true;
    } else if (keyword == "element") {
      PlyElement element;
      if (tokens.size() != 3 || !parse_count(tokens[2], &element.count))
        return fail(why, path + ": bad element line '" + line + "'");
      element.name = tokens[1];
      header->elements.push_back(std::move(element));
    } else if (keyword == "property") {
      if (header->elements.empty())
        return fail(why, path + ": property before any element: '" + line + "'");
      PlyElement& element = header->elements.back();
      if (tokens.size() >= 2 && tokens[1] == "list")
        return fail(why, path + ": list property in element '" + element.name +
                             "' is not supported: '" + line + "'");
      if (tokens.size() != 3) return fail(why, path + ": bad property line '" + line + "'");
      PlyProperty property{tokens[2], tokens[1], scalar_size(tokens[1]), element.stride};
      if (property.size == 0)
        return fail(
            why, path + ": unknown type '" + tokens[1] + "' of property '" + property.name + "'");
      for (const PlyProperty& other : element.properties) {
        if (other.name == property.name)
          return fail(why, path + ": property '" + property.name + "' appears twice");
      }
      element.stride += property.size;
      element.properties.push_back(std::move(property));
    } else {
      return fail(why, path + ": unexpected PLY header line '" + line + "'");
    }
  }
  if (!have_format) return fail(why, path + ": PLY header has no format line");
  header->data_offset = static_cast<std::uint64_t>(in.tellg());
  return true;
}

// ---- where each vertex property goes ---------------------------------------------------------

struct Target {
  std::vector<float>* array = nullptr;  // nullptr: skipped property
  std::size_t row = 0;                  // values per Gaussian in *array
  std::size_t col = 0;
};

// `name` == prefix + a decimal index written the canonical way; the index in *index.
bool indexed_name(const std::string& name, const std::string& prefix, int* index) {
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return false;
  const std::string digits = name.substr(prefix.size());
  auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), *index);
  return ec == std::errc() && ptr == digits.data() + digits.size() && *index >= 0 &&
         std::to_string(*index) == digits;
}

// Checks that `indices` (property indices by their numeric suffix) run 0..M-1 without gaps.
bool contiguous(std::vector<std::pair<int, std::size_t>>* indices, const std::string& path,
                const std::string& prefix, std::string* why) {
  std::sort(indices->begin(), indices->end());
  for (std::size_t j = 0; j < indices->size(); ++j) {
    if ((*indices)[j].first != static_cast<int>(j))
      return fail(why, path + ": " + prefix + "* properties are not contiguous from 0 (" + prefix +
                           std::to_string(j) + " missing)");
  }
  return true;
}

// Sets `map`'s SH degree and feature dimension from the vertex properties and fills `targets`
// (one per property); allocates nothing.
bool plan_vertex(const PlyElement& vertex, const std::string& path, GaussianMap* map,
                 std::vector<Target>* targets, std::string* why) {
  const char* kRequired[] = {"x",      "y",       "z",       "f_dc_0",  "f_dc_1",
                             "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                             "rot_0",  "rot_1",   "rot_2",   "rot_3"};
  std::vector<std::pair<int, std::size_t>> rest, feat;  // (suffix, property index)
  std::size_t required_at[std::size(kRequired)];
  std::fill(std::begin(required_at), std::end(required_at), vertex.properties.size());
  std::size_t filter_at = vertex.properties.size();
  std::vector<bool> needed(vertex.properties.size(), false);
  for (std::size_t p = 0; p < vertex.properties.size(); ++p) {
    const std::string& name = vertex.properties[p].name;
    int index = 0;
    if (indexed_name(name, "f_rest_", &index)) {
      rest.emplace_back(index, p);
    } else if (indexed_name(name, "feat_", &index)) {
      feat.emplace_back(index, p);
    } else if (name == "filter_3d") {
      filter_at = p;
    } else {
      const auto* it = std::find(std::begin(kRequired), std::end(kRequired), name);
      if (it == std::end(kRequired)) continue;
      required_at[it - std::begin(kRequired)] = p;
    }
    needed[p] = true;
  }
  for (std::size_t r = 0; r < std::size(kRequired); ++r) {
    if (required_at[r] == vertex.properties.size())
      return fail(why, path + ": missing required vertex property '" + kRequired[r] + "'");
  }
  for (std::size_t p = 0; p < vertex.properties.size(); ++p) {
    const PlyProperty& property = vertex.properties[p];
    if (needed[p] && property.type != "float" && property.type != "float32")
      return fail(why, path + ": vertex property '" + property.name + "' is " + property.type +
                           ", expected float");
  }
  if (!contiguous(&rest, path, "f_rest_", why) || !contiguous(&feat, path, "feat_", why))
    return false;
  int degree = -1;
  for (int d = 0; d <= kMaxShDegree; ++d) {
    if (rest.size() == static_cast<std::size_t>(3 * (sh_coefficients(d) - 1))) degree = d;
  }
  if (degree < 0)
    return fail(why, path + ": found " + std::to_string(rest.size()) +
                         " f_rest_* properties, expected 0, 9, 24 or 45 (SH degree 0-3)");

  // Targets point at the arrays, not their data, so sizing them later (once the file size has
  // been checked against the header) keeps them valid.
  const std::size_t k = static_cast<std::size_t>(sh_coefficients(degree));
  map->clear();
  map->sh_degree = degree;
  map->feature_dim = static_cast<int>(feat.size());
  targets->assign(vertex.properties.size(), Target{});
  const Target required_targets[] = {  // in kRequired order
      {&map->means, 3, 0},          {&map->means, 3, 1},      {&map->means, 3, 2},
      {&map->sh, 3 * k, 0},         {&map->sh, 3 * k, 1},     {&map->sh, 3 * k, 2},
      {&map->opacity_logits, 1, 0}, {&map->log_scales, 3, 0}, {&map->log_scales, 3, 1},
      {&map->log_scales, 3, 2},     {&map->rotations, 4, 0},  {&map->rotations, 4, 1},
      {&map->rotations, 4, 2},      {&map->rotations, 4, 3}};
  for (std::size_t r = 0; r < std::size(kRequired); ++r)
    (*targets)[required_at[r]] = required_targets[r];
  for (const auto& [j, p] : rest) {  // channel-major: f_rest_{c (K-1) + k-1} = sh[i, k, c]
    const std::size_t c = j / (k - 1), coeff = j % (k - 1) + 1;
    (*targets)[p] = {&map->sh, 3 * k, 3 * coeff + c};
  }
  for (const auto& [j, p] : feat) (*targets)[p] = {&map->features, feat.size(), std::size_t(j)};
  if (filter_at != vertex.properties.size()) (*targets)[filter_at] = {&map->filter_3d, 1, 0};
  return true;
}

// ---- data ------------------------------------------------------------------------------------

// Checks the header's element counts against the bytes after it before anything is allocated:
// binary elements are fixed-size, so the header fixes the file size exactly; an ASCII value takes
// at least two bytes (a digit and a separator), which bounds what the header may claim.
bool check_data_size(const PlyHeader& header, std::size_t vertex_element, std::uint64_t file_size,
                     const std::string& path, std::string* why) {
  const std::uint64_t available = file_size - header.data_offset;
  const std::uint64_t capacity = header.ascii ? (available + 1) / 2 : available;
  std::uint64_t expected = 0;  // bytes (binary) or values (ASCII)
  for (const PlyElement& element : header.elements) {
    const std::uint64_t row = header.ascii ? element.properties.size() : element.stride;
    if (row > 0 && element.count > (capacity - expected) / row)
      return fail(why, path + ": truncated: element '" + element.name + "' declares " +
                           std::to_string(element.count) + " rows, but only " +
                           std::to_string(available) + " bytes follow the header");
    expected += element.count * row;
  }
  if (!header.ascii && available != expected)
    return fail(why, path + ": vertex count " +
                         std::to_string(header.elements[vertex_element].count) +
                         " is inconsistent with the file size: the header declares " +
                         std::to_string(expected) + " data bytes, the file holds " +
                         std::to_string(available));
  return true;
}

void allocate(std::size_t n, GaussianMap* map) {
  map->means.resize(3 * n);
  map->rotations.resize(4 * n);
  map->log_scales.resize(3 * n);
  map->opacity_logits.resize(n);
  map->sh.resize(static_cast<std::size_t>(map->sh_per_gaussian()) * n);
  map->features.resize(static_cast<std::size_t>(map->feature_dim) * n);
  map->filter_3d.assign(n, 0.0f);
}

bool non_finite(const std::string& path, std::size_t vertex, const PlyProperty& property,
                const std::string& value, std::string* why) {
  return fail(why, path + ": vertex " + std::to_string(vertex) + " property '" + property.name +
                       "' is not finite (" + value + ")");
}

// Reads the vertex rows; the size has been checked, so a short read is a file changed under us.
bool read_binary(std::istream& in, const std::string& path, const PlyHeader& header,
                 std::size_t vertex_element, const std::vector<Target>& targets, std::string* why) {
  std::uint64_t vertex_start = header.data_offset;
  for (std::size_t e = 0; e < vertex_element; ++e)
    vertex_start += header.elements[e].count * header.elements[e].stride;
  const PlyElement& vertex = header.elements[vertex_element];
  in.seekg(static_cast<std::streamoff>(vertex_start));
  const std::size_t chunk_rows = std::max<std::size_t>(1, (std::size_t{1} << 20) / vertex.stride);
  std::vector<char> buffer(chunk_rows * vertex.stride);
  for (std::size_t begin = 0; begin < vertex.count; begin += chunk_rows) {
    const std::size_t rows = std::min<std::size_t>(chunk_rows, vertex.count - begin);
    if (!in.read(buffer.data(), static_cast<std::streamsize>(rows * vertex.stride)))
      return fail(why, path + ": truncated: read failed at vertex " + std::to_string(begin));
    for (std::size_t r = 0; r < rows; ++r) {
      const char* row = buffer.data() + r * vertex.stride;
      for (std::size_t p = 0; p < targets.size(); ++p) {
        const Target& t = targets[p];
        if (t.array == nullptr) continue;
        const float value = load_le_float(row + vertex.properties[p].offset);
        if (!std::isfinite(value))
          return non_finite(path, begin + r, vertex.properties[p], std::to_string(value), why);
        (*t.array)[(begin + r) * t.row + t.col] = value;
      }
    }
  }
  return true;
}

// Parses one ASCII value as float; false with *non_finite set for inf, nan and out-of-range.
bool parse_float(const std::string& token, float* value, bool* non_finite) {
  const char* end = token.data() + token.size();
  auto [ptr, ec] = std::from_chars(token.data(), end, *value);
  if (ec == std::errc::result_out_of_range) {  // overflow, or underflow to a float denormal/zero
    double wide = 0.0;
    auto [wide_ptr, wide_ec] = std::from_chars(token.data(), end, wide);
    if (wide_ec == std::errc() && wide_ptr == end &&
        std::abs(wide) <= std::numeric_limits<float>::max()) {
      *value = static_cast<float>(wide);
      return true;
    }
    *non_finite = true;
    return false;
  }
  if (ec != std::errc() || ptr != end) return false;
  *non_finite = !std::isfinite(*value);
  return !*non_finite;
}

bool read_ascii(std::istream& in, const std::string& path, const PlyHeader& header,
                std::size_t vertex_element, const std::vector<Target>& targets, std::string* why) {
  const PlyElement& vertex = header.elements[vertex_element];
  auto truncated = [&](const std::string& where) {
    return fail(why, path + ": truncated: the data ends in " + where + " (header declares " +
                         std::to_string(vertex.count) + " vertices)");
  };
  auto skip_element = [&](const PlyElement& element) {
    std::string token;
    for (std::uint64_t v = 0; v < element.count * element.properties.size(); ++v) {
      if (!(in >> token)) return truncated("element '" + element.name + "'");
    }
    return true;
  };
  for (std::size_t e = 0; e < vertex_element; ++e) {
    if (!skip_element(header.elements[e])) return false;
  }
  std::string token;
  for (std::size_t i = 0; i < vertex.count; ++i) {
    for (std::size_t p = 0; p < targets.size(); ++p) {
      if (!(in >> token)) return truncated("vertex " + std::to_string(i));
      const Target& t = targets[p];
      if (t.array == nullptr) continue;
      float value = 0.0f;
      bool infinite_or_nan = false;
      if (!parse_float(token, &value, &infinite_or_nan)) {
        if (infinite_or_nan) return non_finite(path, i, vertex.properties[p], token, why);
        return fail(why, path + ": vertex " + std::to_string(i) + " property '" +
                             vertex.properties[p].name + "': '" + token + "' is not a number");
      }
      (*t.array)[i * t.row + t.col] = value;
    }
  }
  for (std::size_t e = vertex_element + 1; e < header.elements.size(); ++e) {
    if (!skip_element(header.elements[e])) return false;
  }
  if (in >> token)
    return fail(why, path + ": vertex count " + std::to_string(vertex.count) +
                         " is inconsistent with the file size: data continues after the "
                         "declared elements ('" +
                         token + "')");
  return true;
}

}  // namespace

namespace {

std::string ply_header(std::size_t vertices, const std::vector<std::string>& names) {
  std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(vertices) + '\n';
  for (const std::string& name : names) header += "property float " + name + '\n';
  return header + "end_header\n";
}

}  // namespace

std::uint64_t gaussian_ply_bytes(const GaussianMap& map) {
  const std::vector<std::string> names = property_names(sh_coefficients(map.sh_degree), map.feature_dim);
  return ply_header(map.size(), names).size() + 4ull * names.size() * map.size();
}

bool write_gaussian_ply(const std::string& path, const GaussianMap& map, std::string* why) {
  std::string bad;
  if (!map.is_consistent(&bad))
    return fail(why, path + ": refusing to write an inconsistent map (" + bad + ")");
  const std::size_t n = map.size();
  const std::size_t k = static_cast<std::size_t>(sh_coefficients(map.sh_degree));
  const std::size_t d = static_cast<std::size_t>(map.feature_dim);
  const std::vector<std::string> names = property_names(static_cast<int>(k), map.feature_dim);

  FileWriter out;
  if (!out.open(path, why)) return false;
  out.write(ply_header(n, names));

  constexpr std::size_t kChunkRows = 4096;
  std::vector<char> buffer(kChunkRows * names.size() * 4);
  for (std::size_t begin = 0; begin < n; begin += kChunkRows) {
    const std::size_t end = std::min(n, begin + kChunkRows);
    char* dst = buffer.data();
    auto put = [&dst](float v) {
      store_le_float(v, dst);
      dst += 4;
    };
    for (std::size_t i = begin; i < end; ++i) {
      for (int a = 0; a < 3; ++a) put(map.means[3 * i + a]);
      for (int a = 0; a < 3; ++a) put(0.0f);        // normals: unused by 3DGS, kept for the layout
      const float* sh = map.sh.data() + 3 * k * i;  // [K, 3]
      for (int c = 0; c < 3; ++c) put(sh[c]);
      for (int c = 0; c < 3; ++c) {  // f_rest is channel-major
        for (std::size_t coeff = 1; coeff < k; ++coeff) put(sh[3 * coeff + c]);
      }
      put(map.opacity_logits[i]);
      for (int a = 0; a < 3; ++a) put(map.log_scales[3 * i + a]);
      for (int a = 0; a < 4; ++a) put(map.rotations[4 * i + a]);
      for (std::size_t j = 0; j < d; ++j) put(map.features[d * i + j]);
      put(map.filter_3d[i]);
    }
    if (!out.write(buffer.data(), static_cast<std::size_t>(dst - buffer.data()))) break;
  }
  return out.close(why);
}

bool read_gaussian_ply(const std::string& path, GaussianMap* map, std::string* why) {
  std::error_code ec;
  const std::uint64_t file_size = std::filesystem::file_size(path, ec);
  std::ifstream in(path, std::ios::binary);
  if (ec || !in) return fail(why, path + ": cannot open for reading");
  PlyHeader header;
  if (!read_header(in, path, &header, why)) return false;
  std::size_t vertex_element = header.elements.size();
  for (std::size_t e = header.elements.size(); e-- > 0;) {  // the first, should there be two
    if (header.elements[e].name == "vertex") vertex_element = e;
  }
  if (vertex_element == header.elements.size())
    return fail(why, path + ": PLY has no 'vertex' element");

  GaussianMap result;
  std::vector<Target> targets;
  if (!plan_vertex(header.elements[vertex_element], path, &result, &targets, why) ||
      !check_data_size(header, vertex_element, file_size, path, why))
    return false;
  allocate(header.elements[vertex_element].count, &result);
  const bool ok = header.ascii ? read_ascii(in, path, header, vertex_element, targets, why)
                               : read_binary(in, path, header, vertex_element, targets, why);
  if (!ok) return false;
  std::string bad;
  if (!result.is_consistent(&bad)) return fail(why, path + ": " + bad);
  *map = std::move(result);
  return true;
}

}  // namespace fslam::core
