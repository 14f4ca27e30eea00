#include "fslam/core/features/onnx_check.hpp"

#include <cstdint>
#include <fstream>
#include <iterator>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

struct Bytes {
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
};

struct Field {
  std::uint64_t number = 0, value = 0;
  int type = 0;  // 0 varint, 1 fixed64, 2 length-delimited, 5 fixed32
  Bytes bytes;
};

// Protobuf wire format (protobuf.dev/programming-guides/encoding): key = field << 3 | wire type.
class Wire {
 public:
  explicit Wire(Bytes b) : p_(b.data), end_(b.data + b.size) {}
  bool done() const { return p_ == end_; }

  bool varint(std::uint64_t* v) {
    *v = 0;
    for (int shift = 0; shift < 64 && p_ != end_; shift += 7) {
      const std::uint8_t b = *p_++;
      *v |= static_cast<std::uint64_t>(b & 0x7f) << shift;
      if ((b & 0x80) == 0) return true;
    }
    return false;
  }

  // The next field: its number and wire type; `value` for varints, `bytes` for LEN fields.
  bool next(Field* f) {
    std::uint64_t key = 0;
    if (!varint(&key)) return false;
    f->number = key >> 3;
    f->type = static_cast<int>(key & 7);
    const std::size_t left = static_cast<std::size_t>(end_ - p_);
    switch (f->type) {
      case 0: return varint(&f->value);
      case 1: return skip(8, left);
      case 5: return skip(4, left);
      case 2: {
        std::uint64_t n = 0;
        if (!varint(&n) || n > static_cast<std::uint64_t>(end_ - p_)) return false;
        f->bytes = {p_, static_cast<std::size_t>(n)};
        p_ += n;
        return true;
      }
      default: return false;  // groups (3, 4) are not used by ONNX; 6, 7 do not exist
    }
  }

 private:
  bool skip(std::size_t n, std::size_t left) {
    if (n > left) return false;
    p_ += n;
    return true;
  }
  const std::uint8_t* p_;
  const std::uint8_t* end_;
};

std::size_t packed_varints(Bytes b) {
  std::size_t n = 0;
  for (std::size_t i = 0; i < b.size; ++i) n += (b.data[i] & 0x80) == 0;
  return n;
}

// Bytes per element of TensorProto.DataType (onnx.proto); 0 for STRING and unknown types.
std::uint64_t element_bytes(std::uint64_t type) {
  switch (type) {
    case 2: case 3: case 9: return 1;     // UINT8, INT8, BOOL
    case 4: case 5: case 10: case 16: return 2;  // UINT16, INT16, FLOAT16, BFLOAT16
    case 1: case 6: case 12: return 4;    // FLOAT, INT32, UINT32
    case 7: case 11: case 13: case 14: return 8;  // INT64, DOUBLE, UINT64, COMPLEX64
    case 15: return 16;                   // COMPLEX128
    default: return 0;
  }
}

class Checker {
 public:
  explicit Checker(std::string* why) : why_(why) {}

  bool model(Bytes b) {
    Wire w(b);
    Field f;
    while (!w.done()) {
      if (!w.next(&f)) return malformed("model");
      if (f.number == 7 && f.type == 2 && !graph(f.bytes, 0, {})) return false;  // ModelProto.graph
    }
    return true;
  }

 private:
  // GraphProto: node = 1, initializer = 5, input = 11. Nodes are checked in order: each reads
  // only names defined before it (a graph input, an initializer, an earlier node's output or,
  // in a subgraph, the enclosing graph's), as onnx.proto requires; OpenCV 4.6 dereferences a
  // null blob on a name nothing defines.
  bool graph(Bytes b, int depth, std::set<std::string> defined) {
    if (depth > 16) return fail(why_, "subgraphs nested deeper than 16");
    Wire w(b);
    Field f;
    std::vector<Bytes> nodes;
    while (!w.done()) {
      if (!w.next(&f)) return malformed("graph");
      if (f.type != 2) continue;
      if (f.number == 1) nodes.push_back(f.bytes);
      std::string name;
      if (f.number == 5 && !tensor(f.bytes, "initializer", &name)) return false;
      if (f.number == 11 && !first_string(f.bytes, 1, &name)) return malformed("graph input");
      if (f.number == 5 || f.number == 11) defined.insert(name);
    }
    for (const Bytes& n : nodes) {
      if (!node(n, depth, &defined)) return false;
    }
    return true;
  }

  // NodeProto: input = 1, output = 2, name = 3, op_type = 4, attribute = 5.
  bool node(Bytes b, int depth, std::set<std::string>* defined) {
    Wire w(b);
    Field f, a;
    std::vector<std::string> inputs, outputs;
    std::string name, op;
    std::vector<Bytes> subgraphs;
    while (!w.done()) {
      if (!w.next(&f)) return malformed("node");
      if (f.type != 2) continue;
      const std::string text(reinterpret_cast<const char*>(f.bytes.data), f.bytes.size);
      if (f.number == 1) inputs.push_back(text);
      if (f.number == 2) outputs.push_back(text);
      if (f.number == 3) name = text;
      if (f.number == 4) op = text;
      if (f.number != 5) continue;
      Wire attribute(f.bytes);
      while (!attribute.done()) {
        if (!attribute.next(&a)) return malformed("attribute");
        if (a.type != 2) continue;
        // AttributeProto: t = 5, tensors = 10, g = 6, graphs = 11.
        if ((a.number == 5 || a.number == 10) && !tensor(a.bytes, "node attribute", nullptr)) return false;
        if (a.number == 6 || a.number == 11) subgraphs.push_back(a.bytes);
      }
    }
    for (const std::string& input : inputs) {
      if (!input.empty() && defined->count(input) == 0) {
        return fail(why_, "node '" + name + "' (" + op + ") reads '" + input +
                              "', which no graph input, initializer or earlier node defines");
      }
    }
    for (const Bytes& g : subgraphs) {
      if (!graph(g, depth + 1, *defined)) return false;
    }
    defined->insert(outputs.begin(), outputs.end());
    return true;
  }

  // The first string field `number` of a message (ValueInfoProto.name = 1).
  bool first_string(Bytes b, std::uint64_t number, std::string* out) {
    Wire w(b);
    Field f;
    while (!w.done()) {
      if (!w.next(&f)) return false;
      if (f.number == number && f.type == 2) {
        out->assign(reinterpret_cast<const char*>(f.bytes.data), f.bytes.size);
        return true;
      }
    }
    return true;
  }

  // TensorProto: dims = 1, data_type = 2, float_data = 4, int32_data = 5, string_data = 6,
  // int64_data = 7, name = 8, raw_data = 9, double_data = 10, uint64_data = 11, data_location = 14.
  bool tensor(Bytes b, const char* where, std::string* name_out) {
    Wire w(b);
    Field f;
    std::vector<std::uint64_t> dims;
    std::uint64_t data_type = 0, typed = 0, raw = 0;
    bool has_raw = false, external = false;
    std::string name;
    while (!w.done()) {
      if (!w.next(&f)) return malformed("tensor");
      switch (f.number) {
        case 1:  // packed or not
          if (f.type == 0) dims.push_back(f.value);
          if (f.type == 2) {
            Wire d(f.bytes);
            std::uint64_t v = 0;
            while (!d.done()) {
              if (!d.varint(&v)) return malformed("tensor's dims");
              dims.push_back(v);
            }
          }
          break;
        case 2: data_type = f.value; break;
        case 4: typed += f.type == 2 ? f.bytes.size / 4 : 1; break;
        case 10: typed += f.type == 2 ? f.bytes.size / 8 : 1; break;
        case 5: case 7: case 11: typed += f.type == 2 ? packed_varints(f.bytes) : 1; break;
        case 6: typed += 1; break;
        case 8: name.assign(reinterpret_cast<const char*>(f.bytes.data), f.bytes.size); break;
        case 9: has_raw = true; raw = f.bytes.size; break;
        case 14: external = f.value == 1; break;
        default: break;
      }
    }
    if (name_out != nullptr) *name_out = name;
    const std::string label = "tensor '" + name + "' (" + where + ")";
    if (external) return fail(why_, label + " keeps its data in an external file, which is not supported");
    std::uint64_t count = 1;
    for (const std::uint64_t d : dims) {
      if (d > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
        return fail(why_, label + " has a negative dimension");
      }
      if (d != 0 && count > std::numeric_limits<std::uint64_t>::max() / d) {
        return fail(why_, label + " has a shape too large to hold");
      }
      count *= d;
    }
    if (count == 0) return true;
    if (has_raw) {
      const std::uint64_t size = element_bytes(data_type);
      if (size == 0) {
        return fail(why_, label + " has raw data of string or unknown type " + std::to_string(data_type));
      }
      if (count > raw / size) {
        return fail(why_, label + " declares " + std::to_string(count) + " elements of " + std::to_string(size) +
                              " bytes but holds " + std::to_string(raw) + " bytes");
      }
      return true;
    }
    const std::uint64_t values = data_type == 14 || data_type == 15 ? 2 : 1;  // complex: two per element
    if (typed / values < count) {
      return fail(why_, label + " declares " + std::to_string(count) + " elements but holds " +
                            std::to_string(typed / values));
    }
    return true;
  }

  bool malformed(const char* what) {
    return fail(why_, std::string("not a valid ONNX protobuf (in a ") + what + ")");
  }

  std::string* why_;
};

}  // namespace

bool check_onnx_file(const std::string& path, std::string* why) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return fail(why, "cannot read " + path);
  const std::vector<char> file((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (file.empty()) return fail(why, path + " is empty");
  std::string reason;
  Checker checker(&reason);
  if (!checker.model({reinterpret_cast<const std::uint8_t*>(file.data()), file.size()})) {
    return fail(why, path + ": " + reason);
  }
  return true;
}

bool read_onnx_net(const std::string& path, cv::dnn::Net* net, std::string* why) {
  if (!check_onnx_file(path, why)) return false;  // before OpenCV reads it
  try {
    *net = cv::dnn::readNetFromONNX(path);
  } catch (const std::exception& e) {
    return fail(why, "cannot be loaded by OpenCV dnn: " + std::string(e.what()));
  }
  if (net->empty()) return fail(why, "OpenCV dnn loaded an empty network");
  return true;
}

}  // namespace fslam::core
