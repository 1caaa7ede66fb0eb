#include <algorithm>
#include <optional>
#include <sstream>
#include <toml++/toml.h>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {
namespace {

std::string describe(const toml::node& node) {
  std::ostringstream ss;
  if (node.is_string()) ss << '"' << *node.value<std::string>() << '"';
  else node.visit([&](auto&& n) { ss << n; });
  return ss.str();
}

std::optional<double> number(const toml::node* n) {
  if (!n) return std::nullopt;
  if (auto d = n->value_exact<double>()) return *d;
  if (auto i = n->value_exact<std::int64_t>()) return static_cast<double>(*i);
  return std::nullopt;
}

/// A TOML array of [x, y] number pairs; `bad` receives the index of the first malformed item.
std::optional<std::vector<Point2>> points(const toml::node& node, std::size_t* bad = nullptr) {
  const auto* arr = node.as_array();
  if (!arr) return std::nullopt;
  std::vector<Point2> pts;
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const auto* pair = arr->get(i)->as_array();
    std::optional<double> x, y;
    if (pair && pair->size() == 2) x = number(pair->get(0)), y = number(pair->get(1));
    if (!x || !y) {
      if (bad) *bad = i;
      return std::nullopt;
    }
    pts.push_back({*x, *y});
  }
  return pts;
}

std::string one_line(std::string s) {
  for (auto& ch : s)
    if (ch == '\n' || ch == '\r') ch = ' ';
  return s;
}

toml::table parse_document(const std::string& text, const std::string& source) {
  try {
    return toml::parse(text, source);
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw InputError(source + ":" + std::to_string(b.line) + ":" + std::to_string(b.column) +
                     ": invalid TOML: " + one_line(std::string(e.description())));
  }
}

/// Converts a TOML node to the FieldValue the field expects; a node of no known shape is
/// rejected here, one of another shape by set_field(), both with the field's rule.
FieldValue to_value(const Field& field, const toml::node& node) {
  if (auto v = node.value_exact<bool>()) return *v;
  if (auto v = node.value_exact<std::int64_t>()) return *v;
  if (auto v = node.value_exact<double>()) return *v;
  if (auto v = node.value_exact<std::string>()) return *v;
  if (field.type == Field::Type::Reals) {
    if (const auto* arr = node.as_array()) {
      std::vector<double> r;
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const auto x = number(arr->get(i));
        if (!x) throw InputError(field.key + " = " + describe(node) + " has the wrong type: allowed " + field.allowed());
        r.push_back(*x);
      }
      return r;
    }
  }
  if (auto p = points(node)) return *p;
  throw InputError(field.key + " = " + describe(node) + " has the wrong type: allowed " + field.allowed());
}

[[noreturn]] void throw_unknown_key(const std::string& key) {
    std::string section = key.substr(0, key.find('.'));
    std::string known;
    for (const auto& f : config_fields())
      if (f.key.rfind(section + ".", 0) == 0) known += (known.empty() ? "" : ", ") + f.key.substr(section.size() + 1);
    throw InputError("unknown key '" + key + "'" +
                     (known.empty() ? std::string(": no such section") : ": allowed keys in [" + section + "] are " + known));
}

void apply_node(Config& cfg, const std::string& key, const toml::node& node) {
  const Field* field = find_field(key);
  if (!field) throw_unknown_key(key);
  set_field(cfg, *field, to_value(*field, node));
}

void apply_table(Config& cfg, const toml::table& table, const std::string& prefix) {
  for (const auto& [k, node] : table) {
    const std::string key = prefix.empty() ? std::string(k.str()) : prefix + "." + std::string(k.str());
    if (const auto* sub = node.as_table(); sub && prefix.empty()) apply_table(cfg, *sub, key);
    else apply_node(cfg, key, node);
  }
}

}  // namespace

void apply_toml(Config& cfg, const std::string& text, const std::string& source) {
  apply_table(cfg, parse_document(text, source), "");
}

std::vector<std::vector<Point2>> read_point_lists(const std::string& text, const std::string& source,
                                                  const std::vector<std::string>& allowed) {
  const toml::table t = parse_document(text, source);
  std::string names;
  for (const auto& a : allowed) names += (names.empty() ? "" : ", ") + a;
  for (const auto& [k, v] : t)
    if (std::find(allowed.begin(), allowed.end(), std::string(k.str())) == allowed.end())
      throw InputError(source + ": unknown key '" + std::string(k.str()) + "': allowed " + names);
  std::vector<std::vector<Point2>> out;
  for (const auto& key : allowed) {
    const toml::node* node = t.get(key);
    std::size_t bad = 0;
    const auto pts = node ? points(*node, &bad) : std::nullopt;
    if (node && !pts && node->is_array())
      throw InputError(source + ": " + key + "[" + std::to_string(bad) + "] is not an [x, y] pair of numbers");
    if (!pts || pts->empty())
      throw InputError(source + ": " + key + " is missing or empty: allowed a non-empty list of [x, y] pairs in metres");
    out.push_back(*pts);
  }
  return out;
}

void apply_override(Config& cfg, const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw InputError("--set '" + assignment + "' is malformed: allowed section.name=value");
  const std::string key = assignment.substr(0, eq);
  const std::string value = assignment.substr(eq + 1);
  const Field* field = find_field(key);
  if (!field) throw_unknown_key(key);
  if (value.find_first_not_of(" \t") == std::string::npos)
    throw InputError(key + " has no value in --set '" + assignment + "': allowed " + field->allowed());
  toml::table parsed;
  try {
    parsed = toml::parse("v = " + value);
  } catch (const toml::parse_error&) {
    // A decimal integer TOML cannot hold (beyond 64 bits) is a number out of range, not a word.
    if (value.find_first_not_of("+-0123456789_") == std::string::npos && value.find_first_of("0123456789") != std::string::npos)
      throw InputError(key + " = " + value + " is out of range: allowed " + field->allowed());
    // Not a TOML value: a bare word is a string (e.g. power_scaling=cap).
    parsed = toml::table{{"v", value}};
  }
  // "50 # x" parses as 50 and a comment: a value is the whole text after '=', nothing dropped.
  if (value.find('#') != std::string::npos && !parsed.get("v")->is_string())
    throw InputError(key + " = '" + value + "' is malformed: a '#' starts a comment here; allowed " + field->allowed());
  set_field(cfg, *field, to_value(*field, *parsed.get("v")));
}

void finalise_users_file(Config& cfg) {
  if (cfg.env.users_file.empty()) return;
  // The users come from the file: K is its count, in the config and every report.
  const auto lists = read_point_lists(read_file(cfg.env.users_file, "env.users_file"), cfg.env.users_file, {"users"});
  const Field* users = find_field("scenario.users");
  const auto k = static_cast<std::int64_t>(lists[0].size());
  if (k < users->lo || k > users->hi)
    throw InputError("env.users_file = " + cfg.env.users_file + " has " + std::to_string(k) + " users: allowed " + users->allowed());
  cfg.scenario.users = static_cast<int>(k);
}

Config resolve_config(const std::optional<std::string>& path, const std::vector<std::string>& overrides) {
  Config cfg;
  if (path) apply_toml(cfg, read_file(*path, "config file"), *path);
  for (const auto& o : overrides) apply_override(cfg, o);
  finalise(cfg);
  finalise_users_file(cfg);
  return cfg;
}

Positions positions_in_area(const std::vector<Point2>& pts, const Config& cfg, const std::string& what) {
  Positions p(static_cast<Eigen::Index>(pts.size()), 2);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const auto [x, y] = pts[i];
    if (!(x >= 0 && x <= cfg.scenario.area_x_m && y >= 0 && y <= cfg.scenario.area_y_m))  // NaN fails too
      throw InputError(what + "[" + std::to_string(i) + "] = [" + format_double(x) + ", " + format_double(y) +
                       "] is outside the area: allowed x in [0, " + format_double(cfg.scenario.area_x_m) + "], y in [0, " +
                       format_double(cfg.scenario.area_y_m) + "]");
    p(static_cast<Eigen::Index>(i), 0) = x;
    p(static_cast<Eigen::Index>(i), 1) = y;
  }
  return p;
}

std::uint64_t parse_count(const std::string& flag, const std::string& text, std::uint64_t lo, std::uint64_t hi) {
  const auto fail = [&] {
    throw InputError(flag + " = '" + text + "' is invalid: allowed an integer in [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "]");
  };
  if (text.empty() || text.size() > 19 || text.find_first_not_of("0123456789") != std::string::npos) fail();
  const std::uint64_t v = std::stoull(text);  // at most 19 digits: no overflow
  if (v < lo || v > hi) fail();
  return v;
}

std::uint64_t parse_seed(const std::string& flag, const std::string& text) {
  const Field* seed = find_field("run.seed");
  const auto hi = static_cast<std::uint64_t>(seed->hi);
  const auto fail = [&] { throw InputError(flag + " = '" + text + "' is invalid: allowed " + seed->allowed()); };
  if (text.empty() || text.size() > 19 || text.find_first_not_of("0123456789") != std::string::npos) fail();
  const std::uint64_t v = std::stoull(text);  // at most 19 digits: no overflow
  if (v > hi) fail();
  return v;
}

std::string to_toml(const Config& cfg) {
  std::ostringstream out;
  std::string section;
  for (const auto& f : config_fields()) {
    const auto dot = f.key.find('.');
    const std::string sec = f.key.substr(0, dot);
    if (sec != section) {
      out << (section.empty() ? "" : "\n") << "[" << sec << "]\n";
      section = sec;
    }
    out << f.key.substr(dot + 1) << " = " << format_value(f.get(cfg)) << "  # " << f.help << "; " << f.allowed()
        << "\n";
  }
  return out.str();
}

}  // namespace skyloop
