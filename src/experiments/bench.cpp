#include "skyloop/experiments/bench.hpp"

#include <algorithm>
#include <set>
#include <cmath>
#include <filesystem>
#include <fmt/format.h>
#include <map>
#include <nlohmann/json.hpp>
#include <ostream>
#include <toml++/toml.h>

#include "toml_document.hpp"

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/paths.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/core/text.hpp"

namespace skyloop {

namespace fs = std::filesystem;

namespace {

std::string fnv_text(const std::string& s) { return fmt::format("fnv1a64:{:016x}", hash_bytes(s.data(), s.size())); }

/// task.toml's keys, read with one-line errors naming the file and the key.
struct TaskReader {
  std::string source;
  const toml::table& t;
  const toml::node* at(const std::string& key) const { return t.at_path(key).node(); }
  std::string text(const std::string& key, bool required = true) const {
    const auto* n = at(key);
    if (!n) {
      if (required) throw InputError(source + ": " + key + " is missing: allowed a string");
      return {};
    }
    if (!n->is_string()) throw InputError(source + ": " + key + " has the wrong type: allowed a string");
    return std::string(*n->value<std::string>());
  }
  std::int64_t integer(const std::string& key, std::int64_t lo, std::int64_t hi) const {
    const auto* n = at(key);
    if (!n || !n->is_integer())
      throw InputError(source + ": " + key + (n ? " has the wrong type" : " is missing") + fmt::format(": allowed an integer in [{}, {}]", lo, hi));
    const auto v = *n->value<std::int64_t>();
    if (v < lo || v > hi) throw InputError(source + fmt::format(": {} = {} is out of range: allowed [{}, {}]", key, v, lo, hi));
    return v;
  }
  double real(const std::string& key, double lo, double hi) const {
    const auto* n = at(key);
    if (!n || !(n->is_floating_point() || n->is_integer()))
      throw InputError(source + ": " + key + (n ? " has the wrong type" : " is missing") + ": allowed a number in [" +
                       format_double(lo) + ", " + format_double(hi) + "]");
    const double v = *n->value<double>();
    if (!(v >= lo && v <= hi))
      throw InputError(source + ": " + key + " = " + format_double(v) + " is out of range: allowed [" + format_double(lo) + ", " +
                       format_double(hi) + "]");
    return v;
  }
};

const std::vector<std::string> kTaskKeys{"task.name", "task.version", "task.title", "task.test_layouts", "task.reference_rtol",
                                         "task.reference_note", "task.fingerprint", "task.reference_checksum",
                                         "protocol.budget_steps", "protocol.seeds", "protocol.train_split"};

void check_keys(const toml::table& doc, const std::string& source) {
  for (const auto& [section, node] : doc) {
    const auto* table = node.as_table();
    if (!table) throw InputError(source + ": '" + std::string(section.str()) + "' is not a table: allowed [task] and [protocol]");
    for (const auto& [key, value] : *table) {
      const std::string full = std::string(section.str()) + "." + std::string(key.str());
      if (std::find(kTaskKeys.begin(), kTaskKeys.end(), full) == kTaskKeys.end())
        throw InputError(source + ": unknown key '" + full + "': allowed " + join(kTaskKeys));
    }
  }
}

std::vector<BenchReference> parse_references(const std::string& path) {
  const auto t = CsvTable::parse(read_file(path, "reference file"), path);
  std::vector<BenchReference> out;
  for (std::size_t i = 0; i < t.size(); ++i) {
    BenchReference r;
    r.layout = static_cast<std::uint64_t>(std::stoull(t.at(i, "layout")));
    r.users_seed = static_cast<std::uint64_t>(std::stoull(t.at(i, "users_seed")));
    r.users = static_cast<int>(t.number(i, "users"));
    r.reference = t.at(i, "reference");
    r.objective = t.number(i, "objective");
    r.seconds = t.has("seconds") ? t.number(i, "seconds") : 0.0;
    out.push_back(r);
  }
  return out;
}

/// Which fields are the task's (the environment a policy is scored in) and which the learner's:
/// a policy trained with other values of the task's fields is not on the task.
bool task_field(const std::string& key) {
  for (const char* section : {"scenario.", "channel.", "trajectory.", "energy."})
    if (key.rfind(section, 0) == 0) return true;
  for (const char* k : {"env.oracle", "env.objective", "env.users_min", "env.users_max", "env.users_file", "nn.selection",
                        "nn.precision"})
    if (key == k) return true;
  return false;
}

}  // namespace

std::vector<WithdrawnTask> withdrawn_tasks() {
  const fs::path path = fs::path(bench_tasks_dir()) / "withdrawn.toml";
  std::vector<WithdrawnTask> out;
  if (!fs::exists(path)) return out;
  const toml::table doc = parse_toml_document(read_file(path.string(), "withdrawn tasks"), path.string());
  for (const auto& [key, node] : doc) {
    const std::string id(key.str());
    const auto* entry = node.as_table();
    const auto reason = entry ? (*entry)["reason"].value<std::string>() : std::nullopt;
    const auto successor = entry ? (*entry)["successor"].value<std::string>() : std::nullopt;
    if (!reason || !successor) throw InputError(path.string() + ": [" + id + "] needs reason and successor: allowed two strings");
    out.push_back({id, *reason, *successor});
  }
  std::sort(out.begin(), out.end(), [](const WithdrawnTask& a, const WithdrawnTask& b) { return a.id < b.id; });
  return out;
}

std::string bench_tasks_dir() { return (fs::path(data_dir()) / "tasks").string(); }

std::vector<std::string> bench_task_ids() {
  std::vector<std::string> ids;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(bench_tasks_dir(), ec))
    if (e.is_directory() && fs::exists(e.path() / "task.toml")) ids.push_back(e.path().filename().string());
  std::sort(ids.begin(), ids.end());
  return ids;
}

std::string config_fingerprint(const Config& cfg, const std::vector<std::string>& keys) {
  const std::set<std::string> fixed(keys.begin(), keys.end());
  Config c = cfg;
  std::string s;
  for (const auto& f : config_fields())
    if (fixed.count(f.key)) s += f.key + " = " + format_value(f.get(c)) + "\n";
  return "fnv1a64-values:" + fnv_text(s).substr(std::string("fnv1a64:").size());
}

namespace {
/// "section.key" of every value a TOML table sets.
void toml_keys(const toml::table& t, const std::string& prefix, std::vector<std::string>& out) {
  for (const auto& [k, v] : t) {
    const std::string key = prefix + std::string(k.str());
    if (const auto* sub = v.as_table()) toml_keys(*sub, key + ".", out);
    else out.push_back(key);
  }
}
}  // namespace

std::string reference_csv(const BenchTask& task, const std::vector<BenchReference>& rows) {
  std::string s = "task,version,layout,users_seed,users,reference,objective,seconds\n";
  for (const auto& r : rows)
    s += fmt::format("{},{},{},{},{},{},{},{}\n", task.name, task.version, r.layout, r.users_seed, r.users, r.reference,
                     format_double(r.objective), format_double(r.seconds));
  return s;
}

std::string reference_checksum(const std::vector<BenchReference>& rows) {
  // The reference itself (not the time it took): the layouts, their K, names and objectives.
  std::string s;
  for (const auto& r : rows) s += fmt::format("{},{},{},{},{}\n", r.layout, r.users_seed, r.users, r.reference, format_double(r.objective));
  return fnv_text(s);
}

BenchTask load_bench_task(const std::string& id_or_dir, bool fresh) {
  fs::path dir;
  if (fs::exists(fs::path(id_or_dir) / "task.toml")) {
    dir = id_or_dir;
  } else {
    const auto ids = bench_task_ids();
    if (std::find(ids.begin(), ids.end(), id_or_dir) != ids.end()) {
      dir = fs::path(bench_tasks_dir()) / id_or_dir;
    } else {
      // A name alone: its highest version.
      int best = 0;
      for (const auto& id : ids) {
        const auto dash = id.rfind("-v");
        if (dash == std::string::npos || id.substr(0, dash) != id_or_dir) continue;
        const int v = std::atoi(id.c_str() + dash + 2);
        if (v > best) best = v, dir = fs::path(bench_tasks_dir()) / id;
      }
      if (best == 0) {
        for (const auto& w : withdrawn_tasks())
          if (w.id == id_or_dir)
            throw InputError("task '" + id_or_dir + "' was withdrawn: " + w.reason + " (its successor: " + w.successor +
                             "): allowed " + join(ids) + " (or a task's folder)");
        throw InputError("task '" + id_or_dir + "' is unknown: allowed " + join(ids) + " (or a task's folder)");
      }
    }
  }
  const std::string source = (dir / "task.toml").string();
  const std::string text = read_file(source, "task file");
  const toml::table doc = parse_toml_document(text, source);
  check_keys(doc, source);
  const TaskReader r{source, doc};
  BenchTask t;
  t.dir = dir.string();
  t.name = r.text("task.name");
  t.version = static_cast<int>(r.integer("task.version", 1, 999));
  t.id = t.name + "-v" + std::to_string(t.version);
  t.title = r.text("task.title");
  t.reference_note = r.text("task.reference_note", false);
  t.reference_rtol = r.real("task.reference_rtol", 0.0, 0.1);
  t.fingerprint = r.text("task.fingerprint", false);
  t.reference_checksum = r.text("task.reference_checksum", false);
  t.protocol.budget_steps = r.integer("protocol.budget_steps", 1, std::int64_t{1} << 40);
  t.protocol.seeds = static_cast<int>(r.integer("protocol.seeds", 1, 1000));
  t.protocol.train_split = r.text("protocol.train_split");
  parse_layout_split(t.protocol.train_split, source + ": protocol.train_split");
  const int layouts = static_cast<int>(r.integer("task.test_layouts", 1, 100000));
  t.config = resolve_config((dir / "config.toml").string(), {});
  {
    const std::string cfg_path = (dir / "config.toml").string();
    toml_keys(parse_toml_document(read_file(cfg_path, "task configuration"), cfg_path), "", t.fixed_keys);
  }
  const fs::path ref = dir / "reference.csv";
  if (!fresh && fs::exists(ref)) {
    t.references = parse_references(ref.string());
    const std::string sum = reference_checksum(t.references);
    if (sum != t.reference_checksum)
      throw InputError(ref.string() + ": checksum " + sum + " differs from task.reference_checksum = \"" + t.reference_checksum +
                       "\" in " + source + ": allowed the reference file as shipped (restore it, or recompute it with "
                       "`skyloop bench reference " + t.id + " --write`)");
    if (static_cast<int>(t.references.size()) != layouts)
      throw InputError(ref.string() + fmt::format(": {} layouts, task.test_layouts = {}: allowed one row per test layout",
                                                  t.references.size(), layouts));
  } else {
    for (int i = 0; i < layouts; ++i) {
      BenchReference b;
      b.layout = static_cast<std::uint64_t>(i);
      b.users_seed = layout_seed(LayoutSplit::Test, b.layout);
      t.references.push_back(b);
    }
  }
  return t;
}

std::vector<std::size_t> sample_layouts(std::size_t layouts, std::size_t count) {
  std::vector<std::size_t> out;
  if (layouts == 0) return out;
  count = std::min(count, layouts);
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t k = count == 1 ? 0 : (i * (layouts - 1) + (count - 1) / 2) / (count - 1);
    if (out.empty() || out.back() != k) out.push_back(k);
  }
  return out;
}

std::vector<BenchReference> compute_references(const BenchTask& task, const std::vector<std::size_t>& indices, int threads,
                                               std::ostream* progress) {
  LayoutEvalOptions opt;
  opt.layouts = static_cast<int>(indices.size());
  for (const auto i : indices) {
    if (i >= task.references.size())
      throw InputError(fmt::format("layout index {} is out of range: allowed 0..{}", i, task.references.size() - 1));
    opt.users_seeds.push_back(task.references[i].users_seed);
  }
  opt.threads = threads;
  const auto rows = evaluate_layouts(task.config, opt, builtin_beamformers(), progress);
  std::vector<BenchReference> out;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    BenchReference b;
    b.layout = task.references[indices[k]].layout;
    b.users_seed = rows[k].users_seed;
    b.users = rows[k].users;
    b.reference = rows[k].planner;
    b.objective = rows[k].objective;
    b.seconds = rows[k].seconds;
    out.push_back(b);
  }
  return out;
}

// ---- statistics ------------------------------------------------------------------------------

double interquartile_mean(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t cut = v.size() / 4;  // scipy.stats.trim_mean(v, 0.25): int(0.25 n) from each end
  double s = 0;
  for (std::size_t i = cut; i < v.size() - cut; ++i) s += v[i];
  return s / static_cast<double>(v.size() - 2 * cut);
}

void iqm_interval(const std::vector<std::vector<double>>& runs_by_layout, int reps, std::uint64_t seed, double& low,
                  double& high) {
  std::vector<double> stats;
  Rng rng(seed);
  std::vector<double> draw;
  for (int b = 0; b < reps; ++b) {
    draw.clear();
    for (const auto& runs : runs_by_layout) {
      for (std::size_t k = 0; k < runs.size(); ++k) draw.push_back(runs[static_cast<std::size_t>(rng.below(runs.size()))]);
    }
    stats.push_back(interquartile_mean(draw));
  }
  low = percentile(stats, 0.025);
  high = percentile(stats, 0.975);
}

std::vector<BenchSummary> summarise_bench(const BenchTask& task, const std::vector<BenchRow>& rows) {
  std::vector<BenchSummary> out;
  std::map<std::string, std::vector<const BenchRow*>> by;
  for (const auto& r : rows) {
    if (!by.count(r.policy)) {
      BenchSummary s;
      s.task = task.name, s.version = task.version, s.policy = r.policy;
      out.push_back(s);
    }
    by[r.policy].push_back(&r);
  }
  for (auto& s : out) {
    const auto& v = by[s.policy];
    std::map<std::uint64_t, std::vector<double>> per_layout;
    std::vector<std::uint64_t> seeds;
    std::vector<double> all;
    std::vector<std::string> reasons;
    for (const auto* r : v) {
      per_layout[r->layout].push_back(r->fraction);
      if (std::find(seeds.begin(), seeds.end(), r->seed) == seeds.end()) seeds.push_back(r->seed);
      all.push_back(r->fraction);
      s.complete_rate += r->complete ? 1.0 : 0.0;
      if (s.reference.find(r->reference) == std::string::npos) s.reference += (s.reference.empty() ? "" : "+") + r->reference;
      if (r->protocol != "ok" && std::find(reasons.begin(), reasons.end(), r->protocol) == reasons.end()) reasons.push_back(r->protocol);
    }
    s.seeds = static_cast<int>(seeds.size());
    s.layouts = static_cast<int>(per_layout.size());
    const double n = static_cast<double>(std::max<std::size_t>(1, all.size()));
    for (const double x : all) s.mean += x / n;
    s.complete_rate /= n;
    s.iqm = interquartile_mean(all);
    s.p5 = percentile(all, 0.05);
    std::vector<std::vector<double>> strata;
    for (auto& [layout, runs] : per_layout) strata.push_back(runs);
    // A fixed stream per (task, policy): the same rows give the same interval.
    const std::string key = task.id + "|" + s.policy;
    iqm_interval(strata, 2000, hash_bytes(key.data(), key.size()), s.iqm_low, s.iqm_high);
    if (s.seeds < task.protocol.seeds) reasons.push_back(fmt::format("{} seeds of the protocol's {}", s.seeds, task.protocol.seeds));
    if (s.layouts < static_cast<int>(task.references.size()))
      reasons.push_back(fmt::format("{} of {} test layouts", s.layouts, task.references.size()));
    if (!reasons.empty()) {
      s.protocol.clear();
      for (const auto& x : reasons) s.protocol += (s.protocol.empty() ? "" : "; ") + x;
    }
  }
  return out;
}

std::string bench_rows_csv(const std::vector<BenchRow>& rows) {
  std::string s = "task,version,policy,seed,layout,users_seed,users,objective,reference,reference_objective,fraction,complete,"
                  "home,collisions,boundary_events,energy_j,protocol\n";
  for (const auto& r : rows)
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},\"{}\"\n", r.task, r.version, r.policy, r.seed, r.layout,
                     r.users_seed, r.users, format_double(r.objective), r.reference, format_double(r.reference_objective),
                     format_double(r.fraction), r.complete ? 1 : 0, r.home, r.collisions, r.boundary, format_double(r.energy_j),
                     r.protocol);
  return s;
}

std::string bench_summary_csv(const std::vector<BenchSummary>& sum) {
  std::string s = "task,version,policy,seeds,layouts,reference,mean,iqm,iqm_ci_low,iqm_ci_high,p5,complete_rate,protocol\n";
  for (const auto& x : sum)
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},\"{}\"\n", x.task, x.version, x.policy, x.seeds, x.layouts, x.reference,
                     format_double(x.mean), format_double(x.iqm), format_double(x.iqm_low), format_double(x.iqm_high),
                     format_double(x.p5), format_double(x.complete_rate), x.protocol);
  return s;
}

std::string bench_profile_csv(const std::vector<BenchRow>& rows) {
  std::map<std::string, std::vector<double>> by;
  std::vector<std::string> order;
  std::string task;
  int version = 1;
  double best = 1.05;
  for (const auto& r : rows) {
    if (!by.count(r.policy)) order.push_back(r.policy);
    by[r.policy].push_back(r.fraction);
    best = std::max(best, r.fraction);
    task = r.task, version = r.version;
  }
  std::string s = "task,version,policy,tau,fraction_of_runs\n";
  const int steps = static_cast<int>(std::ceil(best * 100.0 - 1e-9));
  for (const auto& p : order) {
    const auto& v = by[p];
    for (int i = 0; i <= steps; ++i) {
      const double tau = i / 100.0;
      const auto above = std::count_if(v.begin(), v.end(), [&](double x) { return x >= tau - 1e-12; });
      s += fmt::format("{},{},{},{},{}\n", task, version, p, format_double(tau),
                       format_double(static_cast<double>(above) / static_cast<double>(v.size())));
    }
  }
  return s;
}

std::string bench_marl_eval_json(const BenchTask& task, const std::vector<BenchRow>& rows) {
  nlohmann::ordered_json policies = nlohmann::ordered_json::object();
  for (const auto& r : rows) {
    auto& run = policies[r.policy]["seed_" + std::to_string(r.seed)];
    for (const char* part : {"step_0", "absolute_metrics"}) {
      auto& m = run[part];
      if (std::string(part) == "step_0") m["step_count"] = task.protocol.budget_steps;
      m["fraction_of_reference"].push_back(r.fraction);
      m["objective"].push_back(r.objective);
      m["complete"].push_back(r.complete ? 1 : 0);
    }
  }
  nlohmann::ordered_json doc;
  doc["skyloop"][task.id] = policies;
  return doc.dump(1) + "\n";
}

std::string format_bench_summary(const std::vector<BenchSummary>& sum) {
  std::string s = fmt::format("{:<16} {:>5} {:>7} {:>8} {:>8} {:>17} {:>8} {:>9}  {}\n", "policy", "seeds", "layouts", "mean %",
                              "IQM %", "IQM 95% CI", "p5 %", "complete", "protocol");
  for (const auto& x : sum)
    s += fmt::format("{:<16} {:>5} {:>7} {:>8.2f} {:>8.2f} {:>17} {:>8.2f} {:>8.1f}%  {}\n", x.policy, x.seeds, x.layouts, 100 * x.mean,
                     100 * x.iqm, fmt::format("[{:.2f}, {:.2f}]", 100 * x.iqm_low, 100 * x.iqm_high), 100 * x.p5,
                     100 * x.complete_rate, x.protocol);
  return s;
}

// ---- scoring -----------------------------------------------------------------------------------

std::string policy_protocol(const BenchTask& task, const Config& trained) {
  std::vector<std::string> reasons;
  std::vector<std::string> differ;
  for (const auto& f : config_fields())
    if (task_field(f.key) && format_value(f.get(trained)) != format_value(f.get(task.config))) differ.push_back(f.key);
  if (!differ.empty()) reasons.push_back("trained on another environment (" + join(differ) + ")");
  if (trained.marl.total_steps != task.protocol.budget_steps)
    reasons.push_back(fmt::format("trained {} steps, the budget is {}", trained.marl.total_steps, task.protocol.budget_steps));
  const LayoutSplit allowed = parse_layout_split(task.protocol.train_split, "protocol.train_split");
  if (!trained.env.resample_users && layout_split(trained.marl.users_seed) != allowed)
    reasons.push_back(fmt::format("trained on users seed {} ({} split)", trained.marl.users_seed, to_string(layout_split(trained.marl.users_seed))));
  if (!trained.env.users_file.empty()) reasons.push_back("trained on a users file");
  if (reasons.empty()) return "ok";
  std::string s;
  for (const auto& x : reasons) s += (s.empty() ? "" : "; ") + x;
  return s;
}

std::vector<BenchRow> run_bench(const BenchTask& task, const BenchRunOptions& opt, std::ostream* progress) {
  if (task.references.empty() || task.references.front().reference.empty())
    throw InputError("task " + task.id + " has no reference yet: allowed a task with reference.csv (`skyloop bench reference " + task.id +
                     " --write`)");
  if (opt.planners.empty() && opt.policies.empty()) throw InputError("nothing to score: allowed --planner NAMES or --policy DIRS");
  for (const auto& p : opt.planners)
    if (!builtin_planners().contains(p) || p == "optimal" || p == "bestknown")
      throw InputError("--planner '" + p + "' is invalid: allowed " + builtin_planners().names_text() + " but the references (optimal, bestknown)");
  std::vector<std::uint64_t> seeds = opt.seeds;
  if (seeds.empty())
    for (int s = 1; s <= task.protocol.seeds; ++s) seeds.push_back(static_cast<std::uint64_t>(s));
  std::vector<std::uint64_t> users_seeds;
  for (const auto& r : task.references) users_seeds.push_back(r.users_seed);
  auto fill = [&](const std::vector<LayoutRow>& rows, std::uint64_t seed, const std::string& label, const std::string& protocol,
                  std::vector<BenchRow>& out) {
    for (std::size_t k = 0; k < rows.size(); ++k) {
      const auto& lr = rows[k];
      const auto& ref = task.references[k % task.references.size()];
      BenchRow b;
      b.task = task.name, b.version = task.version, b.policy = label.empty() ? lr.planner : label, b.seed = seed;
      b.layout = ref.layout, b.users_seed = ref.users_seed, b.users = lr.users;
      b.objective = lr.objective, b.reference = ref.reference, b.reference_objective = ref.objective;
      b.fraction = ref.objective > 0 ? lr.objective / ref.objective : 0.0;
      b.complete = lr.complete, b.home = lr.home, b.collisions = lr.collisions, b.boundary = lr.boundary, b.energy_j = lr.energy_j;
      b.protocol = protocol;
      out.push_back(b);
    }
  };
  std::vector<BenchRow> out;
  LayoutEvalOptions base;
  base.layouts = static_cast<int>(users_seeds.size());
  base.users_seeds = users_seeds;
  base.solve_reference = false;
  base.threads = opt.threads;
  // Planners, rows of one planner together: a seeded one (Planner::seeded) flies every seed; one
  // that draws nothing flies the same episode under any seed, so it flies once and its rows stand
  // for every seed (BenchRun.PlannersAreScoredPerSeedAndLayoutAgainstTheShippedOptimum checks it).
  for (const auto& name : opt.planners) {
    const bool seeded = builtin_planners().create(name)->seeded();
    std::vector<LayoutRow> once;
    for (const auto seed : seeds) {
      if (seeded || once.empty()) {
        LayoutEvalOptions o = base;
        o.planners = {name};
        o.planner_seed = seed;
        once = evaluate_layouts(task.config, o, builtin_beamformers(), progress);
      }
      fill(once, seed, name, "ok", out);
    }
  }
  // Policies: one training seed each (its run.seed), scored as trained under the task's settings.
  for (const auto& dir : opt.policies) {
    const auto policy = MarlPolicy::load(dir);
    const Config trained = policy_config(dir);
    LayoutEvalOptions o = base;
    o.policies = {dir};
    if (!opt.policy_label.empty()) o.policy_names = {opt.policy_label};
    const auto rows = evaluate_layouts(task.config, o, builtin_beamformers(), progress);
    fill(rows, trained.run.seed, opt.policy_label.empty() ? policy->name() : opt.policy_label, policy_protocol(task, trained), out);
  }
  return out;
}

}  // namespace skyloop
