// UavEnv's observation and state writers: each fills the rows of its spec entry
// (skyloop/env/spec.hpp) for one agent or for the environment, the paper's 11 reals, the set
// observation (Gaussian kernels of the users and UAVs on two grids), its move gains and radio map,
// the sequential turns' decided landings, and the critic's state.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "skyloop/env/uav_env.hpp"

namespace skyloop {

void UavEnv::write_observation(int n, float* o) const {
  const auto& users = oracle_->users();
  double mx = 0, my = 0;
  for (Eigen::Index k = 0; k < users.rows(); ++k) mx += users(k, 0) - pos_(n, 0), my += users(k, 1) - pos_(n, 1);
  const double K = static_cast<double>(std::max<Eigen::Index>(1, users.rows()));
  o[0] = static_cast<float>(pos_(n, 0) / mission_.area_x);
  o[1] = static_cast<float>(pos_(n, 1) / mission_.area_y);
  o[2] = static_cast<float>(mx / K / mission_.area_x);
  o[3] = static_cast<float>(my / K / mission_.area_y);
  o[4] = static_cast<float>((mission_.destinations(n, 0) - pos_(n, 0)) / mission_.area_x);
  o[5] = static_cast<float>((mission_.destinations(n, 1) - pos_(n, 1)) / mission_.area_y);
  write_previous_action(n, o + 6);
  write_optional(n, o + 6 + (spec_->action.continuous() ? spec_->action.dims : actions()), ObservationField::kPaper);
}

void UavEnv::write_optional(int n, float* o, int array) const {
  for (const auto& f : observation_fields())
    if ((f.arrays & array) && f.on(spec_params_)) {
      f.write(*this, n, o);
      o += f.size(spec_params_);
    }
}

float UavEnv::altitude_share(int n) const {
  const LatticeDynamics& l = *dynamics_->lattice();
  return static_cast<float>((pos_(n, 2) - l.floor_m()) / (l.climb_m() * (l.levels() - 1)));
}

void UavEnv::write_previous_action(int n, float* o) const {
  dynamics_->write_previous_action(prev_action_[static_cast<std::size_t>(n)], current(n), o);
}

std::vector<float> UavEnv::observation(int n) const {
  std::vector<float> o(static_cast<std::size_t>(observation_size()));
  write_observation(n, o.data());
  return o;
}

namespace {
/// The Gaussian kernel of width `width` on a G x G grid of spacing `step` centred on 0 is
/// separable: exp(-(dx - c_i)^2 / (2 s^2)) * exp(-(dy - c_j)^2 / (2 s^2)). One axis's G factors
/// for offset d come from three exponentials and a recurrence (f_{i+1} = f_i r_i, r_{i+1} = r_i q);
/// false (and no factors) where every factor is below e^-24 (4e-11): a point out of reach along
/// one axis adds nothing.
bool kernel_axis(int G, double step, double width, double d, double* f) {
  const double half = (G - 1) / 2.0, inv = 1.0 / (2 * width * width);
  const double g = std::max(0.0, std::abs(d) - half * step);
  if (g * g * inv > 24.0) return false;
  const double q = std::exp(-2 * step * step * inv);
  const double c0 = -half * step;
  f[0] = std::exp(-(d - c0) * (d - c0) * inv);
  double r = std::exp((2 * (d - c0) * step - step * step) * inv);  // f_1 / f_0
  for (int i = 1; i < G; ++i) {
    f[i] = f[i - 1] * r;
    r *= q;
  }
  return true;
}

/// Adds w * fx[i] * fy[j] at every grid point (i, j).
void add_kernel(float* map, int G, const double* fx, const double* fy, double w) {
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < G; ++i) map[j * G + i] += static_cast<float>(w * fx[i] * fy[j]);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SKYLOOP_ENV_CLONES __attribute__((target_clones("avx2", "default"), noinline))
#else
#define SKYLOOP_ENV_CLONES
#endif

/// add_kernel of the points `users` (ascending) on a 7 x 7 map, from factor rows of 8 doubles (the
/// eighth zero). The map is summed in registers, a row of 8 floats per map row, each entry's terms
/// in the same order, each term the same two products and the same float addition as
/// add_kernel's (nothing to contract), so every instruction set writes the same floats as
/// add_kernel point by point.
static_assert(kWideGrid == 7, "add_kernels: a map row is one 8-float vector");
SKYLOOP_ENV_CLONES void add_kernels(float* map, const double* fx, const double* fy, const int* users, std::size_t count,
                                    double w) {
  typedef double d4 __attribute__((vector_size(32), aligned(8), may_alias));
  typedef float f4 __attribute__((vector_size(16)));
  typedef float f8 __attribute__((vector_size(32)));
  constexpr int G = 7, P = 8;
  f8 acc[G];
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < P; ++i) acc[j][i] = i < G ? map[j * G + i] : 0.0f;
  for (std::size_t u = 0; u < count; ++u) {
    const auto k = static_cast<std::size_t>(users[u]) * P;
    const d4 wlo = w * *reinterpret_cast<const d4*>(fx + k), whi = w * *reinterpret_cast<const d4*>(fx + k + 4);
    for (int j = 0; j < G; ++j) {
      const double y = fy[k + static_cast<std::size_t>(j)];
      const f4 lo = __builtin_convertvector(wlo * y, f4), hi = __builtin_convertvector(whi * y, f4);
      acc[j] += __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7);
    }
  }
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < G; ++i) map[j * G + i] = acc[j][i];
}

/// The kernel of a point at offset (dx, dy), computed afresh.
void add_kernel(float* map, int G, double step, double width, double dx, double dy, double w) {
  double fx[16], fy[16];
  if (!kernel_axis(G, step, width, dx, fx) || !kernel_axis(G, step, width, dy, fy)) return;
  add_kernel(map, G, fx, fy, w);
}
}  // namespace

void UavEnv::write_set_observation(int n, float* o) const {
  const double x = pos_(n, 0), y = pos_(n, 1);
  const int left = t_max_ - t_;
  *o++ = static_cast<float>(x / mission_.area_x);
  *o++ = static_cast<float>(y / mission_.area_y);
  *o++ = static_cast<float>((mission_.destinations(n, 0) - x) / mission_.area_x);
  *o++ = static_cast<float>((mission_.destinations(n, 1) - y) / mission_.area_y);
  *o++ = static_cast<float>(left - min_moves(n, x, y, pos_(n, 2))) / static_cast<float>(t_max_);
  *o++ = static_cast<float>(t_) / static_cast<float>(t_max_);
  write_previous_action(n, o);
  o += spec_->action.continuous() ? spec_->action.dims : actions();
  constexpr int W = kWideGrid * kWideGrid, Q = kNearGrid * kNearGrid;
  std::fill(o, o + 2 * W + Q, 0.0f);
  const auto& users = oracle_->users();
  const double per_user = 4.0 / static_cast<double>(std::max<Eigen::Index>(1, users.rows()));
  // The users' factors along each axis depend on the UAV's coordinate alone (the users are fixed
  // until set_oracle): computed once per coordinate, a few dozen per episode, where each UAV's
  // each slot would otherwise take five exponentials per user. A user out of reach along one axis
  // has zero factors there: its kernel would add +0 to every (non-negative) entry, so only the
  // users within reach along the axis with fewer of them are visited, in order. The same floats
  // as every kernel computed and added afresh.
  const auto K = users.rows();
  constexpr std::size_t P = kWideGrid + 1;  // factor rows padded with a zero
  auto axis = [&](std::unordered_map<std::uint64_t, KernelAxes::Axis>& index, double at, int dim) {
    std::uint64_t bits;
    std::memcpy(&bits, &at, sizeof bits);
    const auto [it, fresh] = index.try_emplace(bits);
    if (fresh) {
      auto& t = kernel_axes_;
      KernelAxes::Axis& a = it->second;
      a.factors = t.f.size();
      a.reach = t.reach.size();
      t.f.resize(t.f.size() + static_cast<std::size_t>(K) * P, 0.0);
      for (Eigen::Index k = 0; k < K; ++k)
        if (kernel_axis(kWideGrid, 2 * d_fly_, 2 * d_fly_, users(k, dim) - at, t.f.data() + a.factors + static_cast<std::size_t>(k) * P))
          t.reach.push_back(static_cast<int>(k));
      a.count = t.reach.size() - a.reach;
    }
    return it->second;
  };
  // Bounded: continuous moves visit new coordinates every slot (a lattice, a few hundred at most).
  if (kernel_axes_.f.size() + 2 * static_cast<std::size_t>(K) * P > (std::size_t{1} << 21)) kernel_axes_.clear();
  const KernelAxes::Axis ax = axis(kernel_axes_.x, x, 0), ay = axis(kernel_axes_.y, y, 1);
  const KernelAxes::Axis& fewer = ax.count <= ay.count ? ax : ay;
  add_kernels(o, kernel_axes_.f.data() + ax.factors, kernel_axes_.f.data() + ay.factors,
              kernel_axes_.reach.data() + fewer.reach, fewer.count, per_user);
  const Positions& seen = seen_positions();
  for (int m = 0; m < n_; ++m) {
    if (m == n) continue;
    add_kernel(o + W, kWideGrid, 2 * d_fly_, 2 * d_fly_, seen(m, 0) - x, seen(m, 1) - y, 1.0);
    add_kernel(o + 2 * W, kNearGrid, d_fly_, d_fly_ / 2, seen(m, 0) - x, seen(m, 1) - y, 1.0);
  }
  o += 2 * W + Q;
  write_optional(n, o, ObservationField::kSet);
}

const std::vector<ObservationField>& observation_fields() {
  using F = ObservationField;
  static const std::vector<ObservationField> fields = {
      // marl.lookahead: tanh(kGainScale (R_a - R) / R) of each action (continuous: each primitive).
      {"move_gains", F::kSet, [](const SpecParams& p) { return p.lookahead; }, [](const SpecParams& p) { return p.action.count(); }, -1, 1,
       [](const UavEnv& e, int n, float* o) { e.write_move_gains(n, o); }},
      // marl.rate_map = r: tanh(kGainScale (R_c - R) / R) at each cell c of rate_map_offsets(r); -1 outside the area.
      {"rate_map", F::kSet, [](const SpecParams& p) { return p.rate_map > 0; },
       [](const SpecParams& p) { return static_cast<int>(rate_map_offsets(p.rate_map).size()); }, -1, 1,
       [](const UavEnv& e, int n, float* o) { e.write_rate_map(n, o); }},
      // Dynamics that choose the altitude: (z - altitude_min_m) / (altitude_max_m - altitude_min_m).
      {"altitude", F::kPaper | F::kSet, [](const SpecParams& p) { return p.altitude; }, [](const SpecParams&) { return 1; }, 0, 1,
       [](const UavEnv& e, int n, float* o) { *o = e.altitude_share(n); }},
  };
  return fields;
}

void UavEnv::show_decided(int m, double x, double y, double z) {
  if (m < 0 || m >= n_) throw std::out_of_range("UavEnv::show_decided: no UAV " + std::to_string(m));
  if (!any_decided_) seen_ = pos_;
  any_decided_ = true;
  seen_(m, 0) = x, seen_(m, 1) = y, seen_(m, 2) = z;
}

void UavEnv::clear_decided() { any_decided_ = false; }

void UavEnv::write_rate_map(int n, float* o) const {
  const auto& cells = rate_map_offsets(spec_params_.rate_map);
  const int C = static_cast<int>(cells.size());
  std::fill(o, o + C, 0.0f);
  if (arrived(n)) return;
  const Positions& seen = seen_positions();
  std::vector<Positions> sets(1, seen);  // sets[0]: where the UAVs are now (the decided ones landed)
  std::vector<int> at(static_cast<std::size_t>(C), -1);
  for (int c = 0; c < C; ++c) {
    const double x = pos_(n, 0) + d_fly_ * cells[static_cast<std::size_t>(c)][0];
    const double y = pos_(n, 1) + d_fly_ * cells[static_cast<std::size_t>(c)][1];
    if (x < 0 || y < 0 || x > mission_.area_x || y > mission_.area_y) {
      o[c] = -1.0f;
      continue;
    }
    at[static_cast<std::size_t>(c)] = static_cast<int>(sets.size());
    sets.push_back(seen);
    sets.back()(n, 0) = x;
    sets.back()(n, 1) = y;
  }
  const auto r = oracle_->sum_rates(sets);
  const double now = r[0];
  if (!(now > 0)) return;  // the cells inside the area stay 0
  for (int c = 0; c < C; ++c)
    if (const int i = at[static_cast<std::size_t>(c)]; i >= 0)
      o[c] = static_cast<float>(std::tanh(kGainScale * (r[static_cast<std::size_t>(i)] - now) / now));
}

void UavEnv::write_move_gains(int n, float* o) const {
  const int A = actions();
  std::fill(o, o + A, 0.0f);
  if (arrived(n)) return;
  // sets[0]: where the UAVs are now; sets[1 + a]: UAV n after move a. Each set moves one UAV from
  // the one before it (the first: the UAV that chose before n, shown landed), which the oracle
  // reassociates for that UAV alone (RateOracle::keys_of).
  std::vector<Positions> sets(static_cast<std::size_t>(A) + 1, seen_positions());
  for (int a = 0; a < A; ++a) {
    place(sets[static_cast<std::size_t>(a) + 1], n, landing(n, a));
  }
  const auto r = oracle_->sum_rates(sets);
  const double now = r[0];
  if (!(now > 0)) return;
  for (int a = 0; a < A; ++a) o[a] = static_cast<float>(std::tanh(kGainScale * (r[static_cast<std::size_t>(a) + 1] - now) / now));
}

void UavEnv::write_compact_state(float* s) const {
  const auto& users = oracle_->users();
  {
    constexpr int G = kStateGrid;
    std::fill(s, s + compact_state_size(), 0.0f);
    auto cell = [&](double x, double y) {
      const int ix = std::min(G - 1, std::max(0, static_cast<int>(x / mission_.area_x * G)));
      const int iy = std::min(G - 1, std::max(0, static_cast<int>(y / mission_.area_y * G)));
      return iy * G + ix;
    };
    const float per_user = 1.0f / static_cast<float>(std::max<Eigen::Index>(1, users.rows()));
    const float per_uav = 1.0f / static_cast<float>(n_);
    for (Eigen::Index k = 0; k < users.rows(); ++k) s[cell(users(k, 0), users(k, 1))] += per_user;
    int home = 0;
    for (int n = 0; n < n_; ++n) {
      s[G * G + cell(pos_(n, 0), pos_(n, 1))] += per_uav;
      if (arrived(n)) ++home;
      else s[2 * G * G + cell(mission_.destinations(n, 0), mission_.destinations(n, 1))] += per_uav;
    }
    s[3 * G * G] = static_cast<float>(t_) / static_cast<float>(t_max_);
    s[3 * G * G + 1] = static_cast<float>(home) * per_uav;
  }
}

void UavEnv::write_state(float* s) const {
  const auto& users = oracle_->users();
  if (compact_) {
    write_compact_state(s);
    return;
  }
  for (int n = 0; n < n_; ++n) *s++ = static_cast<float>(pos_(n, 0) / mission_.area_x), *s++ = static_cast<float>(pos_(n, 1) / mission_.area_y);
  for (Eigen::Index k = 0; k < users.rows(); ++k)
    *s++ = static_cast<float>(users(k, 0) / mission_.area_x), *s++ = static_cast<float>(users(k, 1) / mission_.area_y);
  for (int n = 0; n < n_; ++n) *s++ = static_cast<float>(mission_.destinations(n, 0) / mission_.area_x), *s++ = static_cast<float>(mission_.destinations(n, 1) / mission_.area_y);
}

void UavEnv::write_agent_context(int n, float* out) const {
  if (!compact_) {
    for (int m = 0; m < n_; ++m) out[m] = m == n ? 1.0f : 0.0f;
    return;
  }
  // The kNeighbours nearest other UAVs (distance, then index), nearest first.
  std::vector<std::pair<double, int>> near;
  for (int m = 0; m < n_; ++m)
    if (m != n) near.emplace_back(std::hypot(pos_(m, 0) - pos_(n, 0), pos_(m, 1) - pos_(n, 1)), m);
  const std::size_t take = std::min<std::size_t>(kNeighbours, near.size());
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(take), near.end());
  std::fill(out, out + 2 * kNeighbours, 0.0f);
  for (std::size_t i = 0; i < take; ++i) {
    const int m = near[i].second;
    out[2 * i] = static_cast<float>((pos_(m, 0) - pos_(n, 0)) / mission_.area_x);
    out[2 * i + 1] = static_cast<float>((pos_(m, 1) - pos_(n, 1)) / mission_.area_y);
  }
}

std::vector<float> UavEnv::state() const {
  std::vector<float> s(static_cast<std::size_t>(state_size()));
  write_state(s.data());
  return s;
}

void UavEnv::write_agent_state(int n, float* out) const {
  write_state(out);
  write_agent_context(n, out + state_size());
  write_observation(n, out + state_size() + agent_context_size());
}

std::vector<float> UavEnv::agent_state(int n) const {
  std::vector<float> s(static_cast<std::size_t>(agent_state_size()));
  write_agent_state(n, s.data());
  return s;
}

void UavEnv::write_obs(int n, float* out) const {
  if (spec_->observation_kind == ObservationKind::Set) write_set_observation(n, out);
  else write_observation(n, out);
}

}  // namespace skyloop
