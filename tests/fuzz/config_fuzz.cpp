// Fuzz target: the YAML configuration layer (--config files and configs/presets), then the
// validation every layer ends with. A file that loads and validates must print as YAML that
// loads back to the same settings.
#include <cstdint>
#include <string>

#include "fslam/server/config_fields.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fslam::fuzz::write_scratch("config.yaml", data, size);
  fslam::server::ServerConfig config;
  std::string why;
  if (!fslam::server::load_config_file(path, &config, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  if (!config.is_valid(&why)) return 0;
  const std::string printed = fslam::server::effective_config_yaml(config);
  const std::string again = fslam::fuzz::write_scratch(
      "printed.yaml", reinterpret_cast<const std::uint8_t*>(printed.data()), printed.size());
  fslam::server::ServerConfig reloaded;
  if (!fslam::server::load_config_file(again, &reloaded, &why)) __builtin_trap();
  if (fslam::server::effective_config_yaml(reloaded) != printed) __builtin_trap();
  return 0;
}
