#include "skyloop/env/layouts.hpp"

#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"

namespace skyloop {

const char* to_string(LayoutSplit s) {
  switch (s) {
    case LayoutSplit::Train: return "train";
    case LayoutSplit::Validation: return "validation";
    case LayoutSplit::Test: return "test";
  }
  return "?";
}

LayoutSplit parse_layout_split(const std::string& s, const std::string& field) {
  for (auto v : {LayoutSplit::Train, LayoutSplit::Validation, LayoutSplit::Test})
    if (s == to_string(v)) return v;
  throw InputError(field + " = '" + s + "' is not a layout split: allowed train, validation, test");
}

std::uint64_t layout_seed(LayoutSplit split, std::uint64_t index) {
  constexpr std::uint64_t span = std::uint64_t{1} << kLayoutSplitBits;
  if (index >= span) throw InputError("layout index " + std::to_string(index) + " is out of range: allowed below 2^62");
  return static_cast<std::uint64_t>(split) * span + index;
}

LayoutSplit layout_split(std::uint64_t users_seed) {
  const std::uint64_t s = users_seed >> kLayoutSplitBits;
  if (s > 2) throw InputError("users seed " + std::to_string(users_seed) + " belongs to no layout split: allowed below 3 * 2^62");
  return static_cast<LayoutSplit>(s);
}

std::uint64_t training_envs_seed(std::uint64_t run_seed) { return derive_seed(run_seed, 0x4c41594fULL); }

std::uint64_t training_layout_seed(std::uint64_t seed, std::uint64_t env, std::uint64_t episode) {
  return derive_seed(seed, env, episode) >> (64 - kLayoutSplitBits);  // into [0, 2^62): the training range
}

int layout_user_count(const Config& cfg, std::uint64_t users_seed) {
  const int lo = cfg.env.users_min ? cfg.env.users_min : cfg.scenario.users;
  const int hi = cfg.env.users_max ? cfg.env.users_max : cfg.scenario.users;
  if (lo >= hi) return hi;
  Rng rng(derive_seed(users_seed, 0x4b4b4bULL));  // a stream of its own: positions stay make_users(seed)'s
  return lo + static_cast<int>(rng.below(static_cast<std::uint64_t>(hi - lo + 1)));
}

int max_layout_users(const Config& cfg) {
  return cfg.env.users_max ? cfg.env.users_max : cfg.scenario.users;
}

Positions layout_users(const Config& cfg, std::uint64_t users_seed) {
  return make_users(cfg, layout_user_count(cfg, users_seed), users_seed);
}

}  // namespace skyloop
