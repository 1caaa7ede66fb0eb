// Experiment files (configs/experiments/*.toml): parsing and validation.
#include <algorithm>
#include <filesystem>
#include <set>
#include <sstream>
#include <toml++/toml.h>

#include "toml_document.hpp"

#include "skyloop/marl/learners.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/channel/path_loss.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/paths.hpp"
#include "skyloop/experiments/reproduce.hpp"
#include "skyloop/core/text.hpp"

namespace skyloop {

std::string source_dir() { return data_dir(); }

namespace {

const std::vector<std::string> kKeys = {"name",  "kind",   "figure", "title", "config", "set",   "models", "reuse_shipped",
                                        "sweep", "values", "methods", "samples", "train_layouts", "seed", "algos", "seeds",
                                        "steps", "users",  "planners", "one_policy", "rollout", "series", "series_values"};

std::string describe(const toml::node& node) {
  std::ostringstream ss;
  if (node.is_string()) ss << '"' << *node.value<std::string>() << '"';
  else node.visit([&](auto&& n) { ss << n; });
  std::string s = ss.str();
  std::replace(s.begin(), s.end(), '\n', ' ');
  return s;
}

struct Reader {
  std::string source;

  [[noreturn]] void bad(const std::string& key, const toml::node& n, const std::string& allowed) const {
    throw InputError(source + ": " + key + " = " + describe(n) + " is invalid: allowed " + allowed);
  }
  std::string text(const std::string& key, const toml::node& n) const {
    if (auto v = n.value_exact<std::string>()) return *v;
    bad(key, n, "a string");
  }
  std::int64_t integer(const std::string& key, const toml::node& n, std::int64_t lo, std::int64_t hi) const {
    std::optional<std::int64_t> v = n.value_exact<std::int64_t>();
    if (!v) {
      if (auto d = n.value_exact<double>(); d && *d == static_cast<double>(static_cast<std::int64_t>(*d)))
        v = static_cast<std::int64_t>(*d);  // 2e6
    }
    if (!v || *v < lo || *v > hi) bad(key, n, "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return *v;
  }
  double number(const std::string& key, const toml::node& n) const {
    if (auto v = n.value_exact<double>()) return *v;
    if (auto v = n.value_exact<std::int64_t>()) return static_cast<double>(*v);
    bad(key, n, "a number");
  }
  const toml::array& array(const std::string& key, const toml::node& n, const std::string& of) const {
    const auto* a = n.as_array();
    if (!a || a->empty()) bad(key, n, "a non-empty list of " + of);
    return *a;
  }
  std::vector<std::string> texts(const std::string& key, const toml::node& n, bool allow_empty = false) const {
    std::vector<std::string> out;
    if (allow_empty && n.as_array() && n.as_array()->empty()) return out;
    for (const auto& x : array(key, n, "strings")) {
      const auto v = x.value_exact<std::string>();
      if (!v) bad(key, n, "a list of strings");
      out.push_back(*v);
    }
    return out;
  }
};

void apply_table(ExperimentSpec& s, const toml::table& t, const Reader& r, const std::string& where, bool append_set) {
  for (const auto& [k, node] : t) {
    const std::string key(k.str());
    const std::string full = where + "." + key;
    if (key == "name") s.name = r.text(full, node);
    else if (key == "kind") s.kind = r.text(full, node);
    else if (key == "figure") s.figure = r.text(full, node);
    else if (key == "title") s.title = r.text(full, node);
    else if (key == "config") {
      // Relative to the experiment file, so that a copy of configs/ works from anywhere.
      const std::string given = r.text(full, node);
      const auto path = std::filesystem::path(r.source).parent_path() / given;
      if (given.empty() || !std::filesystem::is_regular_file(path))
        r.bad(full, node, "a configuration file relative to the experiment file (" + path.lexically_normal().string() + " is not one)");
      s.config = path.lexically_normal().string();
      try {  // a bad field of the file fails here, at load, naming both files
        Config check;
        apply_toml(check, read_file(s.config, "config file"), s.config);
      } catch (const InputError& e) {
        const std::string what = e.what();
        throw InputError(r.source + ": " + full + " = \"" + given + "\": " +
                         (what.rfind(s.config, 0) == 0 ? what : s.config + ": " + what));
      }
    }
    else if (key == "set") {
      auto v = r.texts(full, node, true);
      if (!append_set) s.set.clear();
      s.set.insert(s.set.end(), v.begin(), v.end());
    } else if (key == "models") s.models = r.texts(full, node);
    else if (key == "reuse_shipped") {
      const auto b = node.value_exact<bool>();
      if (!b) r.bad(full, node, "true or false");
      s.reuse_shipped = *b;
    } else if (key == "one_policy") {
      const auto b = node.value_exact<bool>();
      if (!b) r.bad(full, node, "true or false");
      s.one_policy = *b;
    } else if (key == "rollout") {
      const auto b = node.value_exact<bool>();
      if (!b) r.bad(full, node, "true or false");
      s.rollout = *b;
    } else if (key == "sweep") s.sweep = r.text(full, node);
    else if (key == "values") {
      s.values.clear();
      for (const auto& x : r.array(full, node, "numbers or names"))
        s.values.push_back(x.is_string() ? r.text(full, x) : format_double(r.number(full, x)));
    } else if (key == "series") s.series = r.text(full, node);
    else if (key == "series_values") {
      s.series_values.clear();
      for (const auto& x : r.array(full, node, "numbers or names"))
        s.series_values.push_back(x.is_string() ? r.text(full, x) : format_double(r.number(full, x)));
    } else if (key == "methods") s.methods = r.texts(full, node);
    else if (key == "samples") s.samples = static_cast<int>(r.integer(full, node, 1, 1'000'000));
    else if (key == "train_layouts") s.train_layouts = static_cast<int>(r.integer(full, node, 0, 1'000'000));
    else if (key == "seed") s.seed = static_cast<std::uint64_t>(r.integer(full, node, 0, INT64_MAX));
    else if (key == "algos") s.algos = r.texts(full, node);
    else if (key == "seeds") {
      s.seeds.clear();
      for (const auto& x : r.array(full, node, "integers")) s.seeds.push_back(static_cast<std::uint64_t>(r.integer(full, x, 0, INT64_MAX)));
    } else if (key == "steps") s.steps = r.integer(full, node, 1, 1'000'000'000'000);
    else if (key == "users") {
      s.users.clear();
      for (const auto& x : r.array(full, node, "integers")) s.users.push_back(static_cast<int>(r.integer(full, x, 1, 10000)));
    } else if (key == "planners") s.planners = r.texts(full, node, true);
    else
      throw InputError(r.source + ": unknown key '" + full + "': allowed keys are " + join(kKeys));
  }
}

void check_in(const std::string& source, const std::string& key, const std::string& v, const std::vector<std::string>& allowed) {
  if (std::find(allowed.begin(), allowed.end(), v) == allowed.end())
    throw InputError(source + ": " + key + " = \"" + v + "\" is invalid: allowed " + join(allowed));
}

}  // namespace

ExperimentSpec parse_experiment(const std::string& text, const std::string& source, const std::string& profile) {
  const toml::table doc = parse_toml_document(text, source);
  Reader r{source};
  ExperimentSpec s;
  s.path = source;
  s.text = text;
  for (const auto& [k, node] : doc) {
    const std::string key(k.str());
    if (key != "experiment" && key != "profile" && key != "reported" && key != "reference" && key != "reading")
      throw InputError(source + ": unknown table '" + key + "': allowed experiment, profile, reported, reference, reading");
  }
  const auto* exp = doc["experiment"].as_table();
  if (!exp) throw InputError(source + ": missing table [experiment]");
  apply_table(s, *exp, r, "experiment", false);
  const auto* profiles = doc["profile"].as_table();
  std::vector<std::string> defined;
  if (profiles)
    for (const auto& [k, node] : *profiles) defined.emplace_back(k.str());
  const auto* prof = profiles ? (*profiles)[profile].as_table() : nullptr;
  if (!prof) throw InputError(source + ": profile '" + profile + "' is not defined: allowed " + join(defined));
  apply_table(s, *prof, r, "profile." + profile, true);

  if (s.name.empty()) throw InputError(source + ": experiment.name is missing: allowed a directory name");
  if (s.name.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_") != std::string::npos)
    throw InputError(source + ": experiment.name = \"" + s.name + "\" is invalid: allowed lower-case letters, digits and _");
  check_in(source, "experiment.kind", s.kind, experiment_kinds());
  auto need = [&](bool ok, const std::string& key, const std::string& what) {
    if (!ok) throw InputError(source + ": " + key + " is missing for kind \"" + s.kind + "\": allowed " + what);
  };
  if (s.kind == "models") {
    const std::vector<std::string> labels{"gnn", "deepsets", "mspointnet", "gnn_structured", "ignn", "ignn_structured"};
    need(!s.models.empty(), "experiment.models", "a list of " + join(labels));
    for (const auto& m : s.models) check_in(source, "experiment.models", m, labels);
  } else if (s.kind == "beamform_sweep") {
    need(!s.sweep.empty(), "experiment.sweep", "a config key such as channel.p_max_dbm");
    need(!s.values.empty(), "experiment.values", "a list of numbers or names");
    need(!s.methods.empty(), "experiment.methods", "a list of beamformer specs");
    need(s.series.empty() == s.series_values.empty(), "experiment.series and experiment.series_values",
         "both (one curve per series value) or neither");
  } else if (s.kind == "altitude_profile") {
    need(!s.values.empty(), "experiment.values", "a list of channel.pathloss models");
    for (const auto& v : s.values) check_in(source, "experiment.values", v, path_loss_models().names());
    need(s.users.size() == 1, "experiment.users", "one user count K");
    need(!s.planners.empty(), "experiment.planners", "a list of planners (optimal: the exact optimum)");
    for (const auto& p : s.planners) check_in(source, "experiment.planners", p, builtin_planners().names());
  } else {
    need(!s.seeds.empty(), "experiment.seeds", "a list of training seeds");
    if (s.kind == "marl_training") {
      need(!s.algos.empty(), "experiment.algos", "a list of mappo, ippo, vdn, qmix");
      for (const auto& a : s.algos) check_in(source, "experiment.algos", a, learner_names());
    } else {
      need(!s.users.empty(), "experiment.users", "a list of user counts K");
      if (s.kind == "rate_energy") {
        need(!s.values.empty(), "experiment.values", "a list of energy.weight values (the front's points)");
        need(s.users.size() == 1, "experiment.users", "one user count K");
        for (const auto& v : s.values)
          if (v.find_first_not_of("0123456789.eE+-") != std::string::npos)
            throw InputError(source + ": experiment.values has \"" + v + "\": allowed numbers (energy.weight)");
      }
      if (s.algos.empty()) s.algos = {"mappo"};
      for (const auto& a : s.algos) check_in(source, "experiment.algos", a, learner_names());
    }
    for (const auto& p : s.planners) check_in(source, "experiment.planners", p, builtin_planners().names());
  }
  return s;
}

Config resolve_experiment(const ExperimentSpec& s, const std::vector<std::string>& before, const std::vector<std::string>& after) {
  std::vector<std::string> all = before;
  all.insert(all.end(), s.set.begin(), s.set.end());
  all.insert(all.end(), after.begin(), after.end());
  return resolve_config(s.config.empty() ? std::nullopt : std::optional<std::string>(s.config), all);
}

std::vector<ExperimentSpec> load_experiments(const std::string& dir, const std::string& profile) {
  namespace fs = std::filesystem;
  if (!fs::is_directory(dir)) throw InputError("experiments directory '" + dir + "' does not exist: allowed a directory of *.toml files");
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && e.path().extension() == ".toml") files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  std::vector<ExperimentSpec> out;
  std::set<std::string> names;
  for (const auto& f : files) {
    out.push_back(parse_experiment(read_file(f, "experiment file"), f, profile));
    if (!names.insert(out.back().name).second)
      throw InputError(f + ": experiment.name = \"" + out.back().name + "\" is used by another file: allowed a unique name");
  }
  if (out.empty()) throw InputError("experiments directory '" + dir + "' holds no *.toml file");
  if (out.front().kind != "models")
    throw InputError(files.front() + ": the first experiment (in file-name order) must be of kind \"models\"");
  return out;
}

}  // namespace skyloop
