#pragma once
// User layouts for training and judging trajectory policies on layouts they never saw.
//
// A layout is the users of one episode (the UAVs' starts and destinations stay the scenario's).
// Every layout is named by its users seed, and the seeds of the three splits are disjoint ranges,
// so a test layout can never be drawn in training, whatever the run's seed:
//   train       [0, 2^62)           marl.users_seed, and every layout sampled in training
//   validation  [2^62, 2^63)        model selection during training (marl.val_layouts)
//   test        [2^63, 2^63 + 2^62) `skyloop eval --layouts`, the generalisation experiment
// Layout i of a split has users seed split * 2^62 + i; training samples its layouts by hashing
// (run seed, environment, episode) into the training range.
#include <cstdint>
#include <string>

#include "skyloop/core/config.hpp"
#include "skyloop/core/types.hpp"

namespace skyloop {

enum class LayoutSplit : std::uint64_t { Train = 0, Validation = 1, Test = 2 };
constexpr int kLayoutSplitBits = 62;

const char* to_string(LayoutSplit s);
/// "train" | "validation" | "test"; throws InputError naming `field` otherwise.
LayoutSplit parse_layout_split(const std::string& s, const std::string& field);

/// Users seed of layout `index` (< 2^62) of `split`.
std::uint64_t layout_seed(LayoutSplit split, std::uint64_t index);
/// The split a users seed belongs to (seeds from 3 * 2^62 up belong to none: InputError).
LayoutSplit layout_split(std::uint64_t users_seed);
/// The seed of a training run's environments (VecEnv) under env.resample_users.
std::uint64_t training_envs_seed(std::uint64_t run_seed);
/// Training layout of environment `env` in its `episode`-th episode of a run seeded `seed`.
std::uint64_t training_layout_seed(std::uint64_t seed, std::uint64_t env, std::uint64_t episode);

/// K of the layout: scenario.users, or uniform in [env.users_min, env.users_max] (0 = scenario.users)
/// drawn from the layout's seed.
int layout_user_count(const Config& cfg, std::uint64_t users_seed);
/// Largest K a layout can have under cfg.
int max_layout_users(const Config& cfg);
/// The layout's users: K = layout_user_count, positions as make_users (scenario.user_layout).
Positions layout_users(const Config& cfg, std::uint64_t users_seed);

}  // namespace skyloop
