#include "options.hpp"

#include <cerrno>
#include <cstdlib>

namespace fslam::client::gateway {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

bool to_int(const std::string& text, long lo, long hi, long* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (errno != 0 || *end != '\0' || v < lo || v > hi) return false;
  *value = v;
  return true;
}

}  // namespace

std::string usage() {
  return "fslam-gateway: the browser viewer's bridge to a featureslam server (docs/viewer.md)\n"
         "  --listen ADDR      address to serve HTTP + WebSocket on (default 127.0.0.1)\n"
         "  --port N           port (default 8090; 0 = any free one)\n"
         "  --token T          secret every browser must present (?token=T); required when\n"
         "                     ADDR is not a loopback address; $FSLAM_GATEWAY_TOKEN also sets it\n"
         "  --web DIR          the bundled page (default <binary dir>/../viewer)\n"
         "  --prefix P         the server's topic prefix (default fslam)\n"
         "  --map-period MS    at most one map read per map per MS (default 250)\n"
         "  --timeout MS       how long a render / segment / map read may take (default 60000)\n"
         "  --max-viewers N    WebSocket connections at once (default 16)\n"
         "  --port-file FILE   write the bound port to FILE once listening\n"
         "  --verbose          one line per map read on stderr\n";
}

bool is_loopback(const std::string& address) {
  return address == "localhost" || address == "::1" || address == "[::1]" ||
         address.rfind("127.", 0) == 0;
}

bool parse_options(const std::vector<std::string>& args, GatewayOptions* o, std::string* why,
                   bool* help) {
  *help = false;
  if (const char* env = std::getenv("FSLAM_GATEWAY_TOKEN")) o->token = env;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a == "-h" || a == "--help") {
      *help = true;
      return true;
    }
    if (a == "--verbose") {
      o->verbose = true;
      continue;
    }
    if (i + 1 >= args.size()) return fail(why, "option " + a + " needs a value (or is unknown)");
    const std::string& v = args[++i];
    long n = 0;
    if (a == "--listen") o->address = v;
    else if (a == "--port") {
      if (!to_int(v, 0, 65535, &n)) return fail(why, "--port: expected 0..65535, got '" + v + "'");
      o->port = static_cast<std::uint16_t>(n);
    } else if (a == "--token") o->token = v;
    else if (a == "--web") o->web_dir = v;
    else if (a == "--prefix") o->prefix = v;
    else if (a == "--port-file") o->port_file = v;
    else if (a == "--map-period") {
      if (!to_int(v, 10, 600000, &n)) return fail(why, "--map-period: expected 10..600000 ms");
      o->map_period_ms = static_cast<int>(n);
    } else if (a == "--timeout") {
      if (!to_int(v, 100, 3600000, &n)) return fail(why, "--timeout: expected 100..3600000 ms");
      o->request_timeout_ms = static_cast<int>(n);
    } else if (a == "--max-viewers") {
      if (!to_int(v, 1, 1024, &n)) return fail(why, "--max-viewers: expected 1..1024");
      o->max_viewers = static_cast<int>(n);
    } else {
      return fail(why, "unknown option " + a);
    }
  }
  return is_valid(*o, why);
}

bool is_valid(const GatewayOptions& o, std::string* why) {
  if (o.address.empty()) return fail(why, "--listen: empty address");
  if (o.prefix.empty()) return fail(why, "--prefix: empty topic prefix");
  // Beyond loopback anyone on the network could look at the maps and load the server: only
  // with a secret, and one long enough not to be guessed.
  if (!is_loopback(o.address) && o.token.size() < 16) {
    return fail(why, "--listen " + o.address + " is not a loopback address: give --token (16 or "
                     "more characters) so that only browsers that know it connect");
  }
  if (!o.token.empty() && o.token.size() < 16) return fail(why, "--token: use 16 or more characters");
  // It travels in a URL and a cookie: unreserved URL characters only, nothing to escape.
  for (const char c : o.token) {
    const bool plain = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                       c == '-' || c == '_' || c == '.' || c == '~';
    if (!plain) return fail(why, "--token: use letters, digits and - _ . ~ only");
  }
  return true;
}

}  // namespace fslam::client::gateway
