// Session open / close cycles against a running server (opt-in benchmark, docs/reliability.md
// "Measured"): opens localise sessions with new names on the served map `cycles`, keeping `--window` of them open at once
// (so that each lives through status rounds and gets its own status instance), closes the oldest,
// and prints the server's resident and virtual memory, memory mappings and threads (from /proc
// of `--server-pid`) every tenth of the run. An adversarial probe once grew a server to 107 GB
// virtual and 30 902 mappings with 13 000 cycles. Run with CYCLONEDDS_URI set to
// configs/dds/loopback.xml; tests/benchmarks/session_cycles.sh starts the server.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <deque>
#include <fstream>
#include <string>

#include <CLI/CLI.hpp>

#include "fslam/client/client.hpp"

namespace {

// A field of /proc/PID/status in KiB (or a count), -1 when absent.
long proc_status(int pid, const std::string& field) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind(field + ":", 0) == 0) return std::stol(line.substr(field.size() + 1));
  return -1;
}

long proc_mappings(int pid) {
  std::ifstream maps("/proc/" + std::to_string(pid) + "/maps");
  long n = 0;
  for (std::string line; std::getline(maps, line);) ++n;
  return n;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("Server memory over session open / close cycles");
  std::string prefix;
  int cycles = 2000, window = 8, server_pid = 0;
  app.add_option("--prefix", prefix, "The server's topic prefix")->required();
  app.add_option("--server-pid", server_pid, "The server's process id (for /proc)")->required();
  app.add_option("--cycles", cycles, "Sessions to open and close")->check(CLI::Range(1, 1000000));
  app.add_option("--window", window, "Sessions open at once")->check(CLI::Range(1, 15));
  CLI11_PARSE(app, argc, argv);
  fslam::client::ClientOptions options;
  options.prefix = prefix;
  fslam::client::Client client(options);
  std::deque<std::string> open;
  std::string why;
  const auto t0 = std::chrono::steady_clock::now();
  const auto report = [&](int done) {
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("cycles=%d t=%.0fs resident=%ld KiB virtual=%ld KiB mappings=%ld threads=%ld\n", done, s,
                proc_status(server_pid, "VmRSS"), proc_status(server_pid, "VmSize"), proc_mappings(server_pid),
                proc_status(server_pid, "Threads"));
    std::fflush(stdout);
  };
  fslam::client::SessionOptions localise;
  localise.mode = fslam::client::SessionMode::localise;
  report(0);
  for (int i = 1; i <= cycles; ++i) {
    const std::string name = "cycle" + std::to_string(i);
    if (!client.open_session(name, "cycles", 20000, &why, localise)) {
      std::fprintf(stderr, "open %s: %s\n", name.c_str(), why.c_str());
      return 1;
    }
    open.push_back(name);
    if (static_cast<int>(open.size()) > window || i == cycles) {
      while (static_cast<int>(open.size()) > (i == cycles ? 0 : window)) {
        if (!client.close_session(open.front(), 20000, &why)) {
          std::fprintf(stderr, "close %s: %s\n", open.front().c_str(), why.c_str());
          return 1;
        }
        open.pop_front();
      }
    }
    if (i % std::max(1, cycles / 10) == 0) report(i);
  }
  return 0;
}
