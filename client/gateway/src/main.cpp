// fslam-gateway: one more DDS client of a featureslam server that serves the browser viewer
// (docs/viewer.md). Links fslam::client and fslam::proto only: it never sees core.
#include <unistd.h>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "fslam/client/client.hpp"
#include "gateway.hpp"
#include "options.hpp"
#include "web_server.hpp"

namespace {

// The bundled page beside the binary: <build>/bin/fslam-gateway -> <build>/viewer.
std::string default_web_dir() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? "viewer" : (exe.parent_path().parent_path() / "viewer").string();
}

}  // namespace

int main(int argc, char** argv) {
  using namespace fslam::client;
  gateway::GatewayOptions options;
  std::string why;
  bool help = false;
  if (!gateway::parse_options(std::vector<std::string>(argv + 1, argv + argc), &options, &why, &help)) {
    std::fprintf(stderr, "fslam-gateway: %s\n%s", why.c_str(), gateway::usage().c_str());
    return 2;
  }
  if (help) {
    std::printf("%s", gateway::usage().c_str());
    return 0;
  }
  if (options.web_dir.empty()) options.web_dir = default_web_dir();
  try {
    ClientOptions client_options;
    client_options.prefix = options.prefix;
    Client client(client_options);
    gateway::Gateway state(options, &client);
    gateway::WebServer web(options, &state);
    if (!web.open(&why)) {
      std::fprintf(stderr, "fslam-gateway: %s\n", why.c_str());
      return 1;
    }
    state.start(&web);
    const std::string host = options.address.find(':') != std::string::npos ? "[" + options.address + "]"
                                                                            : options.address;
    std::string url = "http://" + host + ":" + std::to_string(web.port()) + "/";
    if (!options.token.empty()) url += "?token=<the token>";
    std::printf("fslam-gateway: viewer at %s (prefix %s, page %s)\n", url.c_str(), options.prefix.c_str(),
                options.web_dir.c_str());
    std::fflush(stdout);
    if (!options.port_file.empty()) {
      const std::string tmp = options.port_file + ".tmp";
      std::ofstream(tmp) << web.port() << "\n";
      std::filesystem::rename(tmp, options.port_file);
    }
    web.run();  // until SIGINT / SIGTERM
    state.stop();
    const gateway::GatewayStats s = state.stats();
    std::fprintf(stderr, "fslam-gateway: stopped; %llu map versions sent (%llu bytes), %llu requests\n",
                 static_cast<unsigned long long>(s.map_versions_sent),
                 static_cast<unsigned long long>(s.map_bytes_sent),
                 static_cast<unsigned long long>(s.requests));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fslam-gateway: %s\n", e.what());
    return 1;
  }
  return 0;
}
