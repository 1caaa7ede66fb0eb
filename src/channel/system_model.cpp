#include <algorithm>
#include "skyloop/channel/system_model.hpp"

#include "skyloop/core/error.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "skyloop/channel/network.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

SystemModel::SystemModel(const Config& cfg)
    : antennas_(cfg.channel.antennas),
      altitude_(cfg.scenario.altitude_m),
      coverage_(cfg.channel.coverage_radius_m),
      p_max_(cfg.channel.p_max_w()),
      noise_(cfg.channel.noise_w()),
      area_x_(cfg.scenario.area_x_m),
      area_y_(cfg.scenario.area_y_m),
      spectrum_(cfg.channel.spectrum),
      channel_(std::make_shared<ChannelModel>(cfg)),
      scenario_(cfg.scenario) {}

double SystemModel::distance(double ux, double uy, double x, double y) const {
  return channel_->distance(ux, uy, x, y);
}

double SystemModel::path_loss(double d) const { return channel_->free_space_gain(d); }

VectorXcd SystemModel::steering(double cos_theta) const { return channel_->steering(cos_theta); }

VectorXcd SystemModel::channel(double ux, double uy, double x, double y, int slot) const {
  return channel_->channel(ux, uy, x, y, slot);
}

Association SystemModel::associate(const Snapshot& s) const { return associate(s.uavs, s.users); }

Association SystemModel::associate(const Positions& uavs, const Positions& users) const {
  Association a;
  associate(uavs, users, a);
  return a;
}

void SystemModel::associate(const Positions& uavs, const Positions& users, Association& a, std::vector<double>* nearest) const {
  const auto n_uav = static_cast<int>(uavs.rows());
  const auto n_user = static_cast<int>(users.rows());
  a.serving.assign(static_cast<std::size_t>(n_user), -1);
  a.users.resize(static_cast<std::size_t>(n_uav));
  for (auto& members : a.users) members.clear();  // capacity kept for the next call
  if (nearest) nearest->assign(static_cast<std::size_t>(n_user), std::numeric_limits<double>::infinity());
  // Nearest UAV by 3-D distance, lowest index on ties, served if within R_c. Every distance is
  // the same distance() call on both paths, so both give the same association bit for bit.
  auto serve = [&](int k, int best, double best_d) {
    if (best >= 0 && best_d <= coverage_) {
      a.serving[static_cast<std::size_t>(k)] = best;
      a.users[static_cast<std::size_t>(best)].push_back(k);
      if (nearest) (*nearest)[static_cast<std::size_t>(k)] = best_d;
    }
  };
  // The horizontal reach of the lowest UAV (the farthest any UAV covers).
  double lowest = n_uav > 0 ? altitude_of(uavs, 0) : altitude_;
  for (int n = 1; n < n_uav; ++n) lowest = std::min(lowest, altitude_of(uavs, n));
  const double dz = lowest - scenario_.user_height_m;
  const double reach2 = coverage_ * coverage_ - dz * dz;  // horizontal reach squared
  if (n_uav <= kAssociationGridFrom || reach2 <= 0) {
    for (int k = 0; k < n_user; ++k) {
      int best = -1;
      double best_d = std::numeric_limits<double>::infinity();
      for (int n = 0; n < n_uav; ++n) {
        const double d = distance(uavs, n, users(k, 0), users(k, 1));
        if (d < best_d) best_d = d, best = n;
      }
      serve(k, best, best_d);
    }
    return;
  }
  // Spatial index: UAVs bucketed on a grid of cells at least the horizontal reach wide. A user's
  // nearest UAV, if it is within R_c at all, lies in the 3 x 3 cells around the user's cell; if
  // none there is within R_c, no UAV is (the global nearest is then unserved on both paths).
  // Cells wider than the reach keep that guarantee, so a tiny reach (R_c just above H) is widened
  // until the grid has about 4 N cells: memory stays linear in N.
  double x0 = uavs(0, 0), y0 = uavs(0, 1), x1 = x0, y1 = y0;
  for (int n = 1; n < n_uav; ++n)
    x0 = std::min(x0, uavs(n, 0)), x1 = std::max(x1, uavs(n, 0)), y0 = std::min(y0, uavs(n, 1)), y1 = std::max(y1, uavs(n, 1));
  const double per_axis = 2.0 * std::ceil(std::sqrt(static_cast<double>(n_uav)));
  const double cell = std::max(std::sqrt(reach2) * (1 + 1e-9), std::max(x1 - x0, y1 - y0) / per_axis);
  const int cx = static_cast<int>((x1 - x0) / cell) + 1, cy = static_cast<int>((y1 - y0) / cell) + 1;
  std::vector<int> head(static_cast<std::size_t>(cx) * static_cast<std::size_t>(cy) + 1, 0), order(static_cast<std::size_t>(n_uav));
  auto cell_of = [&](double x, double y, int& ix, int& iy) {
    ix = static_cast<int>(std::floor((x - x0) / cell)), iy = static_cast<int>(std::floor((y - y0) / cell));
  };
  std::vector<int> cell_id(static_cast<std::size_t>(n_uav));
  for (int n = 0; n < n_uav; ++n) {
    int ix, iy;
    cell_of(uavs(n, 0), uavs(n, 1), ix, iy);
    cell_id[static_cast<std::size_t>(n)] = iy * cx + ix;
    ++head[static_cast<std::size_t>(iy * cx + ix) + 1];
  }
  for (std::size_t c = 1; c < head.size(); ++c) head[c] += head[c - 1];
  {
    std::vector<int> fill(head.begin(), head.end() - 1);
    for (int n = 0; n < n_uav; ++n) order[static_cast<std::size_t>(fill[static_cast<std::size_t>(cell_id[static_cast<std::size_t>(n)])]++)] = n;
  }
  for (int k = 0; k < n_user; ++k) {
    int ix, iy;
    cell_of(users(k, 0), users(k, 1), ix, iy);
    int best = -1;
    double best_d = std::numeric_limits<double>::infinity();
    for (int jy = std::max(0, iy - 1); jy <= std::min(cy - 1, iy + 1); ++jy)
      for (int jx = std::max(0, ix - 1); jx <= std::min(cx - 1, ix + 1); ++jx) {
        const auto c = static_cast<std::size_t>(jy * cx + jx);
        for (int i = head[c]; i < head[c + 1]; ++i) {
          const int n = order[static_cast<std::size_t>(i)];
          const double d = distance(uavs, n, users(k, 0), users(k, 1));
          if (d < best_d || (d == best_d && n < best)) best_d = d, best = n;
        }
      }
    serve(k, best, best_d);
  }
  // Users were visited in ascending order: each cluster's list is ascending.
}

void SystemModel::reassociate(const Positions& uavs, const Positions& users, int moved, Association& a,
                              std::vector<double>& nearest) const {
  const auto n_uav = static_cast<int>(uavs.rows());
  const auto n_user = static_cast<int>(users.rows());
  if (moved < 0 || moved >= n_uav || a.serving.size() != static_cast<std::size_t>(n_user) ||
      a.users.size() != static_cast<std::size_t>(n_uav) || nearest.size() != static_cast<std::size_t>(n_user))
    throw std::invalid_argument("SystemModel::reassociate: no association of these positions to update");

  for (int k = 0; k < n_user; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    const int was = a.serving[kk];
    if (was == moved) {  // its nearest may be anyone now: searched afresh, as associate's scan
      int best = -1;
      double best_d = std::numeric_limits<double>::infinity();
      for (int n = 0; n < n_uav; ++n) {
        const double d = distance(uavs, n, users(k, 0), users(k, 1));
        if (d < best_d) best_d = d, best = n;
      }
      const bool served = best_d <= coverage_;
      a.serving[kk] = served ? best : -1;
      nearest[kk] = served ? best_d : std::numeric_limits<double>::infinity();
      continue;
    }
    // Served by another UAV (its distance is the nearest of all) or by none (none within R_c, the
    // moved UAV's old place included): only the moved UAV's new distance can change that.
    const double d = distance(uavs, moved, users(k, 0), users(k, 1));
    if (was >= 0 ? (d < nearest[kk] || (d == nearest[kk] && moved < was)) : d <= coverage_) {
      a.serving[kk] = moved;
      nearest[kk] = d;
    }
  }
  for (auto& members : a.users) members.clear();
  for (int k = 0; k < n_user; ++k)  // ascending, as associate lists them
    if (const int n = a.serving[static_cast<std::size_t>(k)]; n >= 0) a.users[static_cast<std::size_t>(n)].push_back(k);
}

Cluster SystemModel::make_cluster(int uav, double ux, double uy, double uz, const Positions& users_xy,
                                  const std::vector<int>& users, int uavs, int slot) const {
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
    c.G.row(static_cast<Eigen::Index>(i)) = channel_->channel_at(ux, uy, uz, users_xy(users[i], 0), users_xy(users[i], 1), slot).adjoint();
  return c;
}

std::vector<Cluster> SystemModel::clusters(const Snapshot& s, const Association& a) const {
  std::vector<Cluster> out;
  for (int n = 0; n < static_cast<int>(a.users.size()); ++n)
    if (!a.users[n].empty())
      out.push_back(make_cluster(n, s.uavs(n, 0), s.uavs(n, 1), altitude_of(s.uavs, n), s.users, a.users[n], static_cast<int>(s.uavs.rows())));
  return out;
}

Network SystemModel::network(const Positions& uavs, const Positions& users_xy,
                             const std::vector<std::vector<int>>& members, int slot) const {
  Network net;
  net.spectrum = spectrum_;
  net.uavs = static_cast<int>(uavs.rows());
  net.offset.push_back(0);
  for (int n = 0; n < net.uavs; ++n) {
    if (members[static_cast<std::size_t>(n)].empty()) continue;
    net.clusters.push_back(make_cluster(n, uavs(n, 0), uavs(n, 1), altitude_of(uavs, n), users_xy, members[static_cast<std::size_t>(n)], net.uavs, slot));
    for (int k : members[static_cast<std::size_t>(n)]) net.served.push_back(k);
    net.offset.push_back(static_cast<int>(net.served.size()));
  }
  const auto ks = static_cast<Eigen::Index>(net.served.size());
  for (const Cluster& c : net.clusters) {
    MatrixXcd H(ks, antennas_);
    for (Eigen::Index r = 0; r < ks; ++r) {
      const int k = net.served[static_cast<std::size_t>(r)];
      H.row(r) = channel_->channel_at(uavs(c.uav, 0), uavs(c.uav, 1), altitude_of(uavs, c.uav), users_xy(k, 0), users_xy(k, 1), slot).adjoint();
    }
    net.cross.push_back(std::move(H));
  }
  return net;
}

Network SystemModel::network(const Snapshot& s, const Association& a) const { return network(s.uavs, s.users, a.users); }

Network SystemModel::network(const Snapshot& s) const { return network(s, associate(s)); }

std::vector<Cluster> SystemModel::clusters(const Snapshot& s) const { return clusters(s, associate(s)); }

Positions draw_users(const ScenarioConfig& s, int users, Rng& rng) {
  Positions p(users, 2);
  const bool hotspot = s.user_layout == UserLayout::Hotspot || (s.user_layout == UserLayout::Mixed && rng.uniform() < 0.5);
  if (!hotspot) {
    for (int k = 0; k < users; ++k) p(k, 0) = rng.uniform(0, s.area_x_m), p(k, 1) = rng.uniform(0, s.area_y_m);
    return p;
  }
  Positions centre(s.hotspots, 2);
  for (int h = 0; h < s.hotspots; ++h) centre(h, 0) = rng.uniform(0, s.area_x_m), centre(h, 1) = rng.uniform(0, s.area_y_m);
  for (int k = 0; k < users; ++k) {
    if (rng.uniform() < s.hotspot_fraction) {
      const auto h = static_cast<Eigen::Index>(rng.below(static_cast<std::uint64_t>(s.hotspots)));
      const double x = centre(h, 0) + s.hotspot_radius_m * rng.normal();
      const double y = centre(h, 1) + s.hotspot_radius_m * rng.normal();
      p(k, 0) = std::clamp(x, 0.0, s.area_x_m), p(k, 1) = std::clamp(y, 0.0, s.area_y_m);
    } else {
      p(k, 0) = rng.uniform(0, s.area_x_m), p(k, 1) = rng.uniform(0, s.area_y_m);
    }
  }
  return p;
}

Snapshot SystemModel::random_snapshot(int uavs, int users, std::uint64_t seed) const {
  // The bounds of scenario.uavs and scenario.users, checked before anything is allocated.
  if (uavs < 1 || uavs > kMaxUavs)
    throw InputError("uavs = " + std::to_string(uavs) + " is out of range: allowed 1 .. " + std::to_string(kMaxUavs));
  if (users < 1 || users > kMaxUsers)
    throw InputError("users = " + std::to_string(users) + " is out of range: allowed 1 .. " + std::to_string(kMaxUsers));
  Rng rng(seed);
  Snapshot s;
  s.uavs.resize(uavs, 2);
  for (int n = 0; n < uavs; ++n) s.uavs(n, 0) = rng.uniform(0, area_x_), s.uavs(n, 1) = rng.uniform(0, area_y_);
  s.users = draw_users(scenario_, users, rng);
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
