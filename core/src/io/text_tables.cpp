#include "fslam/core/io/text_tables.hpp"

#include "fslam/core/error.hpp"

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace fslam::core {
bool parse_double(const std::string& text, double* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  // Overflow comes back as inf, which callers reject as non-finite; underflow is harmless.
  const double v = std::strtod(text.c_str(), &end);
  if (end != text.c_str() + text.size()) return false;
  *value = v;
  return true;
}

bool parse_number_list(const std::string& text, std::vector<double>* values, std::string* why) {
  std::string spaced = text;
  for (char& c : spaced)
    if (c == ',' || c == '\t') c = ' ';
  std::istringstream fields(spaced);
  std::vector<double> result;
  std::string field;
  while (fields >> field) {
    double v = 0.0;
    if (!parse_double(field, &v) || !std::isfinite(v))
      return fail(why, "'" + field + "' is not a finite number");
    result.push_back(v);
  }
  *values = std::move(result);
  return true;
}

bool read_text_rows(const std::string& path, std::vector<TextRow>* rows, std::string* why) {
  std::ifstream in(path);
  if (!in) return fail(why, path + ": cannot open file");
  std::vector<TextRow> result;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    for (char& c : line)
      if (c == ',' || c == '\t' || c == '\r') c = ' ';
    const auto first = line.find_first_not_of(' ');
    if (first == std::string::npos || line[first] == '#') continue;
    TextRow row;
    row.line = line_number;
    std::istringstream fields(line);
    std::string field;
    while (fields >> field) row.fields.push_back(field);
    result.push_back(std::move(row));
  }
  if (in.bad()) return fail(why, path + ": read error");
  *rows = std::move(result);
  return true;
}

bool read_number_rows(const std::string& path, std::vector<NumberRow>* rows, std::string* why) {
  std::vector<TextRow> text;
  if (!read_text_rows(path, &text, why)) return false;
  std::vector<NumberRow> result;
  result.reserve(text.size());
  for (const TextRow& t : text) {
    NumberRow row;
    row.line = t.line;
    row.values.reserve(t.fields.size());
    for (const std::string& field : t.fields) {
      double v = 0.0;
      const std::string where = path + ":" + std::to_string(t.line);
      if (!parse_double(field, &v)) return fail(why, where + ": '" + field + "' is not a number");
      if (!std::isfinite(v)) return fail(why, where + ": non-finite value '" + field + "'");
      row.values.push_back(v);
    }
    result.push_back(std::move(row));
  }
  *rows = std::move(result);
  return true;
}

bool read_matrix_file(const std::string& path, int rows, int cols, Eigen::MatrixXd* matrix,
                      std::string* why) {
  std::vector<NumberRow> lines;
  if (!read_number_rows(path, &lines, why)) return false;
  std::vector<double> values;
  for (const NumberRow& line : lines)
    values.insert(values.end(), line.values.begin(), line.values.end());
  const std::size_t expected = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
  if (values.size() != expected) {
    std::ostringstream s;
    s << path << ": expected a " << rows << "x" << cols << " matrix (" << expected
      << " numbers), found " << values.size() << " numbers";
    return fail(why, s.str());
  }
  Eigen::MatrixXd m(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) m(r, c) = values[static_cast<std::size_t>(r * cols + c)];
  *matrix = m;
  return true;
}

}  // namespace fslam::core
