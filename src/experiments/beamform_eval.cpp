#include "skyloop/experiments/beamform_eval.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fmt/format.h>
#include <memory>

#include "skyloop/channel/network.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

std::vector<BeamformEvalRow> run_beamform_eval(const Config& cfg, const BeamformEvalOptions& opt,
                                               const BeamformerRegistry& registry, std::ostream* progress) {
  if (opt.methods.empty()) throw InputError("--methods is empty: allowed a comma-separated list such as mrt,zf,wmmse");
  if (opt.samples == 0) throw InputError("--samples = 0 is out of range: allowed >= 1");
  std::vector<std::unique_ptr<Beamformer>> methods;
  for (const auto& spec : opt.methods) methods.push_back(registry.create(spec, cfg));

  const SystemModel model(cfg);
  const std::size_t m = methods.size();
  std::vector<BeamformEvalRow> rows(opt.samples * m);
  std::unique_ptr<Progress> bar;
  if (progress) bar = std::make_unique<Progress>("beamform eval", opt.samples, *progress);

  parallel_for(opt.samples, opt.threads, [&](std::size_t i) {
    const Snapshot snap = model.random_snapshot(opt.uavs, opt.users, derive_seed(opt.seed, opt.first + i));
    const Network net = model.network(snap);
    for (std::size_t j = 0; j < m; ++j) {
      const Beamformer& bf = *methods[j];
      const auto t0 = std::chrono::steady_clock::now();
      const std::vector<MatrixXcd> W = bf.design_network(net);
      const auto t1 = std::chrono::steady_clock::now();
      check_network_output(bf, net, W);
      const double total = network_sum_rate(net, W);
      BeamformEvalRow& r = rows[i * m + j];
      r.seed = opt.seed;
      r.sample = opt.first + i;
      r.method = opt.methods[j];
      r.uavs = opt.uavs;
      r.users = opt.users;
      r.clusters = static_cast<int>(net.clusters.size());
      r.served_users = net.served_count();
      r.sum_rate = total;
      r.latency_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    }
    if (bar) bar->advance();
  });
  if (bar) bar->finish();
  return rows;
}

std::string beamform_eval_csv(const std::vector<BeamformEvalRow>& rows, const Config& cfg) {
  std::string out =
      "seed,sample,method,uavs,users,antennas,p_max_dbm,noise_dbm,spectrum,clusters,served_users,sum_rate_bps_hz,latency_ms\n";
  for (const auto& r : rows) {
    out += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{}\n", r.seed, r.sample, r.method, r.uavs, r.users,
                       cfg.channel.antennas, format_double(cfg.channel.p_max_dbm), format_double(cfg.channel.noise_dbm),
                       name_of(cfg.channel.spectrum),
                       r.clusters, r.served_users, format_double(r.sum_rate), format_double(r.latency_ms));
  }
  return out;
}

std::vector<BeamformEvalRow> parse_beamform_eval_csv(const std::string& csv, const std::string& source) {
  const CsvTable t = CsvTable::parse(csv, source);
  std::vector<BeamformEvalRow> rows(t.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    BeamformEvalRow& r = rows[i];
    r.seed = std::stoull(t.at(i, "seed"));
    r.sample = std::stoull(t.at(i, "sample"));
    r.method = t.at(i, "method");
    r.uavs = std::stoi(t.at(i, "uavs"));
    r.users = std::stoi(t.at(i, "users"));
    r.clusters = std::stoi(t.at(i, "clusters"));
    r.served_users = std::stoi(t.at(i, "served_users"));
    r.sum_rate = t.number(i, "sum_rate_bps_hz");
    r.latency_ms = t.number(i, "latency_ms");
  }
  return rows;
}

std::vector<MethodSummary> summarise(const std::vector<BeamformEvalRow>& rows) {
  std::vector<std::string> order;
  for (const auto& r : rows)
    if (std::find(order.begin(), order.end(), r.method) == order.end()) order.push_back(r.method);
  std::vector<MethodSummary> out;
  for (const auto& name : order) {
    std::vector<double> rate, lat;
    for (const auto& r : rows)
      if (r.method == name) rate.push_back(r.sum_rate), lat.push_back(r.latency_ms);
    MethodSummary s;
    s.method = name;
    s.samples = rate.size();
    for (double v : rate) s.mean += v;
    s.mean /= static_cast<double>(rate.size());
    double ss = 0.0;
    for (double v : rate) ss += (v - s.mean) * (v - s.mean);
    s.std = rate.size() > 1 ? std::sqrt(ss / static_cast<double>(rate.size() - 1)) : 0.0;
    for (double v : lat) s.mean_latency_ms += v;
    s.mean_latency_ms /= static_cast<double>(lat.size());
    std::sort(lat.begin(), lat.end());
    const std::size_t n = lat.size();
    s.median_latency_ms = n % 2 ? lat[n / 2] : 0.5 * (lat[n / 2 - 1] + lat[n / 2]);
    out.push_back(s);
  }
  return out;
}

std::string format_summary(const std::vector<MethodSummary>& s) {
  double best = 0.0;
  std::size_t width = 16;
  for (const auto& m : s) best = std::max(best, m.mean), width = std::max(width, m.method.size() + 1);
  std::string out = fmt::format("{:<{}} {:>8} {:>14} {:>10} {:>8} {:>20}\n", "method", width, "samples", "sum rate mean",
                                "std", "% best", "median latency (ms)");
  for (const auto& m : s)
    out += fmt::format("{:<{}} {:>8} {:>14.3f} {:>10.3f} {:>8.1f} {:>20.4f}\n", m.method, width, m.samples, m.mean, m.std,
                       best > 0 ? 100.0 * m.mean / best : 0.0, m.median_latency_ms);
  return out;
}

}  // namespace skyloop
