#include "skyloop/channel/system_model.hpp"

#include <cmath>
#include <limits>

#include "skyloop/channel/network.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

SystemModel::SystemModel(const Config& cfg)
    : antennas_(cfg.channel.antennas),
      spacing_(cfg.channel.antenna_spacing_wavelengths),
      altitude_(cfg.scenario.altitude_m),
      beta0_(db_to_linear(cfg.channel.beta0_db)),
      d0_(cfg.channel.d0_m),
      coverage_(cfg.channel.coverage_radius_m),
      p_max_(cfg.channel.p_max_w()),
      noise_(cfg.channel.noise_w()),
      area_x_(cfg.scenario.area_x_m),
      area_y_(cfg.scenario.area_y_m),
      spectrum_(parse_spectrum(cfg.channel.spectrum)) {}

double SystemModel::distance(double ux, double uy, double x, double y) const {
  const double dx = ux - x, dy = uy - y;
  return std::sqrt(dx * dx + dy * dy + altitude_ * altitude_);
}

double SystemModel::path_loss(double d) const {
  const double r = d0_ / d;
  return beta0_ * r * r;
}

VectorXcd SystemModel::steering(double cos_theta) const {
  VectorXcd a(antennas_);
  const double phase = 2.0 * M_PI * spacing_ * cos_theta;
  for (int l = 0; l < antennas_; ++l) a[l] = std::polar(1.0, phase * l);
  return a;
}

VectorXcd SystemModel::channel(double ux, double uy, double x, double y) const {
  const double d = distance(ux, uy, x, y);
  return std::sqrt(path_loss(d)) * steering(altitude_ / d);
}

Association SystemModel::associate(const Snapshot& s) const {
  const auto n_uav = static_cast<int>(s.uavs.rows());
  const auto n_user = static_cast<int>(s.users.rows());
  Association a;
  a.serving.assign(n_user, -1);
  a.users.assign(n_uav, {});
  for (int k = 0; k < n_user; ++k) {
    int best = -1;
    double best_d = std::numeric_limits<double>::infinity();
    for (int n = 0; n < n_uav; ++n) {
      const double d = distance(s.uavs(n, 0), s.uavs(n, 1), s.users(k, 0), s.users(k, 1));
      if (d < best_d) best_d = d, best = n;
    }
    if (best >= 0 && best_d <= coverage_) {
      a.serving[k] = best;
      a.users[best].push_back(k);
    }
  }
  return a;
}

Cluster SystemModel::make_cluster(int uav, double ux, double uy, const Positions& users_xy,
                                  const std::vector<int>& users, int uavs) const {
  Cluster c;
  c.uav = uav;
  c.users = users;
  c.p_max = p_max_;
  c.noise = noise_;
  if (spectrum_ == Spectrum::OrthogonalSplit && uavs > 1) {
    c.bandwidth = 1.0 / static_cast<double>(uavs);
    c.noise = noise_ / static_cast<double>(uavs);
  }
  c.G.resize(static_cast<Eigen::Index>(users.size()), antennas_);
  for (std::size_t i = 0; i < users.size(); ++i)
    c.G.row(static_cast<Eigen::Index>(i)) = channel(ux, uy, users_xy(users[i], 0), users_xy(users[i], 1)).adjoint();
  return c;
}

std::vector<Cluster> SystemModel::clusters(const Snapshot& s, const Association& a) const {
  std::vector<Cluster> out;
  for (int n = 0; n < static_cast<int>(a.users.size()); ++n)
    if (!a.users[n].empty())
      out.push_back(make_cluster(n, s.uavs(n, 0), s.uavs(n, 1), s.users, a.users[n], static_cast<int>(s.uavs.rows())));
  return out;
}

Network SystemModel::network(const Positions& uavs, const Positions& users_xy,
                             const std::vector<std::vector<int>>& members) const {
  Network net;
  net.spectrum = spectrum_;
  net.uavs = static_cast<int>(uavs.rows());
  net.offset.push_back(0);
  for (int n = 0; n < net.uavs; ++n) {
    if (members[static_cast<std::size_t>(n)].empty()) continue;
    net.clusters.push_back(make_cluster(n, uavs(n, 0), uavs(n, 1), users_xy, members[static_cast<std::size_t>(n)], net.uavs));
    for (int k : members[static_cast<std::size_t>(n)]) net.served.push_back(k);
    net.offset.push_back(static_cast<int>(net.served.size()));
  }
  const auto ks = static_cast<Eigen::Index>(net.served.size());
  for (const Cluster& c : net.clusters) {
    MatrixXcd H(ks, antennas_);
    for (Eigen::Index r = 0; r < ks; ++r) {
      const int k = net.served[static_cast<std::size_t>(r)];
      H.row(r) = channel(uavs(c.uav, 0), uavs(c.uav, 1), users_xy(k, 0), users_xy(k, 1)).adjoint();
    }
    net.cross.push_back(std::move(H));
  }
  return net;
}

Network SystemModel::network(const Snapshot& s, const Association& a) const { return network(s.uavs, s.users, a.users); }

Network SystemModel::network(const Snapshot& s) const { return network(s, associate(s)); }

std::vector<Cluster> SystemModel::clusters(const Snapshot& s) const { return clusters(s, associate(s)); }

Snapshot SystemModel::random_snapshot(int uavs, int users, std::uint64_t seed) const {
  Rng rng(seed);
  Snapshot s;
  s.uavs.resize(uavs, 2);
  s.users.resize(users, 2);
  for (int n = 0; n < uavs; ++n) s.uavs(n, 0) = rng.uniform(0, area_x_), s.uavs(n, 1) = rng.uniform(0, area_y_);
  for (int k = 0; k < users; ++k) s.users(k, 0) = rng.uniform(0, area_x_), s.users(k, 1) = rng.uniform(0, area_y_);
  return s;
}

std::vector<Snapshot> random_snapshots(const SystemModel& model, int uavs, int users, std::uint64_t seed,
                                       std::size_t count) {
  std::vector<Snapshot> out;
  out.reserve(count);
  for (std::size_t i = 0; i < count; ++i) out.push_back(model.random_snapshot(uavs, users, derive_seed(seed, i)));
  return out;
}

std::vector<Cluster> clusters_of(const SystemModel& model, const std::vector<Snapshot>& snapshots,
                                 std::vector<int>* owner) {
  std::vector<Cluster> out;
  if (owner) owner->clear();
  for (std::size_t i = 0; i < snapshots.size(); ++i) {
    for (auto& c : model.clusters(snapshots[i])) {
      out.push_back(std::move(c));
      if (owner) owner->push_back(static_cast<int>(i));
    }
  }
  return out;
}

}  // namespace skyloop
