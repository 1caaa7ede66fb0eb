// The observation and state fields (skyloop/env/spec.hpp): one row per field in observation_fields()
// and state_fields(), its layout and its writer together; the spec lays the arrays out from those
// rows, and UavEnv writes an array by calling each field's writer at its offset. Here too the set
// observation's Gaussian kernels (with their cache), its move gains and radio map, and the
// sequential turns' decided landings.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "skyloop/env/uav_env.hpp"

namespace skyloop {

void UavEnv::write_array(const ArraySpec& a, int n, float* out) const {
  for (const auto& f : a.fields) f.write(*this, n, out + f.offset);
}

void UavEnv::write_observation(int n, float* o) const { write_array(spec_->paper_obs, n, o); }

float UavEnv::altitude_share(int n) const {
  const LatticeDynamics& l = *dynamics_->lattice();
  return static_cast<float>((world_.positions(n, 2) - l.floor_m()) / (l.climb_m() * (l.levels() - 1)));
}

void UavEnv::write_previous_action(int n, float* o) const {
  dynamics_->write_previous_action(world_.previous_action[static_cast<std::size_t>(n)], current(n), o);
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

void UavEnv::write_set_observation(int n, float* o) const { write_array(spec_->set_obs, n, o); }

void UavEnv::write_users_density(int n, float* o) const {
  const double x = world_.positions(n, 0), y = world_.positions(n, 1);
  std::fill(o, o + kWideGrid * kWideGrid, 0.0f);
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
}

void UavEnv::write_uav_kernels(int n, float* o, int G, double step, double width) const {
  std::fill(o, o + G * G, 0.0f);
  const Positions& seen = seen_positions();
  for (int m = 0; m < n_; ++m)
    if (m != n) add_kernel(o, G, step, width, seen(m, 0) - world_.positions(n, 0), seen(m, 1) - world_.positions(n, 1), 1.0);
}

// Every observation field, in the order the observations hold them (the paper's 11 reals: the
// rows marked kPaper; the set observation: kSet). A row is the field's whole definition: where it
// appears, when it is on, its size and bounds, and its writer.
const std::vector<ObservationField>& observation_fields() {
  using F = ObservationField;
  using P = const SpecParams&;
  static const std::vector<ObservationField> fields = {
      // (x, y) / area side.
      {"own_position", F::kPaper | F::kSet, [](P) { return true; }, [](P) { return 2; }, 0, 1,
       [](const UavEnv& e, int n, float* o) {
         o[0] = static_cast<float>(e.world_.positions(n, 0) / e.mission_.area_x);
         o[1] = static_cast<float>(e.world_.positions(n, 1) / e.mission_.area_y);
       }},
      // The mean over the users of (u - x) / area side.
      {"users_mean_displacement", F::kPaper, [](P) { return true; }, [](P) { return 2; }, -1, 1,
       [](const UavEnv& e, int n, float* o) {
         const auto& users = e.oracle_->users();
         double mx = 0, my = 0;
         for (Eigen::Index k = 0; k < users.rows(); ++k) mx += users(k, 0) - e.world_.positions(n, 0), my += users(k, 1) - e.world_.positions(n, 1);
         const double K = static_cast<double>(std::max<Eigen::Index>(1, users.rows()));
         o[0] = static_cast<float>(mx / K / e.mission_.area_x);
         o[1] = static_cast<float>(my / K / e.mission_.area_y);
       }},
      // (destination - x) / area side.
      {"destination_displacement", F::kPaper | F::kSet, [](P) { return true; }, [](P) { return 2; }, -1, 1,
       [](const UavEnv& e, int n, float* o) {
         o[0] = static_cast<float>((e.mission_.destinations(n, 0) - e.world_.positions(n, 0)) / e.mission_.area_x);
         o[1] = static_cast<float>((e.mission_.destinations(n, 1) - e.world_.positions(n, 1)) / e.mission_.area_y);
       }},
      // (moves left - moves needed) / T_max; the moves needed are at most the grid's Manhattan
      // distance across the area, or t_max + 1 (out of reach, UavEnv::min_moves) under other models.
      {"slack", F::kSet, [](P) { return true; }, [](P) { return 1; }, 0, 1,
       [](const UavEnv& e, int n, float* o) {
         const int left = e.t_max_ - e.world_.slot;
         *o = static_cast<float>(left - e.min_moves(n, e.world_.positions(n, 0), e.world_.positions(n, 1), e.world_.positions(n, 2))) / static_cast<float>(e.t_max_);
       },
       [](P p, float& low, float&) {
         const double moves = std::max(std::ceil(p.area_x / p.d_fly) + std::ceil(p.area_y / p.d_fly), p.t_max + 1.0);
         low = static_cast<float>(-moves / p.t_max);
       }},
      // t / T_max.
      {"time", F::kSet, [](P) { return true; }, [](P) { return 1; }, 0, 1,
       [](const UavEnv& e, int, float* o) { *o = static_cast<float>(e.world_.slot) / static_cast<float>(e.t_max_); }},
      // One-hot over a discrete model's actions (Dynamics::write_previous_action) ...
      {"previous_action", F::kPaper | F::kSet, [](P p) { return !p.action.continuous(); }, [](P p) { return p.action.count(); }, 0, 1,
       [](const UavEnv& e, int n, float* o) { e.write_previous_action(n, o); }},
      // ... or a commanding model's last velocity / v_max.
      {"previous_velocity", F::kPaper | F::kSet, [](P p) { return p.action.continuous(); }, [](P p) { return p.action.dims; }, -1, 1,
       [](const UavEnv& e, int n, float* o) { e.write_previous_action(n, o); }},
      // (4 / K) sum_k of the users' Gaussian kernels on the wide grid around the UAV.
      {"users_density", F::kSet, [](P) { return true; }, [](P) { return kWideGrid * kWideGrid; }, 0, 4,
       [](const UavEnv& e, int n, float* o) { e.write_users_density(n, o); }},
      // The other UAVs' kernels on the wide grid (spacing and width 2 D_fly), and on the near one
      // (spacing D_fly, width D_fly / 2: who is one move away); at most N - 1 each.
      {"uavs_wide", F::kSet, [](P) { return true; }, [](P) { return kWideGrid * kWideGrid; }, 0, 0,
       [](const UavEnv& e, int n, float* o) { e.write_uav_kernels(n, o, kWideGrid, 2 * e.d_fly_, 2 * e.d_fly_); },
       [](P p, float&, float& high) { high = static_cast<float>(std::max(0, p.agents - 1)); }},
      {"uavs_near", F::kSet, [](P) { return true; }, [](P) { return kNearGrid * kNearGrid; }, 0, 0,
       [](const UavEnv& e, int n, float* o) { e.write_uav_kernels(n, o, kNearGrid, e.d_fly_, e.d_fly_ / 2); },
       [](P p, float&, float& high) { high = static_cast<float>(std::max(0, p.agents - 1)); }},
      // marl.lookahead: tanh(kGainScale (R_a - R) / R) of each action (continuous: each primitive).
      {"move_gains", F::kSet, [](P p) { return p.lookahead; }, [](P p) { return p.action.count(); }, -1, 1,
       [](const UavEnv& e, int n, float* o) { e.write_move_gains(n, o); }},
      // marl.rate_map = r: tanh(kGainScale (R_c - R) / R) at each cell c of rate_map_offsets(r); -1 outside the area.
      {"rate_map", F::kSet, [](P p) { return p.rate_map > 0; },
       [](P p) { return static_cast<int>(rate_map_offsets(p.rate_map).size()); }, -1, 1,
       [](const UavEnv& e, int n, float* o) { e.write_rate_map(n, o); }},
      // Dynamics that choose the altitude: (z - altitude_min_m) / (altitude_max_m - altitude_min_m).
      {"altitude", F::kPaper | F::kSet, [](P p) { return p.altitude; }, [](P) { return 1; }, 0, 1,
       [](const UavEnv& e, int n, float* o) { *o = e.altitude_share(n); }},
  };
  return fields;
}

void UavEnv::show_decided(int m, double x, double y, double z) {
  if (m < 0 || m >= n_) throw std::out_of_range("UavEnv::show_decided: no UAV " + std::to_string(m));
  if (!any_decided_) seen_ = world_.positions;
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
    const double x = world_.positions(n, 0) + d_fly_ * cells[static_cast<std::size_t>(c)][0];
    const double y = world_.positions(n, 1) + d_fly_ * cells[static_cast<std::size_t>(c)][1];
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

namespace {
/// The compact state's cell of point (x, y): a G x G grid over the area.
int state_cell(const Mission& m, double x, double y) {
  constexpr int G = kStateGrid;
  const int ix = std::min(G - 1, std::max(0, static_cast<int>(x / m.area_x * G)));
  const int iy = std::min(G - 1, std::max(0, static_cast<int>(y / m.area_y * G)));
  return iy * G + ix;
}
}  // namespace

// Every state field, in the order its array holds them.
const std::vector<StateField>& state_fields() {
  using F = StateField;
  using P = const SpecParams&;
  constexpr int G2 = kStateGrid * kStateGrid;
  static const std::vector<StateField> fields = {
      // The paper's s[t]: every UAV's position, every user's, every destination, each / area side.
      {"uav_positions", F::kPaperState, [](P p) { return 2 * p.agents; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         for (int n = 0; n < e.n_; ++n)
           *s++ = static_cast<float>(e.world_.positions(n, 0) / e.mission_.area_x), *s++ = static_cast<float>(e.world_.positions(n, 1) / e.mission_.area_y);
       }},
      {"user_positions", F::kPaperState, [](P p) { return 2 * p.users; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         const auto& users = e.oracle_->users();
         for (Eigen::Index k = 0; k < users.rows(); ++k)
           *s++ = static_cast<float>(users(k, 0) / e.mission_.area_x), *s++ = static_cast<float>(users(k, 1) / e.mission_.area_y);
       }},
      {"destinations", F::kPaperState, [](P p) { return 2 * p.agents; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         for (int n = 0; n < e.n_; ++n)
           *s++ = static_cast<float>(e.mission_.destinations(n, 0) / e.mission_.area_x),
           *s++ = static_cast<float>(e.mission_.destinations(n, 1) / e.mission_.area_y);
       }},
      // The compact state: shares per cell of a kStateGrid x kStateGrid grid over the area.
      {"user_density", F::kCompactState, [](P) { return G2; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         const auto& users = e.oracle_->users();
         std::fill(s, s + G2, 0.0f);
         const float per_user = 1.0f / static_cast<float>(std::max<Eigen::Index>(1, users.rows()));
         for (Eigen::Index k = 0; k < users.rows(); ++k) s[state_cell(e.mission_, users(k, 0), users(k, 1))] += per_user;
       }},
      {"uav_density", F::kCompactState, [](P) { return G2; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         std::fill(s, s + G2, 0.0f);
         const float per_uav = 1.0f / static_cast<float>(e.n_);
         for (int n = 0; n < e.n_; ++n) s[state_cell(e.mission_, e.world_.positions(n, 0), e.world_.positions(n, 1))] += per_uav;
       }},
      // The not-yet-arrived UAVs' destinations.
      {"destination_density", F::kCompactState, [](P) { return G2; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         std::fill(s, s + G2, 0.0f);
         const float per_uav = 1.0f / static_cast<float>(e.n_);
         for (int n = 0; n < e.n_; ++n)
           if (!e.arrived(n)) s[state_cell(e.mission_, e.mission_.destinations(n, 0), e.mission_.destinations(n, 1))] += per_uav;
       }},
      {"time", F::kCompactState, [](P) { return 1; }, 0, 1,  // t / T_max
       [](const UavEnv& e, int, float* s) { *s = static_cast<float>(e.world_.slot) / static_cast<float>(e.t_max_); }},
      {"arrived_share", F::kCompactState, [](P) { return 1; }, 0, 1,
       [](const UavEnv& e, int, float* s) {
         int home = 0;
         for (int n = 0; n < e.n_; ++n) home += e.arrived(n) ? 1 : 0;
         *s = static_cast<float>(home) * (1.0f / static_cast<float>(e.n_));
       }},
      // Who agent n is, under the paper's state: a one-hot id.
      {"agent_id", F::kIdContext, [](P p) { return p.agents; }, 0, 1,
       [](const UavEnv& e, int n, float* out) {
         for (int m = 0; m < e.n_; ++m) out[m] = m == n ? 1.0f : 0.0f;
       }},
      // Under the compact state: displacements / area to the kNeighbours nearest other UAVs
      // (distance, then index), nearest first, zeros past N - 1.
      {"neighbour_displacements", F::kNeighbourContext, [](P) { return 2 * kNeighbours; }, -1, 1,
       [](const UavEnv& e, int n, float* out) {
         std::vector<std::pair<double, int>> near;
         for (int m = 0; m < e.n_; ++m)
           if (m != n) near.emplace_back(std::hypot(e.world_.positions(m, 0) - e.world_.positions(n, 0), e.world_.positions(m, 1) - e.world_.positions(n, 1)), m);
         const std::size_t take = std::min<std::size_t>(kNeighbours, near.size());
         std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(take), near.end());
         std::fill(out, out + 2 * kNeighbours, 0.0f);
         for (std::size_t i = 0; i < take; ++i) {
           const int m = near[i].second;
           out[2 * i] = static_cast<float>((e.world_.positions(m, 0) - e.world_.positions(n, 0)) / e.mission_.area_x);
           out[2 * i + 1] = static_cast<float>((e.world_.positions(m, 1) - e.world_.positions(n, 1)) / e.mission_.area_y);
         }
       }},
  };
  return fields;
}

void UavEnv::write_compact_state(float* s) const { write_array(compact_state_spec(), 0, s); }

void UavEnv::write_state(float* s) const { write_array(spec_->state, 0, s); }

void UavEnv::write_agent_context(int n, float* out) const { write_array(spec_->agent_context, n, out); }

std::vector<float> UavEnv::state() const {
  std::vector<float> s(static_cast<std::size_t>(state_size()));
  write_state(s.data());
  return s;
}

void UavEnv::write_agent_state(int n, float* out) const { write_array(spec_->agent_state, n, out); }

std::vector<float> UavEnv::agent_state(int n) const {
  std::vector<float> s(static_cast<std::size_t>(agent_state_size()));
  write_agent_state(n, s.data());
  return s;
}

void UavEnv::write_obs(int n, float* out) const { write_array(spec_->obs, n, out); }

}  // namespace skyloop
