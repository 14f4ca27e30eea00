// The tables of settings: every scalar of a config struct under a dotted key that mirrors its
// member path (`tracker.gicp.kernel`, `mapper.loss.rgb_ssim`, `server.queue_capacity`). YAML
// files, `--set key=value`, dedicated flags and the printed effective configuration all go
// through them, so a setting is added in one place (src/config_fields.cpp). Three tables, one
// set of keys:
//   pipeline_settings(): core::PipelineConfig (tracker.*, mapper.*, features.*, realtime, ...);
//   run_settings():      RunConfig of `fslam run` / `fslam track` = the pipeline's + dataset.*;
//   config_fields():     ServerConfig = the pipeline's + server.* + dataset.*.
// Nothing here validates: callers apply every layer, then call is_valid once (a file may set
// min_depth before max_depth).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/server/server.hpp"

namespace fslam::server {

template <class Config>
struct Setting {
  std::string key;        // dotted member path
  std::string type_name;  // for help texts: BOOL, INT, UINT, FLOAT, TEXT or a|b|c
  // Parses `text` into the field; false with `why` ("expected ..., got '...'") when it does not.
  std::function<bool(Config*, const std::string& text, std::string* why)> set;
  // The value as text that `set` parses back to the same value (numbers exactly).
  std::function<std::string(const Config&)> get;
};
template <class Config>
using SettingsTable = std::vector<Setting<Config>>;

// What the offline commands (`fslam run`, `fslam track`) read: the pipeline with its offline
// defaults (the server's are real-time ones) and the recording's cameras.
struct RunConfig {
  core::PipelineConfig pipeline;
  DatasetSettings dataset;
};

using ConfigField = Setting<ServerConfig>;

// Every setting of each table, in the order the effective configuration prints them.
const SettingsTable<core::PipelineConfig>& pipeline_settings();
const SettingsTable<RunConfig>& run_settings();
const std::vector<ConfigField>& config_fields();

// The table of a config type (overloads, so the functions below work on any of them).
inline const SettingsTable<core::PipelineConfig>& settings_of(const core::PipelineConfig*) {
  return pipeline_settings();
}
inline const SettingsTable<RunConfig>& settings_of(const RunConfig*) { return run_settings(); }
inline const SettingsTable<ServerConfig>& settings_of(const ServerConfig*) { return config_fields(); }

// nullptr for an unknown key.
template <class Config>
const Setting<Config>* find_setting(const SettingsTable<Config>& table, const std::string& key);
inline const ConfigField* find_config_field(const std::string& key) {
  return find_setting(config_fields(), key);
}

// Sets one setting; the message names the key and, for an unknown one, the nearest known key.
// Defined for ServerConfig, RunConfig and core::PipelineConfig.
template <class Config>
bool set_config_value(Config* config, const std::string& key, const std::string& value,
                      std::string* why);
// `key=value`, as `--set` takes it.
template <class Config>
bool set_config_assignment(Config* config, const std::string& assignment, std::string* why);

// Applies a YAML file of sparse overrides: nested maps are flattened to dotted keys. An unknown
// key, a map or list where one value belongs, or a value that does not parse is an error naming
// the file, line and key.
template <class Config>
bool load_config_file(const std::string& path, Config* config, std::string* why);

// Every setting as nested YAML (the format load_config_file reads back to the same config).
template <class Config>
std::string effective_config_yaml(const Config& config);

}  // namespace fslam::server
