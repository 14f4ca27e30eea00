#include "client_args.hpp"

#include <cmath>
#include <sstream>
#include <vector>

#include <CLI/CLI.hpp>

#include "fslam/core/io/text_tables.hpp"

namespace fslam::cli {

void add_client_options(CLI::App* app, ClientArgs* args) {
  app->add_option("--prefix", args->prefix, "Topic prefix of the server")->capture_default_str();
  app->add_option("--timeout", args->timeout_s, "Seconds to wait for the server's answer")
      ->capture_default_str();
}

bool parse_pose_text(const std::string& text, double translation[3], double rotation[4],
                     std::string* why) {
  std::vector<double> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    double x = 0;
    if (!core::parse_double(item, &x) || !std::isfinite(x)) {
      *why = "--pose: '" + item + "' is not a number";
      return false;
    }
    v.push_back(x);
  }
  if (v.size() != 7) {
    *why = "--pose expects tx,ty,tz,qx,qy,qz,qw (7 numbers), got " + std::to_string(v.size());
    return false;
  }
  const double norm = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
  if (std::abs(norm - 1.0) > 1e-3) {
    *why = "--pose: the quaternion is not unit length";
    return false;
  }
  for (int k = 0; k < 3; ++k) translation[k] = v[k];
  for (int k = 0; k < 4; ++k) rotation[k] = v[3 + k] / norm;
  return true;
}

}  // namespace fslam::cli
