// The one table of settings: every scalar of ServerConfig (core::PipelineConfig included) under a
// dotted key that mirrors its member path (`tracker.gicp.kernel`, `mapper.loss.rgb_ssim`,
// `server.queue_capacity`). YAML files, `--set key=value`, dedicated flags and the printed
// effective configuration all go through it, so a setting is added in one place
// (src/config_fields.cpp). Nothing here validates: callers apply every layer, then call
// ServerConfig::is_valid once (a file may set min_depth before max_depth).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "fslam/server/server.hpp"

namespace fslam::server {

struct ConfigField {
  std::string key;        // dotted member path
  std::string type_name;  // for help texts: BOOL, INT, UINT, FLOAT, TEXT or a|b|c
  // Parses `text` into the field; false with `why` ("expected ..., got '...'") when it does not.
  std::function<bool(ServerConfig*, const std::string& text, std::string* why)> set;
  // The value as text that `set` parses back to the same value (numbers exactly).
  std::function<std::string(const ServerConfig&)> get;
};

// Every setting, in the order the effective configuration prints them.
const std::vector<ConfigField>& config_fields();
// nullptr for an unknown key.
const ConfigField* find_config_field(const std::string& key);

// Sets one setting; the message names the key and, for an unknown one, the nearest known key.
bool set_config_value(ServerConfig* config, const std::string& key, const std::string& value,
                      std::string* why);
// `key=value`, as `--set` takes it.
bool set_config_assignment(ServerConfig* config, const std::string& assignment, std::string* why);

// Applies a YAML file of sparse overrides: nested maps are flattened to dotted keys. An unknown
// key, a map or list where one value belongs, or a value that does not parse is an error naming
// the file, line and key.
bool load_config_file(const std::string& path, ServerConfig* config, std::string* why);

// Every setting as nested YAML (the format load_config_file reads back to the same config).
std::string effective_config_yaml(const ServerConfig& config);

}  // namespace fslam::server
