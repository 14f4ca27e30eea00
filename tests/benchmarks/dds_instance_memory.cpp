// DDS instance memory (opt-in benchmark, docs/reliability.md "Soak"): a PoseStamped writer
// publishing at a fixed rate, with the server's QoS (`--writer bounded`: keep all, up to 4096
// unacknowledged) or the keep-last one it had before (`--writer keep-last`: Delivery::stream),
// and a reader in a second process taking everything, both printing resident memory every 5 s. `--keys one` writes one
// session, as the protocol does; `--keys per-sample` gives every sample its own session key, as a
// key per frame did before 5139b45 (Cyclone keeps every instance a writer wrote for its life).
// Run with CYCLONEDDS_URI set to configs/dds/loopback.xml.
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>

#include "fslam/client/dds.hpp"
#include "fslam/proto/types.h"
#include "proc_status.hpp"

namespace {

using Clock = std::chrono::steady_clock;

long resident_kib() { return fslam::bench::proc_status("self", "VmRSS"); }

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("Resident memory of a PoseStamped writer and reader over time");
  std::string keys = "one", writer_qos = "bounded";
  int seconds = 30, rate = 500;
  app.add_option("--keys", keys, "one (a session) or per-sample (a new key per sample)")
      ->check(CLI::IsMember({"one", "per-sample"}));
  app.add_option("--writer", writer_qos, "bounded (the server's) or keep-last (Delivery::stream)")
      ->check(CLI::IsMember({"bounded", "keep-last"}));
  app.add_option("--seconds", seconds, "How long to publish")->check(CLI::Range(1, 3600));
  app.add_option("--rate", rate, "Samples per second")->check(CLI::Range(1, 100000));
  CLI11_PARSE(app, argc, argv);
  using namespace fslam::client;
  const std::string prefix = "ddsmem" + std::to_string(getpid());
  const pid_t child = fork();
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  Entity topic = make_topic(participant, &fslam_proto_PoseStamped_desc, prefix, "poses");
  const auto report = [&](const char* who, int t, long n) {
    std::printf("%s writer=%s keys=%s t=%ds samples=%ld resident=%ld KiB\n", who, writer_qos.c_str(), keys.c_str(), t,
                n, resident_kib());
    std::fflush(stdout);
  };
  if (child == 0) {
    Entity reader = make_reader(participant, topic, Delivery::stream);
    const auto t0 = Clock::now();
    long n = 0;
    for (int next = 5; next <= seconds + 5;) {
      const int taken = take_each<fslam_proto_PoseStamped>(reader.get(), [&](const fslam_proto_PoseStamped&) { ++n; });
      if (taken == 0) std::this_thread::sleep_for(std::chrono::milliseconds(2));
      if (std::chrono::duration<double>(Clock::now() - t0).count() >= next) report("reader", next, n), next += 5;
    }
    return 0;
  }
  Entity writer = writer_qos == "bounded" ? make_bounded_writer(participant, topic, 4096)
                                          : make_writer(participant, topic, Delivery::stream);
  std::this_thread::sleep_for(std::chrono::seconds(2));  // discovery
  const auto t0 = Clock::now();
  char note[] = "";
  long n = 0;
  for (int next = 5; next <= seconds; ++n) {
    const std::string session = keys == "one" ? "s" : "s" + std::to_string(n);
    fslam_proto_PoseStamped pose{};
    pose.session = const_cast<char*>(session.c_str());
    pose.frame_id = static_cast<std::uint64_t>(n);
    pose.note = note;
    pose.T_world_camera.rotation[3] = 1.0;
    dds_write(writer.get(), &pose);
    if (std::chrono::duration<double>(Clock::now() - t0).count() >= next) report("writer", next, n), next += 5;
    std::this_thread::sleep_until(t0 + std::chrono::microseconds(1000000L * (n + 1) / rate));
  }
  waitpid(child, nullptr, 0);
  return 0;
}
