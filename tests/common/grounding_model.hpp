// A tiny grounding model for tests of the text-prompt plumbing, generated at test time by
// make_grounding_model.py with Debian's python3-onnx (nothing binary is checked in).
#pragma once

#include <cstdio>
#include <string>

#include "cli_runner.hpp"

namespace fslam::test {

// Writes <dir>/grounding.onnx (+ .vocab.txt): input image size x size; two boxes whatever the
// input, the high-scoring one at (cx, cy, w, h) normalised, the other scoring 0.02. Returns the
// model path, or "" with `why` when python3-onnx is missing or the script fails.
inline std::string make_grounding_model(const std::string& dir, int size, double cx, double cy,
                                        double w, double h, std::string* why) {
  const std::string model = dir + "/grounding.onnx";
  char box[160];
  std::snprintf(box, sizeof box, "%d %.9g %.9g %.9g %.9g", size, cx, cy, w, h);
  std::string out, err;
  const int status = run_command("/usr/bin/python3 " FSLAM_TEST_COMMON_DIR "/make_grounding_model.py " +
                                     model + " " + box,
                                 &out, &err);
  if (status != 0) {
    *why = "cannot generate the test's ONNX model (needs /usr/bin/python3 with python3-onnx): " + err;
    return "";
  }
  return model;
}

}  // namespace fslam::test
