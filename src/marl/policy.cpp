#include <algorithm>
#include <filesystem>

#include "common.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/marl/learners.hpp"

namespace skyloop {

namespace marl {
MarlTrainResult train_ppo(const Config& cfg, const MarlTrainOptions& opt);
MarlTrainResult train_value_decomposition(const Config& cfg, const MarlTrainOptions& opt);
}  // namespace marl

MarlTrainResult train_marl(const Config& cfg, const MarlTrainOptions& opt) {
  if (opt.out_dir.empty()) throw InputError("--out is empty: allowed a directory for the run");
  if (!opt.registry) throw std::invalid_argument("train_marl: MarlTrainOptions::registry is required");
  // The cross-field rules, whoever built cfg (a task's recipe with another learner, Python, a
  // test): a combination the learners cannot run is one line here, never a run.
  validate(cfg);
  switch (find_learner(cfg.marl.algo).core) {
    case LearnerInfo::Core::Ppo: return marl::train_ppo(cfg, opt);
    case LearnerInfo::Core::ValueDecomposition: break;
  }
  return marl::train_value_decomposition(cfg, opt);
}

struct MarlPolicy::Impl {
  std::string algo, config;
  marl::Nets nets;
  bool q_based = false;
  marl::Encoder enc;
  SafetyOptions safety;
  ActionSpec actions;    // the action space it was trained on
  std::string mobility;  // trajectory.mobility it was trained with
  std::string command;   // trajectory.command it was trained with (continuous)
  int input = 0;         // its network's input width (observation, and the Q-networks' agent context)
  WaysMemory ways;       // the ways home reserved, slot to slot (marl.reserve_slack)
};

MarlPolicy::MarlPolicy(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MarlPolicy::~MarlPolicy() = default;
std::string MarlPolicy::name() const { return impl_->algo; }
const std::string& MarlPolicy::config_toml() const { return impl_->config; }
bool MarlPolicy::action_mask() const { return impl_->safety.mask; }
bool MarlPolicy::shield() const { return impl_->safety.shield; }
void MarlPolicy::set_safety(bool action_mask, bool shield) {
  impl_->safety.mask = action_mask;
  impl_->safety.shield = shield;
}
int MarlPolicy::reserve_slack() const { return impl_->safety.reserve; }
void MarlPolicy::set_reserve_slack(int slack) {
  if (slack < -1) throw InputError("marl.reserve_slack = " + std::to_string(slack) + ": allowed -1 (none) or a slack >= 0");
  if (slack >= 0 && impl_->actions.continuous())
    throw InputError("marl.reserve_slack = " + std::to_string(slack) + " for a policy trained on continuous mobility: allowed -1 "
                     "(ways home are reserved on the lattice models)");
  impl_->safety.reserve = slack;
}

std::unique_ptr<MarlPolicy> MarlPolicy::load(const std::string& where) {
  std::string path = where;
  if (std::filesystem::is_directory(path)) path = (std::filesystem::path(path) / "policy.pt").string();
  const auto meta = marl::read_meta(path);
  auto impl = std::make_unique<Impl>();
  impl->algo = meta.value("algo", "");
  impl->config = meta.value("config", "");
  // Safety as trained (marl.action_mask, marl.shield; both on unless the run turned them off).
  Config trained;
  // All of it or nothing: a configuration this version cannot read (a field it lacks, a value it
  // no longer allows) would leave the policy half as trained and half as defaults.
  try {
    apply_toml(trained, impl->config, path + " (training config)");
  } catch (const InputError& e) {
    throw InputError("policy '" + path + "' holds a training configuration this version cannot read (" + e.what() +
                     "): allowed a policy trained by this version of skyloop");
  }
  impl->safety = safety_options(trained);
  impl->enc.sequential = trained.marl.sequential;  // the UAVs choose one after another, as trained
  impl->enc.passes = trained.marl.sequential ? trained.marl.sequential_passes : 1;
  impl->command = name_of(trained.trajectory.command);
  const int hidden = meta.value("hidden", 0), obs = meta.value("obs_dim", 0), uavs = meta.value("uavs", 0);
  const std::string encoder = meta.value("encoder", "mlp");
  impl->enc.set = parse_choice<ObservationKind>("policy '" + path + "''s encoder", encoder) == ObservationKind::Set;
  const auto* row = learners().find(impl->algo);
  const LearnerInfo* learner = row ? &row->entry : nullptr;
  if (!learner) throw InputError("policy '" + path + "' names algo '" + impl->algo + "': allowed " + learner_names_text());
  const bool q_based = learner->acts_by_q();
  if (q_based && trained.marl.sequential)
    throw InputError("policy '" + path + "' is a " + impl->algo + " policy with marl.sequential = true: allowed sequential turns "
                     "for the PPO learners only (a Q-network has no turns to sample)");
  impl->q_based = q_based;
  impl->enc.context = q_based;
  // The Q-networks' agent context: a one-hot id (uavs reals; policies written before env.state),
  // nearest UAVs, or none (set observation).
  // The action space it was trained on (policies written before mobility models: the grid's).
  impl->actions = grid_actions();
  impl->mobility = meta.value("mobility", std::string("grid"));
  if (meta.contains("actions")) {
    impl->actions.names = meta.at("actions").get<std::vector<std::string>>();
    const auto& n = impl->actions.names;
    const auto named = std::find_if(n.begin(), n.end(), [](const std::string& a) { return a == "STAY" || a == "HOVER"; });
    impl->actions.hover = meta.value("hover", named == n.end() ? kStay : static_cast<int>(named - n.begin()));
  }
  impl->actions.dims = meta.value("dims", 0);
  if (impl->actions.dims < 0 || impl->actions.dims > 2 || (impl->actions.dims > 0 && q_based))
    throw InputError("policy '" + path + "' names dims " + std::to_string(impl->actions.dims) + " for " + impl->algo +
                     ": allowed 0 (discrete) or 2 (continuous, mappo and ippo)");
  // The actor's outputs: one logit per action, or the squashed Gaussian's mean and log std per dimension.
  const int width = impl->actions.continuous() ? 2 * impl->actions.dims : impl->actions.count();
  impl->input = q_based ? obs + meta.value("context_dim", uavs) : obs;
  auto net = marl::MlpNet(impl->input, hidden, width);
  (q_based ? impl->nets.q : impl->nets.actor) = net;
  marl::load(path, impl->nets, nullptr);
  return std::unique_ptr<MarlPolicy>(new MarlPolicy(std::move(impl)));
}

namespace {
std::string joined(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& x : v) out += (out.empty() ? "" : ",") + x;
  return out;
}

/// The width of the policy's input on this environment, once the environment's action space and
/// observation are the ones it was trained on (refused in one line otherwise).
int checked_input(const MarlPolicy::Impl& impl, const UavEnv& env) {
  // The actions it chooses among: the mobility model's (the Q-learners, and any discrete chooser
  // under continuous mobility, choose among its primitives; a continuous policy commands its dims).
  const ActionSpec& mine = impl.actions;
  const ActionSpec& theirs = env.dynamics().actions();
  const bool same_dims = mine.dims == theirs.dims || (mine.dims == 0 && impl.q_based);
  if (mine.names != theirs.names || mine.hover != theirs.hover || !same_dims) {
    std::string what;
    if (impl.mobility != env.dynamics().name()) what = "trajectory.mobility = \"" + impl.mobility + "\" but the environment has \"" +
                                                       env.dynamics().name() + "\"";
    else if (mine.names != theirs.names)
      what = "the actions " + joined(mine.names) + " but the environment's are " + joined(theirs.names) +
             " (trajectory.speeds_mps, trajectory.v_max_mps)";
    else if (!same_dims)
      what = std::to_string(mine.dims) + "-dimensional commands but the environment takes " + std::to_string(theirs.dims);
    else
      what = "hover action " + std::to_string(mine.hover) + " but the environment's is " + std::to_string(theirs.hover);
    throw InputError("policy " + impl.algo + " was trained with " + what + ": allowed the mobility settings it was trained with");
  }
  const int D = impl.enc.width(env);
  if (D != impl.input)
    throw InputError("policy " + impl.algo + " reads " + std::to_string(impl.input) + " reals per agent but the environment writes " +
                     std::to_string(D) + " (marl.encoder, marl.lookahead, env.state): allowed the observation settings it was trained with");
  return D;
}

/// The policy network's outputs [N x width] on the environment's observations (checked_input).
torch::Tensor network_outputs(MarlPolicy::Impl& impl, UavEnv& env) {
  torch::NoGradGuard ng;
  auto& net = impl.q_based ? impl.nets.q : impl.nets.actor;
  const auto& enc = impl.enc;
  const int N = env.uavs(), D = checked_input(impl, env);
  std::vector<float> in(static_cast<std::size_t>(N * D));
  for (int n = 0; n < N; ++n) enc.write(env, n, in.data() + static_cast<std::size_t>(n * D));
  return net(torch::from_blob(in.data(), {N, D})).contiguous();
}

/// marl.sequential: the UAVs choose one after another in shield order, each its best allowed move
/// on its observation written just before, with the landings chosen before it shown
/// (UavEnv::show_decided), and with marl.sequential_passes the turns taken that many times, every
/// UAV also seeing the others' moves of the pass before (take_turns); each UAV's scores are those
/// of its last turn. The joint action is then
/// shielded_argmax's on those scores, which is the sequential choice itself wherever that choice
/// lands no two UAVs within D_min (the first UAV's best, the next one's best clear of it, ...), and
/// the shield's depth-first search over the joint moves where it would.
std::vector<int> act_sequentially(MarlPolicy::Impl& impl, UavEnv& env) {
  const int D = checked_input(impl, env), A = env.actions();
  std::vector<float> in(static_cast<std::size_t>(D));
  std::vector<std::vector<float>> scores(static_cast<std::size_t>(env.uavs()), std::vector<float>(static_cast<std::size_t>(A), 0.0f));
  WaysMemory ways = impl.ways;  // the turns' passes leave the memory to the joint choice below
  take_turns(
      env, impl.safety, impl.enc.passes,
      [&](int n, ActionSet allowed, bool) {
        impl.enc.write(env, n, in.data());
        const auto out = impl.nets.actor(torch::from_blob(in.data(), {1, D})).contiguous();
        const float* z = out.data_ptr<float>();
        auto& mine = scores[static_cast<std::size_t>(n)];
        std::copy_n(z, A, mine.begin());
        int best = -1;
        for (int a = 0; a < A; ++a)
          if ((allowed >> a & 1u) && (best < 0 || z[a] > z[best])) best = a;
        return best;
      },
      &ways);
  env.clear_decided();
  return shielded_argmax(env, impl.safety, scores, &impl.ways);
}
}  // namespace

bool MarlPolicy::commands_velocities() const { return impl_->actions.continuous(); }

Positions MarlPolicy::act_velocities(UavEnv& env) {
  if (!impl_->actions.continuous()) return Planner::act_velocities(env);
  if (env.dynamics().command_mode() != impl_->command)
    throw InputError("policy " + impl_->algo + " was trained with trajectory.command = \"" + impl_->command +
                     "\" but the environment has trajectory.command = \"" + env.dynamics().command_mode() +
                     "\": allowed the command it was trained with");
  const auto out = network_outputs(*impl_, env);
  const auto o = out.accessor<float, 2>();
  const int C = impl_->actions.dims;
  // Deployed: the mean command u = tanh(mu) of each UAV, through the safety layer.
  Positions wanted = Positions::Zero(env.uavs(), 2);
  for (int n = 0; n < env.uavs(); ++n)
    env.command_velocity(n, std::tanh(o[n][0]), C > 1 ? std::tanh(o[n][1]) : 0.0, wanted(n, 0), wanted(n, 1));
  return safe_velocities(env, impl_->safety, wanted);
}

std::vector<int> MarlPolicy::act(UavEnv& env) {
  if (impl_->actions.continuous())
    throw std::logic_error("MarlPolicy::act: a continuous policy commands velocities (act_velocities)");
  torch::NoGradGuard ng;
  if (impl_->enc.sequential) return act_sequentially(*impl_, env);
  const auto out = network_outputs(*impl_, env);
  const int N = env.uavs(), A = env.actions();
  const auto oa = out.accessor<float, 2>();
  std::vector<std::vector<float>> scores(static_cast<std::size_t>(N), std::vector<float>(static_cast<std::size_t>(A)));
  for (int n = 0; n < N; ++n)
    for (int a = 0; a < A; ++a) scores[static_cast<std::size_t>(n)][static_cast<std::size_t>(a)] = oa[n][a];
  return shielded_argmax(env, impl_->safety, scores, &impl_->ways);
}

bool MarlPolicy::sequential() const { return impl_->enc.sequential; }
void MarlPolicy::set_sequential(bool sequential) {
  if (sequential && (impl_->q_based || !impl_->enc.set || impl_->actions.continuous()))
    throw InputError("marl.sequential = true for a " + impl_->algo + " policy" + (impl_->enc.set ? "" : " on the paper's observation") +
                     (impl_->actions.continuous() ? " of continuous commands" : "") +
                     ": allowed for mappo and ippo policies on the set observation with discrete moves (" + lattice_dynamics_names() + ")");
  impl_->enc.sequential = sequential;
  if (!sequential) impl_->enc.passes = 1;
}

int MarlPolicy::sequential_passes() const { return impl_->enc.passes; }
void MarlPolicy::set_sequential_passes(int passes) {
  if (passes < 1 || passes > kMaxSequentialPasses)
    throw InputError("marl.sequential_passes = " + std::to_string(passes) + ": allowed 1 .. " + std::to_string(kMaxSequentialPasses));
  if (passes > 1 && !impl_->enc.sequential)
    throw InputError("marl.sequential_passes = " + std::to_string(passes) + " for a policy that does not choose sequentially: allowed "
                     "1, or more passes with marl.sequential = true");
  impl_->enc.passes = passes;
}

void MarlPolicy::reset(UavEnv&) { impl_->ways = WaysMemory{}; }

Config policy_config(const std::string& path) {
  const auto policy = MarlPolicy::load(path);
  Config cfg;
  apply_toml(cfg, policy->config_toml(), path + " (training config)");
  finalise(cfg);
  return cfg;
}

}  // namespace skyloop
