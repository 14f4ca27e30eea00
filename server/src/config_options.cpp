#include "fslam/server/config_options.hpp"

#include <stdexcept>

#include <CLI/CLI.hpp>

#include "fslam/core/error.hpp"
#include "fslam/server/config_fields.hpp"

namespace fslam::server {

namespace {

template <class Config>
bool apply_layers(const ConfigOptions& options, Config* config, std::string* why) {
  if (!options.file.empty() && !load_config_file(options.file, config, why)) return false;
  std::string reason;
  for (const std::string& item : options.settings)
    if (!set_config_assignment(config, item, &reason)) return core::fail(why, "--set: " + reason);
  for (const ConfigOptions::FlagSetting& f : options.flags)
    if (!set_config_value(config, f.key, f.value, &reason)) return core::fail(why, f.flag + ": " + reason);
  return true;
}

// The type and default of `key` in the table `kind` names; false for an unknown key.
bool describe(SettingsKind kind, const std::string& key, std::string* type_name, std::string* value) {
  if (kind == SettingsKind::run) {
    const Setting<RunConfig>* field = find_setting(run_settings(), key);
    if (field == nullptr) return false;
    *type_name = field->type_name;
    *value = field->get(run_defaults());
    return true;
  }
  const ConfigField* field = find_config_field(key);
  if (field == nullptr) return false;
  *type_name = field->type_name;
  *value = field->get(ServerConfig{});
  return true;
}

}  // namespace

bool ConfigOptions::apply(ServerConfig* config, std::string* why) const {
  return apply_layers(*this, config, why);
}

bool ConfigOptions::apply(RunConfig* config, std::string* why) const {
  return apply_layers(*this, config, why);
}

RunConfig run_defaults() { return RunConfig{}; }

void add_config_options(CLI::App* app, ConfigOptions* options, SettingsKind kind) {
  options->kind = kind;
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
  std::string type_name, default_value;
  if (!describe(options->kind, key, &type_name, &default_value))
    throw std::logic_error("add_setting_option: no setting '" + key + "'");
  app->add_option_function<std::string>(
         flag, [options, flag, key](const std::string& value) {
           options->flags.push_back({flag, key, value});
         },
         help + " (" + key + ")")
      ->type_name(type_name)
      ->default_str(default_value);
}

void add_setting_flag(CLI::App* app, const std::string& flag, const std::string& key,
                      const std::string& value, const std::string& help, ConfigOptions* options) {
  std::string type_name, default_value;
  if (!describe(options->kind, key, &type_name, &default_value))
    throw std::logic_error("add_setting_flag: no setting '" + key + "'");
  app->add_flag_callback(
      flag, [options, flag, key, value] { options->flags.push_back({flag, key, value}); },
      help + " (" + key + "=" + value + ")");
}

}  // namespace fslam::server
