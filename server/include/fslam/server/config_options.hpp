// The command-line face of the settings tables (config_fields.hpp), shared by fslam-server and
// `fslam serve` (the server's table) and `fslam run` / `fslam track` (RunConfig's, with the
// offline pipeline's defaults): --config FILE, repeatable --set key=value, and dedicated flags
// that are shorthands for one key. Layers, later wins:
//   built-in defaults < --config file < --set (in order) < dedicated flags.
#pragma once

#include <string>
#include <vector>

#include "fslam/server/server.hpp"

namespace fslam::server {
struct RunConfig;
}

namespace CLI {
class App;
}

namespace fslam::server {

// Which table a command's options are keys of.
enum class SettingsKind { server, run };

struct ConfigOptions {
  SettingsKind kind = SettingsKind::server;
  struct FlagSetting {
    std::string flag, key, value;
  };
  std::string file;                   // --config, empty: none
  std::vector<std::string> settings;  // --set key=value, in command-line order
  std::vector<FlagSetting> flags;     // dedicated flags given, in command-line order

  // Applies the layers on top of *config without validating (the caller validates once, after
  // anything else it sets). Messages name the file, the --set item or the flag.
  bool apply(ServerConfig* config, std::string* why) const;
  bool apply(RunConfig* config, std::string* why) const;
};

// The defaults of `fslam run` and `fslam track`: core's offline pipeline, no dataset overrides.
RunConfig run_defaults();

// --config and --set on `app`, writing into `options` (which must outlive parsing); `kind`
// picks the table their keys come from.
void add_config_options(CLI::App* app, ConfigOptions* options,
                        SettingsKind kind = SettingsKind::server);
// `flag VALUE` as a shorthand for `--set key=VALUE`; the help shows the default of the table
// `options` is for (add_config_options first).
void add_setting_option(CLI::App* app, const std::string& flag, const std::string& key,
                        const std::string& help, ConfigOptions* options);
// A value-less `flag` that sets `key` to `value`.
void add_setting_flag(CLI::App* app, const std::string& flag, const std::string& key,
                      const std::string& value, const std::string& help, ConfigOptions* options);

}  // namespace fslam::server
