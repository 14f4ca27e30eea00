#include "fslam/server/config_fields.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "fslam/server/config_options.hpp"
#include "test_support.hpp"

namespace fslam::server {
namespace {

std::map<std::string, std::string> all_values(const ServerConfig& config) {
  std::map<std::string, std::string> values;
  for (const ConfigField& field : config_fields()) values[field.key] = field.get(config);
  return values;
}

// A value of the field's type that differs from `text` (its current value).
std::string another_value(const ConfigField& field, const std::string& text) {
  if (field.type_name == "BOOL") return text == "true" ? "false" : "true";
  if (field.type_name == "INT" || field.type_name == "UINT") return std::to_string(std::stoll(text) + 3);
  if (field.type_name == "FLOAT") {
    std::ostringstream out;
    out.precision(9);
    out << std::stod(text) * 1.5 + 0.375;
    return out.str();
  }
  if (field.type_name == "TEXT") return text + "_x";
  // An enum: type_name lists the names, a|b|c.
  std::stringstream names(field.type_name);
  std::string name;
  while (std::getline(names, name, '|'))
    if (name != text) return name;
  ADD_FAILURE() << field.key << ": no other value of " << field.type_name;
  return text;
}

// Every setting changed from its default, through the table.
ServerConfig changed_config() {
  ServerConfig config;
  for (const ConfigField& field : config_fields()) {
    std::string why;
    EXPECT_TRUE(field.set(&config, another_value(field, field.get(config)), &why)) << field.key << why;
  }
  return config;
}

std::string write_file(const std::string& name, const std::string& text) {
  const auto path = test::fresh_temp_dir("config") / name;
  std::ofstream(path) << text;
  return path.string();
}

TEST(ConfigFields, KeysAreUniqueDottedMemberPaths) {
  std::vector<std::string> keys;
  for (const ConfigField& field : config_fields()) keys.push_back(field.key);
  std::sort(keys.begin(), keys.end());
  EXPECT_EQ(std::adjacent_find(keys.begin(), keys.end()), keys.end());
  for (const char* key : {"realtime", "tracker.preprocess.stride", "tracker.gicp.kernel",
                          "tracker.preprocess.depth_noise.a", "mapper.loss.rgb_ssim",
                          "mapper.loss.pcc.block", "mapper.learning_rates.means",
                          "mapper.render.near_plane", "server.prefix", "server.queue_capacity",
                          "server.status_period_ms"}) {
    EXPECT_NE(find_config_field(key), nullptr) << key;
  }
  EXPECT_EQ(find_config_field("server.domain"), nullptr);  // a command-line choice only
}

// Each key sets its own member and no other (a copy-pasted member pointer would show), and the
// printed value parses back to the same value.
TEST(ConfigFields, EveryKeyRoundTripsAndTouchesOnlyItsMember) {
  const ServerConfig defaults;
  const auto default_values = all_values(defaults);
  for (const ConfigField& field : config_fields()) {
    ServerConfig config;
    std::string why;
    const std::string value = another_value(field, field.get(config));
    ASSERT_TRUE(set_config_value(&config, field.key, value, &why)) << field.key << ": " << why;
    const std::string printed = field.get(config);
    EXPECT_NE(printed, default_values.at(field.key)) << field.key;
    for (const auto& [key, text] : all_values(config)) {
      if (key == field.key) continue;
      EXPECT_EQ(text, default_values.at(key)) << field.key << " changed " << key;
    }
    ServerConfig reparsed;
    ASSERT_TRUE(field.set(&reparsed, printed, &why)) << field.key << ": " << why;
    EXPECT_EQ(field.get(reparsed), printed) << field.key;
  }
}

TEST(ConfigFields, NumbersRoundTripExactly) {
  ServerConfig config;
  std::string why;
  ASSERT_TRUE(set_config_value(&config, "mapper.learning_rates.means", "0.000123456789", &why)) << why;
  ASSERT_TRUE(set_config_value(&config, "tracker.gicp.lm_lambda", "1.2345678901234567e-7", &why)) << why;
  ServerConfig reparsed;
  for (const char* key : {"mapper.learning_rates.means", "tracker.gicp.lm_lambda"})
    ASSERT_TRUE(set_config_value(&reparsed, key, find_config_field(key)->get(config), &why)) << why;
  EXPECT_EQ(reparsed.pipeline.mapper.learning_rates.means, config.pipeline.mapper.learning_rates.means);
  EXPECT_EQ(reparsed.pipeline.tracker.gicp.lm_lambda, config.pipeline.tracker.gicp.lm_lambda);
}

TEST(ConfigFields, BadValuesNameTheKey) {
  ServerConfig config;
  std::string why;
  EXPECT_FALSE(set_config_value(&config, "tracker.gicp.max_iter", "5", &why));
  EXPECT_NE(why.find("unknown setting 'tracker.gicp.max_iter'"), std::string::npos) << why;
  EXPECT_NE(why.find("did you mean tracker.gicp.max_iterations?"), std::string::npos) << why;
  // The short names `fslam run --set` took before the table point at the full key.
  EXPECT_FALSE(set_config_value(&config, "loss.erank_lambda_max", "0", &why));
  EXPECT_NE(why.find("did you mean mapper.loss.erank_lambda_max?"), std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "tracker.preprocess.stride", "4.5", &why));
  EXPECT_NE(why.find("tracker.preprocess.stride: expected an integer, got '4.5'"), std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "server.queue_capacity", "-1", &why));
  EXPECT_NE(why.find("server.queue_capacity"), std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "mapper.loss.rgb_l1", "0.8x", &why));
  EXPECT_NE(why.find("mapper.loss.rgb_l1: expected a number"), std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "tracker.gicp.kernel", "tukey", &why));
  EXPECT_NE(why.find("tracker.gicp.kernel: expected one of none|huber|cauchy, got 'tukey'"),
            std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "realtime", "yes", &why));
  EXPECT_NE(why.find("realtime: expected true or false"), std::string::npos) << why;
  EXPECT_FALSE(set_config_value(&config, "tracker.gicp", "1", &why));
  EXPECT_NE(why.find("'tracker.gicp' is a group of settings"), std::string::npos) << why;
  EXPECT_FALSE(set_config_assignment(&config, "realtime", &why));
  EXPECT_NE(why.find("key=value"), std::string::npos) << why;
  // Nothing was half-applied by the failures.
  EXPECT_EQ(all_values(config), all_values(ServerConfig{}));
}

// compute.backend picks the server's rasterisers: auto by default, a name outside auto|cpu|cuda
// is refused by validation, naming the key.
TEST(ConfigFields, ComputeBackendIsAutoCpuOrCuda) {
  ServerConfig config;
  EXPECT_EQ(find_config_field("compute.backend")->get(config), "auto");
  std::string why;
  for (const char* backend : {"auto", "cpu", "cuda"}) {
    ASSERT_TRUE(set_config_value(&config, "compute.backend", backend, &why)) << why;
    EXPECT_TRUE(config.is_valid(&why)) << backend << ": " << why;
  }
  ASSERT_TRUE(set_config_value(&config, "compute.backend", "gpu", &why)) << why;
  EXPECT_FALSE(config.is_valid(&why));
  EXPECT_EQ(why, "compute.backend must be auto, cpu or cuda, not 'gpu'");
}

TEST(ConfigFile, NestedMapsSetDottedKeys) {
  const std::string path = write_file("nested.yaml", R"(# a sparse override
realtime: true
tracker.keyframe.translation: 0.1   # dotted keys work at any level
tracker:
  preprocess:
    stride: 4        # pixels
    depth_noise: {enabled: false, a: 0.002}
  gicp:
    kernel: cauchy
mapper:
  loss:
    rgb_ssim: 0.3
  learning_rates:
    means: 2e-4
  render:            # every entry commented out: sets nothing
server:
  prefix: lab
  queue_capacity: 8
)");
  ServerConfig config;
  std::string why;
  ASSERT_TRUE(load_config_file(path, &config, &why)) << why;
  EXPECT_TRUE(config.pipeline.realtime);
  EXPECT_EQ(config.pipeline.tracker.preprocess.stride, 4);
  EXPECT_FALSE(config.pipeline.tracker.preprocess.depth_noise.enabled);
  EXPECT_FLOAT_EQ(config.pipeline.tracker.preprocess.depth_noise.a, 0.002f);
  EXPECT_EQ(config.pipeline.tracker.gicp.kernel, core::RobustKernel::cauchy);
  EXPECT_DOUBLE_EQ(config.pipeline.tracker.keyframe.translation, 0.1);
  EXPECT_DOUBLE_EQ(config.pipeline.mapper.loss.rgb_ssim, 0.3);
  EXPECT_FLOAT_EQ(config.pipeline.mapper.learning_rates.means, 2e-4f);
  EXPECT_EQ(config.prefix, "lab");
  EXPECT_EQ(config.queue_capacity, 8u);
  // Untouched settings keep their defaults.
  EXPECT_EQ(config.pipeline.tracker.gicp.max_iterations, core::GicpConfig{}.max_iterations);
  EXPECT_TRUE(config.is_valid(&why)) << why;
}

TEST(ConfigFile, ErrorsNameFileLineAndKey) {
  struct Case {
    const char* yaml;
    const char* message;
  };
  for (const Case& c : {
           Case{"tracker:\n  gicp:\n    max_iter: 5\n",
                ":3: unknown setting 'tracker.gicp.max_iter' (did you mean tracker.gicp.max_iterations?)"},
           Case{"tracker:\n  preprocess:\n    stride: four\n",
                ":3: tracker.preprocess.stride: expected an integer, got 'four'"},
           Case{"tracker:\n  gicp:\n    kernel: tukey\n", "tracker.gicp.kernel: expected one of"},
           Case{"tracker:\n  gicp:\n    kernel:\n      name: huber\n",
                ":3: 'tracker.gicp.kernel' takes one value, not a map"},
           Case{"mapper:\n  render:\n    near_plane: [1, 2]\n",
                "'mapper.render.near_plane' takes one value, not a list"},
           Case{"mapper:\n  min_depth:\n", "'mapper.min_depth' has no value"},
           Case{"tracker: 3\n", "'tracker' is a group of settings"},
           Case{"[1, 2]\n", "expected a map of settings"},
           Case{"tracker: {gicp: \n", "bad.yaml:"},  // a YAML syntax error, with its line
       }) {
    const std::string path = write_file("bad.yaml", c.yaml);
    ServerConfig config;
    std::string why;
    EXPECT_FALSE(load_config_file(path, &config, &why)) << c.yaml;
    EXPECT_EQ(why.rfind(path, 0), 0u) << why;  // starts with the file
    EXPECT_NE(why.find(c.message), std::string::npos) << "got: " << why;
  }
  ServerConfig config;
  std::string why;
  EXPECT_FALSE(load_config_file("/nonexistent/x.yaml", &config, &why));
  EXPECT_NE(why.find("/nonexistent/x.yaml: cannot read"), std::string::npos) << why;
  EXPECT_TRUE(load_config_file(write_file("empty.yaml", "# nothing\n"), &config, &why)) << why;
}

// Loading does not validate: a file may move max_depth below the default min_depth before it
// sets min_depth; the caller validates once at the end.
TEST(ConfigFile, ValidatesOnlyAtTheEnd) {
  const std::string path = write_file("order.yaml",
                                      "tracker:\n  preprocess:\n    max_depth: 0.2\n    min_depth: 0.1\n");
  ServerConfig config;
  std::string why;
  ASSERT_TRUE(load_config_file(path, &config, &why)) << why;
  EXPECT_TRUE(config.is_valid(&why)) << why;
}

TEST(EffectiveConfig, PrintsNestedYamlThatReloadsIdentically) {
  const ServerConfig config = changed_config();
  const std::string yaml = effective_config_yaml(config);
  EXPECT_NE(yaml.find("\ntracker:\n  constant_velocity: true\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("\n  preprocess:\n    min_depth: 0.825\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("server:\n"), std::string::npos) << yaml;
  ServerConfig reloaded;
  std::string why;
  ASSERT_TRUE(load_config_file(write_file("effective.yaml", yaml), &reloaded, &why)) << why;
  EXPECT_EQ(all_values(reloaded), all_values(config));
  // The defaults too, and text that YAML would otherwise read as something else.
  for (const char* prefix : {"", "null", "~", "true", "12", "a: b", " padded", "#x"}) {
    ServerConfig text_config;
    text_config.prefix = prefix;
    ServerConfig text_reloaded;
    ASSERT_TRUE(load_config_file(write_file("text.yaml", effective_config_yaml(text_config)),
                                 &text_reloaded, &why))
        << "prefix '" << prefix << "': " << why;
    EXPECT_EQ(text_reloaded.prefix, prefix);
  }
}

// defaults < --config < --set (in order) < dedicated flags.
TEST(ConfigOptions, LayersApplyInOrder) {
  ConfigOptions options;
  options.file = write_file("layer.yaml", "tracker:\n  preprocess:\n    stride: 2\n    voxel_size: 0.01\n"
                                          "mapper:\n  sh_degree: 1\n");
  options.settings = {"tracker.preprocess.stride=3", "tracker.preprocess.stride=5",
                      "mapper.sh_degree=2"};
  options.flags = {{"--sh-degree", "mapper.sh_degree", "3"}};
  ServerConfig config;
  std::string why;
  ASSERT_TRUE(options.apply(&config, &why)) << why;
  EXPECT_FLOAT_EQ(config.pipeline.tracker.preprocess.voxel_size, 0.01f);  // file
  EXPECT_EQ(config.pipeline.tracker.preprocess.stride, 5);                // last --set
  EXPECT_EQ(config.pipeline.mapper.sh_degree, 3);                         // flag

  options.settings = {"mapper.sh_degre=2"};
  EXPECT_FALSE(options.apply(&config, &why));
  EXPECT_NE(why.find("--set: unknown setting 'mapper.sh_degre'"), std::string::npos) << why;
  options.settings.clear();
  options.flags = {{"--stride", "tracker.preprocess.stride", "x"}};
  EXPECT_FALSE(options.apply(&config, &why));
  EXPECT_NE(why.find("--stride: tracker.preprocess.stride: expected an integer"), std::string::npos)
      << why;
}

TEST(ConfigPresets, EveryPresetLoadsAndValidates) {
  const std::filesystem::path dir = std::filesystem::path(FSLAM_TEST_CONFIGS_DIR) / "presets";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  int presets = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    ServerConfig config;
    std::string why;
    ASSERT_TRUE(load_config_file(entry.path().string(), &config, &why)) << why;
    EXPECT_TRUE(config.is_valid(&why)) << entry.path() << ": " << why;
    ++presets;
  }
  EXPECT_GE(presets, 3);
}

}  // namespace
}  // namespace fslam::server
