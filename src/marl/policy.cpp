#include <filesystem>

#include "common.hpp"
#include "skyloop/core/error.hpp"

namespace skyloop {

namespace marl {
MarlTrainResult train_ppo(const Config& cfg, const MarlTrainOptions& opt);
MarlTrainResult train_value_decomposition(const Config& cfg, const MarlTrainOptions& opt);
}  // namespace marl

MarlTrainResult train_marl(const Config& cfg, const MarlTrainOptions& opt) {
  if (opt.out_dir.empty()) throw InputError("--out is empty: allowed a directory for the run");
  if (!opt.registry) throw std::invalid_argument("train_marl: MarlTrainOptions::registry is required");
  if (cfg.marl.algo == "mappo" || cfg.marl.algo == "ippo") return marl::train_ppo(cfg, opt);
  return marl::train_value_decomposition(cfg, opt);
}

struct MarlPolicy::Impl {
  std::string algo, config;
  marl::Nets nets;
  bool q_based = false;
};

MarlPolicy::MarlPolicy(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MarlPolicy::~MarlPolicy() = default;
std::string MarlPolicy::name() const { return impl_->algo; }
const std::string& MarlPolicy::config_toml() const { return impl_->config; }

std::unique_ptr<MarlPolicy> MarlPolicy::load(const std::string& where) {
  std::string path = where;
  if (std::filesystem::is_directory(path)) path = (std::filesystem::path(path) / "policy.pt").string();
  const auto meta = marl::read_meta(path);
  auto impl = std::make_unique<Impl>();
  impl->algo = meta.value("algo", "");
  impl->config = meta.value("config", "");
  const int hidden = meta.value("hidden", 0), obs = meta.value("obs_dim", 0), uavs = meta.value("uavs", 0);
  if (impl->algo == "mappo" || impl->algo == "ippo") {
    impl->nets.actor = marl::MlpNet(obs, hidden, kActions);
  } else if (impl->algo == "vdn" || impl->algo == "qmix") {
    // The agent context: a one-hot id (uavs reals; policies written before env.state) or nearest UAVs.
    impl->nets.q = marl::MlpNet(obs + meta.value("context_dim", uavs), hidden, kActions);
    impl->q_based = true;
  } else {
    throw InputError("policy '" + path + "' names algo '" + impl->algo + "': allowed mappo, ippo, vdn, qmix");
  }
  marl::load(path, impl->nets, nullptr);
  return std::unique_ptr<MarlPolicy>(new MarlPolicy(std::move(impl)));
}

std::vector<int> MarlPolicy::act(UavEnv& env) {
  torch::NoGradGuard ng;
  std::vector<int> a(static_cast<std::size_t>(env.uavs()), kStay);
  for (int n = 0; n < env.uavs(); ++n) {
    if (!env.mask(n)) continue;
    auto o = impl_->q_based ? marl::obs_with_id(env, n) : env.observation(n);
    const auto x = torch::from_blob(o.data(), {1, static_cast<int64_t>(o.size())});
    const auto out = impl_->q_based ? impl_->nets.q(x) : impl_->nets.actor(x);
    a[static_cast<std::size_t>(n)] = static_cast<int>(out.argmax(1).item<int64_t>());
  }
  return a;
}

}  // namespace skyloop
