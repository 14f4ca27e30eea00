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
#include "proc_status.hpp"

namespace {

// Lines of /proc/PID/maps: the process's memory mappings.
long proc_mappings(const std::string& pid) {
  std::ifstream maps("/proc/" + pid + "/maps");
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
  using fslam::bench::proc_status;
  const std::string pid = std::to_string(server_pid);
  const auto report = [&](int done) {
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("cycles=%d t=%.0fs resident=%ld KiB virtual=%ld KiB mappings=%ld threads=%ld\n", done, s,
                proc_status(pid, "VmRSS"), proc_status(pid, "VmSize"), proc_mappings(pid), proc_status(pid, "Threads"));
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
