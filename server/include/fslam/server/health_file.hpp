// A file that says the server is serving, for probes that cannot speak DDS (Kubernetes exec
// probes, deploy/k8s): rewritten every status period while the ingest thread runs, removed when
// the server stops. Readiness: the file exists. Liveness: it is younger than a few periods.
#pragma once

#include <cstddef>
#include <string>

namespace fslam::server {

class HealthFile {
 public:
  explicit HealthFile(std::string path) : path_(std::move(path)) {}
  ~HealthFile();
  HealthFile(const HealthFile&) = delete;
  HealthFile& operator=(const HealthFile&) = delete;
  // Replaces the file (written beside it, then renamed: a probe never reads half a line) with
  // "serving <service prefix> maps <n> sessions <m> utc_ns <t>". False when it cannot be written.
  bool beat(const std::string& service_prefix, std::size_t maps, std::size_t sessions);

 private:
  std::string path_;
};

}  // namespace fslam::server
