// fslam-gateway's settings: where it listens, who may connect, which deployment it joins.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace fslam::client::gateway {

struct GatewayOptions {
  std::string address = "127.0.0.1";  // HTTP + WebSocket; anything but loopback needs a token
  std::uint16_t port = 8090;           // 0: any free port (printed at start and to port_file)
  std::string token;                   // required of every browser when set (docs/viewer.md)
  std::string web_dir;                 // the bundled page (empty: <binary>/../viewer)
  std::string prefix = "fslam";        // the server's topic prefix
  std::string port_file;               // written with the bound port once listening (tests)
  int map_period_ms = 250;             // at most one map read per map per period
  int request_timeout_ms = 60000;      // render / segment / map export answers
  int max_viewers = 16;                // WebSocket connections at once
  int workers = 2;                     // render / segment requests forwarded at once
  bool verbose = false;                // one line per map read on stderr
};

// Parses the command line (argv without the program name). False with `why` for an unknown
// option, a bad number, or a non-loopback address without a token.
bool parse_options(const std::vector<std::string>& args, GatewayOptions* options, std::string* why,
                   bool* help);
// The --help text.
std::string usage();
// 127.0.0.0/8, ::1 and "localhost".
bool is_loopback(const std::string& address);
// The rules of docs/viewer.md "Security" on top of well-formed values.
bool is_valid(const GatewayOptions& options, std::string* why);

}  // namespace fslam::client::gateway
