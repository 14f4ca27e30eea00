// The command-line face of the settings table (config_fields.hpp), shared by fslam-server,
// `fslam serve`, `fslam run` and `fslam track`: --config FILE, repeatable --set key=value, and
// dedicated flags that are shorthands for one key. Layers, later wins:
//   built-in defaults < --config file < --set (in order) < dedicated flags.
#pragma once

#include <string>
#include <vector>

#include "fslam/server/server.hpp"

namespace CLI {
class App;
}

namespace fslam::server {

struct ConfigOptions {
  struct FlagSetting {
    std::string flag, key, value;
  };
  std::string file;                   // --config, empty: none
  std::vector<std::string> settings;  // --set key=value, in command-line order
  std::vector<FlagSetting> flags;     // dedicated flags given, in command-line order

  // Applies the layers on top of *config without validating (the caller validates once, after
  // anything else it sets). Messages name the file, the --set item or the flag.
  bool apply(ServerConfig* config, std::string* why) const;
};

// --config and --set on `app`, writing into `options` (which must outlive parsing).
void add_config_options(CLI::App* app, ConfigOptions* options);
// `flag VALUE` as a shorthand for `--set key=VALUE`; the help shows the built-in default.
void add_setting_option(CLI::App* app, const std::string& flag, const std::string& key,
                        const std::string& help, ConfigOptions* options);
// A value-less `flag` that sets `key` to `value`.
void add_setting_flag(CLI::App* app, const std::string& flag, const std::string& key,
                      const std::string& value, const std::string& help, ConfigOptions* options);

}  // namespace fslam::server
