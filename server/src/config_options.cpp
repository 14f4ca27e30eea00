#include "fslam/server/config_options.hpp"

#include <stdexcept>

#include <CLI/CLI.hpp>

#include "fslam/core/error.hpp"
#include "fslam/server/config_fields.hpp"

namespace fslam::server {

bool ConfigOptions::apply(ServerConfig* config, std::string* why) const {
  if (!file.empty() && !load_config_file(file, config, why)) return false;
  std::string reason;
  for (const std::string& item : settings)
    if (!set_config_assignment(config, item, &reason)) return core::fail(why, "--set: " + reason);
  for (const FlagSetting& f : flags)
    if (!set_config_value(config, f.key, f.value, &reason)) return core::fail(why, f.flag + ": " + reason);
  return true;
}

void add_config_options(CLI::App* app, ConfigOptions* options) {
  app->add_option("--config", options->file,
                  "YAML file of settings overriding the defaults (docs/configuration.md)")
      ->type_name("FILE");
  app->add_option("--set", options->settings,
                  "Override one setting, key=value (e.g. tracker.gicp.kernel=cauchy); repeatable, "
                  "applied after --config, before dedicated flags")
      ->type_name("KEY=VALUE");
}

void add_setting_option(CLI::App* app, const std::string& flag, const std::string& key,
                        const std::string& help, ConfigOptions* options) {
  const ConfigField* field = find_config_field(key);
  if (!field) throw std::logic_error("add_setting_option: no setting '" + key + "'");
  app->add_option_function<std::string>(
         flag, [options, flag, key](const std::string& value) {
           options->flags.push_back({flag, key, value});
         },
         help + " (" + key + ")")
      ->type_name(field->type_name)
      ->default_str(field->get(ServerConfig{}));
}

void add_setting_flag(CLI::App* app, const std::string& flag, const std::string& key,
                      const std::string& value, const std::string& help, ConfigOptions* options) {
  if (!find_config_field(key)) throw std::logic_error("add_setting_flag: no setting '" + key + "'");
  app->add_flag_callback(
      flag, [options, flag, key, value] { options->flags.push_back({flag, key, value}); },
      help + " (" + key + "=" + value + ")");
}

}  // namespace fslam::server
