#include "skyloop/env/vec_env.hpp"

#include <algorithm>
#include <numeric>

#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/layouts.hpp"

namespace skyloop {

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, int count, std::uint64_t seed)
    : cfg_(cfg), beamformer_(std::move(beamformer)), seed_(seed), episodes_(static_cast<std::size_t>(count), 0),
      settled_(static_cast<std::size_t>(count), 0), cost_(static_cast<std::size_t>(count), -1.0),
      prepared_(static_cast<std::size_t>(count)) {
  if (count < 1) throw std::invalid_argument("VecEnv: count = " + std::to_string(count) + ", allowed at least 1");
  // One environment made from the configuration (over environment 0's users), the others copies
  // of it (sharing its lattice tables) with their own users.
  UavEnv::require_table_memory(cfg_, count);
  like_ = std::make_unique<const UavEnv>(cfg_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(0, 0)));
  envs_.push_back(std::make_unique<UavEnv>(*like_));
  for (int i = 1; i < count; ++i)
    envs_.push_back(std::make_unique<UavEnv>(*like_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(static_cast<std::size_t>(i), 0))));
}

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, const std::vector<std::uint64_t>& layouts)
    : cfg_(cfg), beamformer_(std::move(beamformer)), seed_(0), episodes_(layouts.size(), 0), settled_(layouts.size(), 0),
      cost_(layouts.size(), -1.0), prepared_(layouts.size()), layouts_(layouts) {
  if (layouts.empty()) throw std::invalid_argument("VecEnv: no layouts, allowed at least 1");
  for (const auto s : layouts) layout_split(s);  // a layout's seed (InputError otherwise)
  UavEnv::require_table_memory(cfg_, static_cast<int>(layouts.size()));
  like_ = std::make_unique<const UavEnv>(cfg_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(0, 0)));
  envs_.push_back(std::make_unique<UavEnv>(*like_));
  for (std::size_t i = 1; i < layouts.size(); ++i)
    envs_.push_back(std::make_unique<UavEnv>(*like_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(i, 0))));
}

bool VecEnv::sampling() const {
  return !shared_ && layouts_.empty() && cfg_.env.resample_users && cfg_.env.users_file.empty();
}

Positions VecEnv::users_of(std::size_t i, std::uint64_t episode) const {
  if (!layouts_.empty()) return layout_users(cfg_, layouts_[i]);
  if (sampling()) return layout_users(cfg_, training_layout_seed(seed_, i, episode));
  return make_users(cfg_, cfg_.scenario.users, derive_seed(seed_, static_cast<std::uint64_t>(i)));
}

std::shared_ptr<RateOracle> VecEnv::next_oracle(std::size_t i) const {
  return std::make_shared<RateOracle>(cfg_, beamformer_, users_of(i, episodes_[i] + 1));
}

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, int count)
    : cfg_(cfg), seed_(0), episodes_(static_cast<std::size_t>(count), 0), settled_(static_cast<std::size_t>(count), 0),
      cost_(static_cast<std::size_t>(count), -1.0), prepared_(static_cast<std::size_t>(count)), shared_(true) {
  if (count < 1) throw std::invalid_argument("VecEnv: count = " + std::to_string(count) + ", allowed at least 1");
  UavEnv::require_table_memory(cfg_, count);
  like_ = std::make_unique<const UavEnv>(cfg_, oracle);
  for (int i = 0; i < count; ++i) envs_.push_back(std::make_unique<UavEnv>(*like_));  // sharing its lattice tables
}

void VecEnv::reset_env(std::size_t i) {
  if (sampling()) {
    // The oracle finish() prepared with its start's rate, else a new one.
    Prepared p = std::move(prepared_[i]);
    prepared_[i] = Prepared{};
    if (!p.oracle) {
      p.oracle = next_oracle(i);
      p.start_rate = p.oracle->sum_rate(envs_[i]->starts());
    }
    ++episodes_[i];
    envs_[i]->set_oracle(std::move(p.oracle), p.start_rate);
  } else {
    ++episodes_[i];
    envs_[i]->reset();
  }
}

void VecEnv::reset() {
  for (std::size_t i = 0; i < envs_.size(); ++i) reset_env(i);
}

Positions VecEnv::begin(int i, const std::vector<int>& actions, StepInfo& info) {
  settled_[static_cast<std::size_t>(i)] = 0;
  cost_[static_cast<std::size_t>(i)] = -1.0;
  return envs_[static_cast<std::size_t>(i)]->begin_step(actions, info);
}

Positions VecEnv::begin_velocities(int i, const Positions& velocities, StepInfo& info) {
  settled_[static_cast<std::size_t>(i)] = 0;
  cost_[static_cast<std::size_t>(i)] = -1.0;
  return envs_[static_cast<std::size_t>(i)]->begin_step_velocities(velocities, info);
}

bool VecEnv::settle(int i, const Positions& next, StepInfo& info) {
  if (shared_) return false;
  const auto ii = static_cast<std::size_t>(i);
  const auto rate = envs_[ii]->oracle().cached_sum_rate(next, &cost_[ii]);
  if (!rate) return false;
  envs_[ii]->end_step(next, *rate, info);
  if (info.done) reset_env(ii);
  settled_[ii] = 1;
  return true;
}

std::vector<StepInfo> VecEnv::step(const std::vector<std::vector<int>>& actions,
                                   const std::function<void(std::size_t)>& before_reset) {
  std::vector<StepInfo> info(envs_.size());
  std::vector<Positions> next(envs_.size());
  for (int i = 0; i < size(); ++i) next[static_cast<std::size_t>(i)] = begin(i, actions[static_cast<std::size_t>(i)], info[static_cast<std::size_t>(i)]);
  return finish(next, info, before_reset);
}

std::vector<StepInfo> VecEnv::step_velocities(const std::vector<Positions>& velocities,
                                              const std::function<void(std::size_t)>& before_reset) {
  std::vector<StepInfo> info(envs_.size());
  std::vector<Positions> next(envs_.size());
  for (int i = 0; i < size(); ++i)
    next[static_cast<std::size_t>(i)] = begin_velocities(i, velocities[static_cast<std::size_t>(i)], info[static_cast<std::size_t>(i)]);
  return finish(next, info, before_reset);
}

std::vector<StepInfo> VecEnv::finish(std::vector<Positions>& next, std::vector<StepInfo>& info,
                                     const std::function<void(std::size_t)>& before_reset) {
  const std::size_t m = envs_.size();
  std::vector<std::size_t> open;  // the environments whose step is still to end
  for (std::size_t i = 0; i < m; ++i)
    if (!settled_[i]) open.push_back(i);
  // Oracles of their own (no memo shared): the open environments in lanes, one per thread (below).
  // A shared oracle: one batch, its misses split over the threads. The steps end once every rate
  // is known.
  int threads = 1;
  if (!shared_ && !in_parallel_for())
    for (std::size_t i : open) threads = std::max(threads, envs_[i]->oracle().threads());
  // Under one band a network's beams may depend, in their last bits, on the other networks of
  // its batch (RateOracle::joint): oracles of their own then keep one lane per environment, the
  // same company on any thread count (an MPI rank's one core or a machine's all).
  bool per_environment = !shared_;
  for (std::size_t i : open) per_environment = per_environment && envs_[i]->oracle().joint();
  per_environment = per_environment && !open.empty();
  const std::size_t lanes = per_environment ? open.size() : std::min(open.size(), static_cast<std::size_t>(threads));
  // The environments whose episode this step ends: their next oracle's start in the same batch.
  std::vector<char> ends(open.size(), 0);
  for (std::size_t j = 0; j < open.size() && sampling(); ++j) ends[j] = envs_[open[j]]->ends_episode(next[open[j]]);
  // The lanes: each open environment's place in `open`, in order. Where settle() weighed every
  // open environment by its misses (and an ending one by its next start's, every cluster a miss),
  // the heaviest first to the lighter lane; else contiguous runs of equal count.
  std::vector<std::vector<std::size_t>> lane_of(lanes);
  bool weighed = lanes > 1 && !per_environment;
  for (std::size_t i : open) weighed = weighed && cost_[i] >= 0;
  if (weighed) {
    std::vector<double> weight(open.size());
    std::vector<std::size_t> heaviest(open.size());
    for (std::size_t j = 0; j < open.size(); ++j) {
      const UavEnv& e = *envs_[open[j]];
      weight[j] = cost_[open[j]] + (ends[j] ? static_cast<double>(e.users() + e.uavs()) : 0.0);
      heaviest[j] = j;
    }
    std::stable_sort(heaviest.begin(), heaviest.end(), [&](std::size_t a, std::size_t b) { return weight[a] > weight[b]; });
    std::vector<double> load(lanes, 0.0);
    for (std::size_t j : heaviest) {
      const auto lane = static_cast<std::size_t>(std::min_element(load.begin(), load.end()) - load.begin());
      load[lane] += weight[j];
      lane_of[lane].push_back(j);
    }
    for (auto& l : lane_of) std::sort(l.begin(), l.end());
  } else {
    for (std::size_t lane = 0; lane < lanes; ++lane)
      for (std::size_t j = open.size() * lane / lanes; j < open.size() * (lane + 1) / lanes; ++j) lane_of[lane].push_back(j);
  }
  // Each lane's misses one batch on a thread of its own: a cluster's rate is designed per cluster,
  // so the rates do not depend on the lanes (nor, one lane per environment, a network's).
  std::vector<double> rates(open.size());
  parallel_for(lanes, static_cast<int>(std::min(lanes, static_cast<std::size_t>(threads))), [&](std::size_t lane) {
    const auto& mine = lane_of[lane];
    std::vector<RateOracle*> oracles;
    std::vector<const Positions*> ptrs;
    for (std::size_t j : mine) {
      oracles.push_back(&envs_[open[j]]->oracle());
      ptrs.push_back(&next[open[j]]);
    }
    // An episode this step ends: its environment's next oracle, the start's rate in the same batch
    // (kept for reset_env only once the batch has succeeded).
    std::vector<std::size_t> ending;
    std::vector<std::shared_ptr<RateOracle>> fresh;
    for (std::size_t j : mine) {
      if (!ends[j]) continue;
      const std::size_t i = open[j];
      ending.push_back(i);
      fresh.push_back(next_oracle(i));
      oracles.push_back(fresh.back().get());
      ptrs.push_back(&envs_[i]->starts());
    }
    const auto r = batch_sum_rates(oracles, ptrs);
    for (std::size_t k = 0; k < mine.size(); ++k) rates[mine[k]] = r[k];
    for (std::size_t k = 0; k < ending.size(); ++k) prepared_[ending[k]] = Prepared{std::move(fresh[k]), r[mine.size() + k]};
  });
  for (std::size_t j = 0; j < open.size(); ++j) {
    const std::size_t i = open[j];
    envs_[i]->end_step(next[i], rates[j], info[i]);
    if (info[i].done) {
      if (before_reset) before_reset(i);
      reset_env(i);
    }
  }
  std::fill(settled_.begin(), settled_.end(), 0);
  return info;
}

}  // namespace skyloop
