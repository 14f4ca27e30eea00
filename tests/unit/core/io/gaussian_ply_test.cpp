#include "fslam/core/io/gaussian_ply.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "test_support.hpp"

namespace fslam::core {
namespace {

// A map with random values plus the awkward finite ones (-0, denormal, huge) in the first rows.
GaussianMap random_map(int degree, int feature_dim, std::size_t n, bool with_filter,
                       unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> uniform(-3.0f, 3.0f);
  GaussianMap map;
  map.sh_degree = degree;
  map.feature_dim = feature_dim;
  std::vector<float> sh(static_cast<std::size_t>(map.sh_per_gaussian()));
  std::vector<float> feat(static_cast<std::size_t>(feature_dim));
  for (std::size_t i = 0; i < n; ++i) {
    const float mean[3] = {uniform(rng), uniform(rng), uniform(rng)};
    const float rot[4] = {uniform(rng), uniform(rng), uniform(rng), 1.0f + std::abs(uniform(rng))};
    const float scale[3] = {uniform(rng), uniform(rng), uniform(rng)};
    for (float& v : sh) v = uniform(rng);
    for (float& v : feat) v = uniform(rng);
    const float filter = with_filter ? 1e-4f * std::abs(uniform(rng)) : 0.0f;
    map.push_back(mean, rot, scale, uniform(rng), sh.data(), feat.data(), filter);
  }
  if (n > 0) {
    map.means[0] = -0.0f;
    map.means[1] = std::numeric_limits<float>::denorm_min();
    map.means[2] = std::numeric_limits<float>::max();
    map.opacity_logits[0] = -std::numeric_limits<float>::max();
  }
  return map;
}

std::uint32_t bits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

// Bit-exact comparison of two float arrays, with the first differing index.
void expect_same_bits(const std::vector<float>& a, const std::vector<float>& b, const char* name) {
  ASSERT_EQ(a.size(), b.size()) << name;
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(bits(a[i]), bits(b[i])) << name << "[" << i << "]: " << a[i] << " vs " << b[i];
  }
}

void expect_same_map(const GaussianMap& a, const GaussianMap& b) {
  EXPECT_EQ(a.sh_degree, b.sh_degree);
  EXPECT_EQ(a.feature_dim, b.feature_dim);
  expect_same_bits(a.means, b.means, "means");
  expect_same_bits(a.rotations, b.rotations, "rotations");
  expect_same_bits(a.log_scales, b.log_scales, "log_scales");
  expect_same_bits(a.opacity_logits, b.opacity_logits, "opacity_logits");
  expect_same_bits(a.sh, b.sh, "sh");
  expect_same_bits(a.features, b.features, "features");
  expect_same_bits(a.filter_3d, b.filter_3d, "filter_3d");
}

// The value of the 3DGS property `name` for Gaussian i, written independently of the library.
float property_value(const GaussianMap& map, std::size_t i, const std::string& name) {
  const std::size_t k = static_cast<std::size_t>(sh_coefficients(map.sh_degree));
  const float* sh = map.sh.data() + 3 * k * i;
  auto index = [&](const char* prefix) { return std::stoul(name.substr(std::strlen(prefix))); };
  if (name == "x") return map.means[3 * i];
  if (name == "y") return map.means[3 * i + 1];
  if (name == "z") return map.means[3 * i + 2];
  if (name == "nx" || name == "ny" || name == "nz") return 0.0f;
  if (name.rfind("f_dc_", 0) == 0) return sh[index("f_dc_")];
  if (name.rfind("f_rest_", 0) == 0) {
    const std::size_t j = index("f_rest_");
    return sh[3 * (j % (k - 1) + 1) + j / (k - 1)];
  }
  if (name == "opacity") return map.opacity_logits[i];
  if (name.rfind("scale_", 0) == 0) return map.log_scales[3 * i + index("scale_")];
  if (name.rfind("rot_", 0) == 0) return map.rotations[4 * i + index("rot_")];
  if (name.rfind("feat_", 0) == 0) return map.features[map.feature_dim * i + index("feat_")];
  if (name == "filter_3d") return map.filter_3d[i];
  ADD_FAILURE() << "unknown property " << name;
  return 0.0f;
}

std::vector<std::string> standard_names(int degree, int feature_dim, bool filter) {
  std::vector<std::string> names = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (int j = 0; j < 3 * (sh_coefficients(degree) - 1); ++j)
    names.push_back("f_rest_" + std::to_string(j));
  for (const char* n :
       {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    names.push_back(n);
  for (int j = 0; j < feature_dim; ++j) names.push_back("feat_" + std::to_string(j));
  if (filter) names.push_back("filter_3d");
  return names;
}

struct Property {
  std::string type;  // PLY scalar type
  std::string name;
};

// Writes a PLY the way other tools might: any property order and scalar types, binary
// little-endian or ASCII. value(i, name) gives each value; non-float types get small integers.
void write_test_ply(const std::filesystem::path& path, const std::string& format, std::size_t n,
                    const std::vector<Property>& properties,
                    const std::function<float(std::size_t, const std::string&)>& value) {
  std::ofstream out(path, std::ios::binary);
  out << "ply\nformat " << format << " 1.0\ncomment written by gaussian_ply_test\n"
      << "element vertex " << n << "\n";
  for (const Property& p : properties) out << "property " << p.type << " " << p.name << "\n";
  out << "end_header\n";
  for (std::size_t i = 0; i < n; ++i) {
    for (const Property& p : properties) {
      const float v = value(i, p.name);
      if (format == "ascii") {
        std::ostringstream text;
        text.precision(9);
        if (p.type == "float")
          text << v;
        else
          text << static_cast<int>(v);
        out << text.str() << (&p == &properties.back() ? "\n" : " ");
        continue;
      }
      auto put = [&out](const auto& x) { out.write(reinterpret_cast<const char*>(&x), sizeof(x)); };
      if (p.type == "float")
        put(v);
      else if (p.type == "double")
        put(static_cast<double>(v));
      else if (p.type == "uchar")
        put(static_cast<std::uint8_t>(v));
      else if (p.type == "char")
        put(static_cast<std::int8_t>(v));
      else if (p.type == "short")
        put(static_cast<std::int16_t>(v));
      else if (p.type == "ushort")
        put(static_cast<std::uint16_t>(v));
      else if (p.type == "int")
        put(static_cast<std::int32_t>(v));
      else if (p.type == "uint")
        put(static_cast<std::uint32_t>(v));
      else
        ADD_FAILURE() << "test writer lacks type " << p.type;
    }
  }
}

std::vector<Property> as_float(const std::vector<std::string>& names) {
  std::vector<Property> properties;
  for (const std::string& name : names) properties.push_back({"float", name});
  return properties;
}

class GaussianPlyRoundTrip : public ::testing::TestWithParam<std::tuple<int, int, bool>> {};

TEST_P(GaussianPlyRoundTrip, BitExact) {
  const auto [degree, feature_dim, with_filter] = GetParam();
  const GaussianMap map = random_map(degree, feature_dim, 37, with_filter, 7u + degree);
  const auto path = (test::fresh_temp_dir("rt") / "map.ply").string();
  std::string why;
  ASSERT_TRUE(write_gaussian_ply(path, map, &why)) << why;
  // 17 standard floats (x..rot_3, f_rest excluded), 3 (K-1) f_rest, D features, filter_3d.
  const std::size_t floats = 17 + 3 * (sh_coefficients(degree) - 1) + feature_dim + 1;
  std::ifstream in(path, std::ios::binary);
  std::string header((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t header_bytes = header.find("end_header\n") + 11;
  EXPECT_EQ(std::filesystem::file_size(path), header_bytes + 37 * floats * 4);

  GaussianMap back;
  back.feature_dim = 99;  // must be replaced, not kept
  ASSERT_TRUE(read_gaussian_ply(path, &back, &why)) << why;
  expect_same_map(map, back);
}

INSTANTIATE_TEST_SUITE_P(DegreesAndFeatures, GaussianPlyRoundTrip,
                         ::testing::Combine(::testing::Values(0, 1, 2, 3),
                                            ::testing::Values(0, 3, 16), ::testing::Bool()));

TEST(GaussianPly, EmptyMapRoundTrips) {
  GaussianMap map;
  map.sh_degree = 2;
  map.feature_dim = 4;
  const auto path = (test::fresh_temp_dir("empty") / "empty.ply").string();
  std::string why;
  ASSERT_TRUE(write_gaussian_ply(path, map, &why)) << why;
  GaussianMap back;
  ASSERT_TRUE(read_gaussian_ply(path, &back, &why)) << why;
  EXPECT_EQ(back.size(), 0u);
  EXPECT_EQ(back.sh_degree, 2);
  EXPECT_EQ(back.feature_dim, 4);
}

TEST(GaussianPly, WritesStandardHeaderAndLayout) {
  GaussianMap map;
  map.sh_degree = 1;
  map.feature_dim = 2;
  // sh[k, c] = 10 k + c, so the channel-major f_rest order is visible in the bytes.
  float sh[12];
  for (int k = 0; k < 4; ++k)
    for (int c = 0; c < 3; ++c) sh[3 * k + c] = 10.0f * k + c;
  const float mean[3] = {1.5f, -2.0f, 3.25f}, rot[4] = {0.5f, 0.1f, 0.2f, 0.3f};
  const float scale[3] = {-4.0f, -5.0f, -6.0f}, feat[2] = {7.5f, -8.5f};
  map.push_back(mean, rot, scale, 0.75f, sh, feat, 0.125f);
  map.push_back(mean, rot, scale, -0.75f, sh, feat, 0.0f);
  const auto path = (test::fresh_temp_dir("header") / "deg1.ply").string();
  std::string why;
  ASSERT_TRUE(write_gaussian_ply(path, map, &why)) << why;

  const std::vector<std::string> expected = {"ply",
                                             "format binary_little_endian 1.0",
                                             "element vertex 2",
                                             "property float x",
                                             "property float y",
                                             "property float z",
                                             "property float nx",
                                             "property float ny",
                                             "property float nz",
                                             "property float f_dc_0",
                                             "property float f_dc_1",
                                             "property float f_dc_2",
                                             "property float f_rest_0",
                                             "property float f_rest_1",
                                             "property float f_rest_2",
                                             "property float f_rest_3",
                                             "property float f_rest_4",
                                             "property float f_rest_5",
                                             "property float f_rest_6",
                                             "property float f_rest_7",
                                             "property float f_rest_8",
                                             "property float opacity",
                                             "property float scale_0",
                                             "property float scale_1",
                                             "property float scale_2",
                                             "property float rot_0",
                                             "property float rot_1",
                                             "property float rot_2",
                                             "property float rot_3",
                                             "property float feat_0",
                                             "property float feat_1",
                                             "property float filter_3d",
                                             "end_header"};
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (std::size_t l = 0; l < expected.size(); ++l) {
    ASSERT_TRUE(std::getline(in, line)) << "header ends before line " << l;
    EXPECT_EQ(line, expected[l]) << "header line " << l;
  }
  // The first vertex, float by float.
  // clang-format off
  const float row[29] = {1.5f, -2.0f, 3.25f, 0, 0, 0,               // x y z nx ny nz
                         0, 1, 2,                                    // f_dc = sh[0, c]
                         10, 20, 30, 11, 21, 31, 12, 22, 32,         // f_rest: R, then G, then B
                         0.75f, -4.0f, -5.0f, -6.0f,                 // opacity, scales
                         0.5f, 0.1f, 0.2f, 0.3f,                     // rot w x y z
                         7.5f, -8.5f, 0.125f};                       // feat, filter_3d
  // clang-format on
  float read_back[29];
  ASSERT_TRUE(in.read(reinterpret_cast<char*>(read_back), sizeof(read_back)));
  for (int j = 0; j < 29; ++j) EXPECT_EQ(read_back[j], row[j]) << "float " << j << " of vertex 0";
  EXPECT_EQ(std::filesystem::file_size(path), static_cast<std::uintmax_t>(in.tellg()) + 29 * 4);
}

TEST(GaussianPly, ReadsAscii) {
  const auto path = test::fresh_temp_dir("ascii") / "ascii.ply";
  // Degree 0, one feature, no filter_3d, extra integer property; CRLF line ends.
  std::ofstream(path, std::ios::binary)
      << "ply\r\nformat ascii 1.0\r\ncomment from some tool\r\nelement vertex 2\r\n"
         "property float x\r\nproperty float y\r\nproperty float z\r\n"
         "property float nx\r\nproperty float ny\r\nproperty float nz\r\n"
         "property float f_dc_0\r\nproperty float f_dc_1\r\nproperty float f_dc_2\r\n"
         "property float opacity\r\nproperty float scale_0\r\nproperty float scale_1\r\n"
         "property float scale_2\r\nproperty float rot_0\r\nproperty float rot_1\r\n"
         "property float rot_2\r\nproperty float rot_3\r\nproperty float feat_0\r\n"
         "property int label\r\nend_header\r\n"
         "1 2 3 0 0 0 0.5 -0.5 0.25 -2.5 -3 -3.5 -4 1 0 0 0 9 42\r\n"
         "-1e-3 2.5e2 0.1 0 0 0 1 1 1 3.5 0 0 0 0.7071068 0.7071068 0 0 -9 7\r\n";
  GaussianMap map;
  std::string why;
  ASSERT_TRUE(read_gaussian_ply(path.string(), &map, &why)) << why;
  ASSERT_EQ(map.size(), 2u);
  EXPECT_EQ(map.sh_degree, 0);
  EXPECT_EQ(map.feature_dim, 1);
  EXPECT_EQ(map.means, (std::vector<float>{1, 2, 3, -1e-3f, 250.0f, 0.1f}));
  EXPECT_EQ(map.sh, (std::vector<float>{0.5f, -0.5f, 0.25f, 1, 1, 1}));
  EXPECT_EQ(map.opacity_logits, (std::vector<float>{-2.5f, 3.5f}));
  EXPECT_EQ(map.log_scales, (std::vector<float>{-3, -3.5f, -4, 0, 0, 0}));
  EXPECT_EQ(map.rotations, (std::vector<float>{1, 0, 0, 0, 0.7071068f, 0.7071068f, 0, 0}));
  EXPECT_EQ(map.features, (std::vector<float>{9, -9}));
  EXPECT_EQ(map.filter_3d, (std::vector<float>{0, 0}));
}

TEST(GaussianPly, ReadsShuffledPropertiesAndSkipsUnknownTypes) {
  const GaussianMap map = random_map(1, 2, 11, true, 3u);
  std::vector<std::string> names = standard_names(1, 2, true);
  std::shuffle(names.begin(), names.end(), std::mt19937(5u));
  std::vector<Property> properties = as_float(names);
  // Unknown properties of every size, placed between the known ones.
  properties.insert(properties.begin() + 3, {"uchar", "red"});
  properties.insert(properties.begin() + 7, {"double", "confidence"});
  properties.insert(properties.begin() + 11, {"short", "s16"});
  properties.insert(properties.begin() + 13, {"char", "s8"});
  properties.insert(properties.begin() + 17, {"ushort", "u16"});
  properties.insert(properties.begin() + 19, {"int", "s32"});
  properties.insert(properties.begin(), {"uint", "u32"});
  properties.push_back({"uchar", "alpha"});
  const auto path = test::fresh_temp_dir("shuffled") / "shuffled.ply";
  write_test_ply(path, "binary_little_endian", map.size(), properties,
                 [&](std::size_t i, const std::string& name) {
                   const float fi = static_cast<float>(i);
                   if (name == "red" || name == "alpha" || name == "u16") return 200.0f + fi;
                   if (name == "s8") return -100.0f + fi;
                   if (name == "confidence" || name == "s16" || name == "s32") return -1.0f - fi;
                   if (name == "u32") return 4000000.0f + fi;
                   return property_value(map, i, name);
                 });
  GaussianMap back;
  std::string why;
  ASSERT_TRUE(read_gaussian_ply(path.string(), &back, &why)) << why;
  expect_same_map(map, back);
}

// ---- errors ------------------------------------------------------------------------------------

class GaussianPlyErrors : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::fresh_temp_dir("errors"); }

  // A valid degree-1, D = 2 binary file of `n` Gaussians written by the library.
  std::filesystem::path valid_file(const std::string& name, std::size_t n = 3) {
    const auto path = dir_ / name;
    std::string why;
    EXPECT_TRUE(write_gaussian_ply(path.string(), random_map(1, 2, n, true, 11u), &why)) << why;
    return path;
  }

  // Expects the read to fail with a message that names the file and contains `fragment`.
  void expect_error(const std::filesystem::path& path, const std::string& fragment) {
    GaussianMap map;
    map.sh_degree = 3;
    std::string why;
    EXPECT_FALSE(read_gaussian_ply(path.string(), &map, &why)) << path;
    EXPECT_NE(why.find(path.string()), std::string::npos) << why;
    EXPECT_NE(why.find(fragment), std::string::npos) << "expected '" << fragment << "' in: " << why;
    EXPECT_EQ(map.sh_degree, 3) << "the output must be left alone on failure";
  }

  // The standard degree-0 property list with `name` replaced by `replacement` (dropped if empty).
  static std::vector<Property> standard_without(const std::string& name, Property replacement) {
    std::vector<Property> properties;
    for (const Property& p : as_float(standard_names(0, 0, false))) {
      if (p.name != name)
        properties.push_back(p);
      else if (!replacement.name.empty())
        properties.push_back(replacement);
    }
    return properties;
  }

  static float unit_value(std::size_t, const std::string& name) {
    return name == "rot_0" ? 1.0f : 0.5f;
  }

  std::filesystem::path dir_;
};

TEST_F(GaussianPlyErrors, MissingFile) { expect_error(dir_ / "missing.ply", "cannot open"); }

TEST_F(GaussianPlyErrors, BadMagic) {
  std::ofstream(dir_ / "magic.ply") << "plx\nformat ascii 1.0\nelement vertex 0\nend_header\n";
  expect_error(dir_ / "magic.ply", "bad magic");
  std::ofstream(dir_ / "binary.ply", std::ios::binary) << std::string(64, '\x7f');
  expect_error(dir_ / "binary.ply", "bad magic");
  std::ofstream(dir_ / "empty.ply");
  expect_error(dir_ / "empty.ply", "bad magic");
}

TEST_F(GaussianPlyErrors, HeaderWithoutEnd) {
  std::ofstream(dir_ / "noend.ply") << "ply\nformat ascii 1.0\nelement vertex 0\n";
  expect_error(dir_ / "noend.ply", "no end_header");
}

TEST_F(GaussianPlyErrors, MissingRequiredProperty) {
  write_test_ply(dir_ / "norot.ply", "binary_little_endian", 2, standard_without("rot_3", {}),
                 unit_value);
  expect_error(dir_ / "norot.ply", "missing required vertex property 'rot_3'");
  write_test_ply(dir_ / "nox.ply", "ascii", 2, standard_without("x", {}), unit_value);
  expect_error(dir_ / "nox.ply", "missing required vertex property 'x'");
  std::ofstream(dir_ / "novertex.ply") << "ply\nformat ascii 1.0\nelement face 0\nend_header\n";
  expect_error(dir_ / "novertex.ply", "no 'vertex' element");
}

TEST_F(GaussianPlyErrors, NonFloatPropertyWeNeed) {
  write_test_ply(dir_ / "double.ply", "binary_little_endian", 2,
                 standard_without("opacity", {"double", "opacity"}), unit_value);
  expect_error(dir_ / "double.ply", "'opacity' is double, expected float");
  write_test_ply(dir_ / "uchar.ply", "binary_little_endian", 2,
                 standard_without("f_dc_1", {"uchar", "f_dc_1"}), unit_value);
  expect_error(dir_ / "uchar.ply", "'f_dc_1' is uchar, expected float");
}

TEST_F(GaussianPlyErrors, BigEndianAndListsRejected) {
  write_test_ply(dir_ / "big.ply", "binary_big_endian", 1, standard_without("", {}), unit_value);
  expect_error(dir_ / "big.ply", "big-endian");
  std::ofstream(dir_ / "list.ply") << "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                                      "element face 0\nproperty list uchar int vertex_indices\n"
                                      "end_header\n";
  expect_error(dir_ / "list.ply", "list property in element 'face'");
  std::ofstream(dir_ / "type.ply") << "ply\nformat ascii 1.0\nelement vertex 0\n"
                                      "property float16 x\nend_header\n";
  expect_error(dir_ / "type.ply", "unknown type 'float16'");
}

TEST_F(GaussianPlyErrors, BadShAndFeatureCounts) {
  std::vector<Property> properties = as_float(standard_names(0, 0, false));
  for (int j = 0; j < 6; ++j) properties.push_back({"float", "f_rest_" + std::to_string(j)});
  write_test_ply(dir_ / "rest6.ply", "binary_little_endian", 1, properties, unit_value);
  expect_error(dir_ / "rest6.ply", "found 6 f_rest_* properties");

  properties = as_float(standard_names(0, 0, false));
  properties.push_back({"float", "feat_0"});
  properties.push_back({"float", "feat_2"});
  write_test_ply(dir_ / "featgap.ply", "binary_little_endian", 1, properties, unit_value);
  expect_error(dir_ / "featgap.ply", "feat_1 missing");
}

TEST_F(GaussianPlyErrors, TruncatedData) {
  const auto binary = valid_file("truncated.ply");
  std::filesystem::resize_file(binary, std::filesystem::file_size(binary) - 5);
  expect_error(binary, "truncated");

  // A header claiming far more vertices than the file holds fails before allocating them.
  write_test_ply(dir_ / "huge.ply", "binary_little_endian", 1, standard_without("", {}),
                 unit_value);
  std::string text;
  {
    std::ifstream in(dir_ / "huge.ply", std::ios::binary);
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const std::size_t at = text.find("element vertex 1\n");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 17, "element vertex 99999999999999999\n");
  std::ofstream(dir_ / "huge.ply", std::ios::binary | std::ios::trunc) << text;
  expect_error(dir_ / "huge.ply", "truncated: element 'vertex' declares 99999999999999999 rows");

  write_test_ply(dir_ / "ascii.ply", "ascii", 3, standard_without("", {}), unit_value);
  std::filesystem::resize_file(dir_ / "ascii.ply",
                               std::filesystem::file_size(dir_ / "ascii.ply") - 10);
  expect_error(dir_ / "ascii.ply", "truncated: the data ends in vertex 2");
}

TEST_F(GaussianPlyErrors, VertexCountInconsistentWithFileSize) {
  const auto path = valid_file("count.ply", 3);
  std::string text;
  {
    std::ifstream in(path, std::ios::binary);
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const std::size_t at = text.find("element vertex 3\n");
  ASSERT_NE(at, std::string::npos);
  text[at + 15] = '2';  // the data still holds 3 vertices
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
  expect_error(path, "vertex count 2 is inconsistent with the file size");

  write_test_ply(dir_ / "ascii.ply", "ascii", 2, standard_without("", {}), unit_value);
  std::ofstream(dir_ / "ascii.ply", std::ios::app) << "0.5 0.5\n";
  expect_error(dir_ / "ascii.ply", "vertex count 2 is inconsistent with the file size");
}

TEST_F(GaussianPlyErrors, NonFiniteValues) {
  const auto nan_at = [](float bad) {
    return [bad](std::size_t i, const std::string& name) {
      return i == 1 && name == "scale_2" ? bad : unit_value(i, name);
    };
  };
  write_test_ply(dir_ / "nan.ply", "binary_little_endian", 3, standard_without("", {}),
                 nan_at(std::numeric_limits<float>::quiet_NaN()));
  expect_error(dir_ / "nan.ply", "vertex 1 property 'scale_2' is not finite");
  write_test_ply(dir_ / "inf.ply", "ascii", 3, standard_without("", {}),
                 nan_at(-std::numeric_limits<float>::infinity()));
  expect_error(dir_ / "inf.ply", "vertex 1 property 'scale_2' is not finite");
  // Beyond float range counts as non-finite, not as a silent infinity.
  write_test_ply(dir_ / "big.ply", "ascii", 3, standard_without("", {}), unit_value);
  {
    std::ifstream in(dir_ / "big.ply");
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    text.replace(text.rfind("0.5"), 3, "1e39");
    std::ofstream(dir_ / "big.ply", std::ios::trunc) << text;
  }
  expect_error(dir_ / "big.ply", "is not finite (1e39)");
}

TEST_F(GaussianPlyErrors, AsciiNotANumber) {
  write_test_ply(dir_ / "word.ply", "ascii", 1, standard_without("", {}), unit_value);
  std::ifstream in(dir_ / "word.ply");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  text.replace(text.find("0.5"), 3, "abc");
  std::ofstream(dir_ / "word.ply", std::ios::trunc) << text;
  expect_error(dir_ / "word.ply", "'abc' is not a number");
}

TEST_F(GaussianPlyErrors, InconsistentMapFromFile) {
  // Finite, well-formed, but a zero quaternion: GaussianMap::is_consistent has the last word.
  write_test_ply(dir_ / "zero_rot.ply", "binary_little_endian", 2, standard_without("", {}),
                 [](std::size_t, const std::string& name) {
                   return name.rfind("rot_", 0) == 0 ? 0.0f : 0.5f;
                 });
  expect_error(dir_ / "zero_rot.ply", "rotation 0 is zero");
}

TEST_F(GaussianPlyErrors, WriteFailuresNameTheFile) {
  std::string why;
  const auto no_dir = (dir_ / "no_such_dir" / "map.ply").string();
  EXPECT_FALSE(write_gaussian_ply(no_dir, random_map(0, 0, 2, false, 1u), &why));
  EXPECT_NE(why.find(no_dir), std::string::npos) << why;
  GaussianMap broken = random_map(0, 0, 2, false, 1u);
  broken.means.pop_back();
  const auto path = (dir_ / "broken.ply").string();
  EXPECT_FALSE(write_gaussian_ply(path, broken, &why));
  EXPECT_NE(why.find(path), std::string::npos) << why;
  EXPECT_NE(why.find("means holds 5 values"), std::string::npos) << why;
  EXPECT_FALSE(std::filesystem::exists(path));
}

}  // namespace
}  // namespace fslam::core
