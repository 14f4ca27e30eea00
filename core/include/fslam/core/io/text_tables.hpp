// Whitespace-separated text files as datasets ship them: lists ("timestamp path"), intrinsics,
// pose matrices. '#' comment lines and blank lines are skipped; spaces, tabs and commas separate
// fields. Errors name the file and line.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

namespace fslam::core {

struct TextRow {
  int line = 0;  // 1-based line number in the file
  std::vector<std::string> fields;
};

struct NumberRow {
  int line = 0;
  std::vector<double> values;
};

// Every non-comment, non-blank line split into fields.
bool read_text_rows(const std::string& path, std::vector<TextRow>* rows, std::string* why);

// Like read_text_rows, but every field must be a finite number.
bool read_number_rows(const std::string& path, std::vector<NumberRow>* rows, std::string* why);

// A file holding exactly rows x cols numbers, row-major, however they are split across lines.
bool read_matrix_file(const std::string& path, int rows, int cols, Eigen::MatrixXd* matrix,
                      std::string* why);

// `text` as a double, the whole of it; false for anything else.
bool parse_double(const std::string& text, double* value);

// Numbers separated by commas and/or spaces ("585,585,320,240"), as command-line values give
// them; every field must be a finite number. Empty text gives no numbers.
bool parse_number_list(const std::string& text, std::vector<double>* values, std::string* why);

}  // namespace fslam::core
