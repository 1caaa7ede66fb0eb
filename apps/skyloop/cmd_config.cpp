#include <iostream>
#include <nlohmann/json.hpp>

#include "common.hpp"

namespace skyloop::cli {

namespace {

const char* type_name(Field::Type t) {
  switch (t) {
    case Field::Type::Boolean: return "boolean";
    case Field::Type::Integer: return "integer";
    case Field::Type::Real: return "real";
    case Field::Type::Text: return "string";
    case Field::Type::Points: return "points";
    case Field::Type::Reals: return "reals";
  }
  return "?";
}

/// The one configuration table (config_fields) as JSON: key, type, default, allowed, help. The
/// documentation's configuration reference is generated from this.
std::string fields_json() {
  const Config defaults;
  nlohmann::json out = nlohmann::json::array();
  for (const auto& f : config_fields())
    out.push_back({{"key", f.key},
                   {"type", type_name(f.type)},
                   {"default", format_value(f.get(defaults))},
                   {"allowed", f.allowed()},
                   {"help", f.help}});
  return out.dump(1) + "\n";
}

std::string fields_text() {
  const Config defaults;
  std::string s;
  for (const auto& f : config_fields())
    s += f.key + " = " + format_value(f.get(defaults)) + "  (" + type_name(f.type) + "; " + f.allowed() + ")\n    " +
         f.help + "\n";
  return s;
}

}  // namespace

void add_config_command(CLI::App& app, Action& action) {
  auto* config = app.add_subcommand("config", "inspect the configuration");
  config->require_subcommand(1);
  auto* show = config->add_subcommand("show", "print the resolved configuration as TOML");
  auto opts = std::make_shared<ConfigOptions>();
  add_config_options(show, *opts);
  show->final_callback([&action, opts] {
    action = [opts] {
      std::cout << to_toml(opts->resolve());
      return 0;
    };
  });
  auto* fields = config->add_subcommand("fields", "list every configuration field: its default, type, allowed values and meaning");
  auto json = std::make_shared<bool>(false);
  fields->add_flag("--json", *json, "print a JSON array of {key, type, default, allowed, help}");
  fields->final_callback([&action, json] {
    action = [json] {
      std::cout << (*json ? fields_json() : fields_text());
      return 0;
    };
  });
}

}  // namespace skyloop::cli
