// The PPO core's networks behind PpoNetworks (ppo.hpp): LibTorch's autograd and Adam (the
// reference, any device) and the fused float32 CPU path (fast_mlp.hpp), chosen by marl.backend.
#include "ppo_loss.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <fmt/format.h>

#include "fast_mlp.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/memory.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop {
namespace marl {

// ---- backends ------------------------------------------------------------------------------------

namespace {

/// The actor and critic as LibTorch modules, in MlpNet's default initialisation under `seed`.
Nets initial_nets(int obs_width, int critic_width, int hidden, int actions, std::uint64_t seed) {
  torch::manual_seed(seed);
  Nets nets;
  nets.actor = MlpNet(obs_width, hidden, actions);
  nets.critic = MlpNet(critic_width, hidden, 1);
  return nets;
}

/// The archive entry of the actor's Polyak average in last.pt (PpoNetworks::set_average_decay).
constexpr const char* kActorAverage = "actor_average";

bool read_module(torch::serialize::InputArchive& archive, const char* key, torch::nn::Module& module) {
  torch::serialize::InputArchive sub;
  if (!archive.try_read(key, sub)) return false;
  module.load(sub);
  return true;
}

/// An actor of `like`'s shape (on its device), for the average's archive form.
MlpNet actor_like(MlpNet& like) {
  MlpNet net(like->l1->options.in_features(), like->l1->options.out_features(), like->l3->options.out_features());
  net->to(like->l1->weight.device());
  return net;
}

/// The reference: LibTorch's autograd and Adam.
class TorchPpo final : public PpoNetworks {
 public:
  TorchPpo(Nets nets, double learning_rate, const torch::Device& device, int critic_observation)
      : critic_observation_(critic_observation), nets_(std::move(nets)), device_(device) {
    nets_.actor->to(device);
    nets_.critic->to(device);
    params_ = nets_.actor->parameters();
    for (auto& p : nets_.critic->parameters()) params_.push_back(p);
    adam_ = std::make_unique<torch::optim::Adam>(params_, torch::optim::AdamOptions(learning_rate));
  }

  void set_learning_rate(double learning_rate) override {
    for (auto& group : adam_->param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(learning_rate);
  }
  void set_average_decay(double decay) override { average_decay_ = decay; }

  void logits(const float* obs, int rows, float* out, int) override { forward(nets_.actor, obs, rows, actions(), out); }
  void values(const float* observations, const float* in, int rows, float* out, int) override {
    torch::NoGradGuard ng;
    copy_rows(nets_.critic(critic_input(observations, in, rows)), rows, 1, out);
  }

  UpdateStats step(Minibatch& b, const PpoSettings& s) override {
    b.ready(0, b.rows);
    if (b.critic_observation != critic_observation_) throw std::logic_error("TorchPpo: the batch's critic input is not the network's");
    const int64_t R = b.rows;
    auto blob = [&](const std::vector<float>& v, std::vector<int64_t> shape) {
      return torch::from_blob(const_cast<float*>(v.data()), shape).to(device_);
    };
    const auto active = blob(b.active, {R});
    const auto logp_old = blob(b.logprobs, {R});
    const auto out = nets_.actor(blob(b.observations, {R, b.obs_width}));
    torch::Tensor logp, entropy;
    if (b.dims > 0) {  // the squashed Gaussian (ppo.hpp)
      const int64_t C = b.dims;
      const auto mu = out.narrow(1, 0, C), log_std = out.narrow(1, C, C).clamp(kLogStdMin, kLogStdMax);
      const auto z = blob(b.raw_actions, {R, C});
      const auto jacobian = 2 * (std::log(2.0) - z - torch::nn::functional::softplus(-2 * z));
      const auto sigma = log_std.exp();
      logp = (-0.5 * ((z - mu) / sigma).pow(2) - log_std - kHalfLog2Pi - jacobian).sum(1);
      // The squashed distribution's entropy at the sample, reparameterised (ppo.hpp).
      const auto zr = mu + sigma * ((z - mu) / sigma).detach();
      const auto at = 2 * (std::log(2.0) - zr - torch::nn::functional::softplus(-2 * zr));
      entropy = masked_mean((log_std + 0.5 + kHalfLog2Pi + at).sum(1), active);
    } else {
      const auto logp_all = torch::log_softmax(masked_logits(out, blob(b.allowed, {R, b.action_count})), 1);
      const auto actions = torch::from_blob(const_cast<std::int64_t*>(b.actions.data()), {R}, torch::kInt64).to(device_);
      logp = logp_all.gather(1, actions.unsqueeze(1)).squeeze(1);
      entropy = masked_mean(-(logp_all.exp() * logp_all).sum(1), active);
    }
    const auto policy_loss = -masked_mean(clipped_surrogate(logp, logp_old, blob(b.advantages, {R}), s.clip), active);
    const auto v = nets_.critic(critic_input(b.observations.data(), b.critic_inputs.data(), static_cast<int>(R))).view({R});
    const auto value_loss = clipped_value_loss(v, blob(b.values, {R}), blob(b.returns, {R}), s.clip);
    const auto loss = policy_loss + s.value_coef * value_loss - s.entropy_coef * entropy;  // eq:total_loss
    adam_->zero_grad();
    loss.backward();
    UpdateStats u;
    {
      torch::NoGradGuard ng;
      double sq = 0;
      for (const auto& p : params_)
        if (p.grad().defined()) sq += p.grad().pow(2).sum().item<double>();
      u.grad_norm = std::sqrt(sq);
    }
    if (s.grad_clip > 0) torch::nn::utils::clip_grad_norm_(params_, s.grad_clip);
    adam_->step();
    torch::NoGradGuard ng;
    if (average_decay_ > 0) {
      const bool first = !average_;
      if (first) average_ = actor_like(nets_.actor);
      const auto w = nets_.actor->parameters(), a = average_->parameters();
      const float d = static_cast<float>(average_decay_);
      for (std::size_t i = 0; i < w.size(); ++i)
        if (first) a[i].copy_(w[i]);
        else a[i].mul_(d).add_(w[i], 1.0f - d);
    }
    const auto log_ratio = logp - logp_old;
    const auto ratio = log_ratio.exp();
    u.policy_loss = policy_loss.item<double>();
    u.value_loss = value_loss.item<double>();
    u.entropy = entropy.item<double>();
    u.old_approx_kl = masked_mean(-log_ratio, active).item<double>();
    u.approx_kl = masked_mean((ratio - 1) - log_ratio, active).item<double>();
    u.clipfrac = masked_mean(((ratio - 1).abs() > s.clip).to(torch::kFloat), active).item<double>();
    return u;
  }

  void save(const std::string& path, const nlohmann::json& meta, bool optimiser) override {
    if (optimiser) {
      std::function<void(torch::serialize::OutputArchive&)> extra;
      if (average_) extra = [this](torch::serialize::OutputArchive& a) { write_module(a, kActorAverage, *average_); };
      marl::save(path, meta, nets_, adam_.get(), extra);
      return;
    }
    Nets published = nets_;  // the same modules; the average as the actor
    if (average_) published.actor = average_;
    marl::save(path, meta, published, nullptr);
  }
  void load(const std::string& path, bool optimiser) override {
    if (!optimiser) {  // a published policy: its actor is the weights, no average
      marl::load(path, nets_, nullptr);
      average_ = MlpNet{nullptr};
      return;
    }
    MlpNet average = actor_like(nets_.actor);
    bool found = false;
    marl::load(path, nets_, adam_.get(), [&](torch::serialize::InputArchive& a) { found = read_module(a, kActorAverage, *average); });
    average_ = found ? average : MlpNet{nullptr};
  }

 private:
  int actions() const { return static_cast<int>(nets_.actor->l3->options.out_features()); }
  void forward(MlpNet& net, const float* in, int rows, int width, float* out) {
    torch::NoGradGuard ng;
    copy_rows(net(torch::from_blob(const_cast<float*>(in), {rows, net->l1->options.in_features()}).to(device_)), rows, width, out);
  }
  static void copy_rows(const torch::Tensor& y, int rows, int width, float* out) {
    const auto cpu = y.to(torch::kCPU).contiguous();
    std::copy(cpu.data_ptr<float>(), cpu.data_ptr<float>() + static_cast<std::size_t>(rows) * width, out);
  }
  /// The critic's whole input rows: the observation's columns (when it reads them), then its own.
  torch::Tensor critic_input(const float* observations, const float* own, int rows) const {
    const int64_t width = nets_.critic->l1->options.in_features(), own_width = width - critic_observation_;
    auto rest = torch::from_blob(const_cast<float*>(own), {rows, own_width}).to(device_);
    if (critic_observation_ == 0) return rest;
    const int64_t obs_width = nets_.actor->l1->options.in_features();
    auto head = torch::from_blob(const_cast<float*>(observations), {rows, obs_width}).to(device_);
    return torch::cat({head, rest}, 1);
  }

  int critic_observation_;  // the critic's leading input columns that are the observation (0 or its width)
  Nets nets_;
  torch::Device device_;
  std::vector<torch::Tensor> params_;
  std::unique_ptr<torch::optim::Adam> adam_;
  double average_decay_ = 0;
  MlpNet average_{nullptr};  // the actor's Polyak average, after the first step with average_decay_ > 0
};

/// The default: fused float32 passes (fast_mlp.hpp), the loss's gradient written out.
class FastPpo final : public PpoNetworks {
 public:
  FastPpo(Nets nets, double learning_rate, int threads, int critic_observation)
      : critic_observation_(critic_observation),
        torch_(std::move(nets)),
        actor_(static_cast<int>(torch_.actor->l1->options.in_features()), static_cast<int>(torch_.actor->l1->options.out_features()),
               static_cast<int>(torch_.actor->l3->options.out_features())),
        critic_(static_cast<int>(torch_.critic->l1->options.in_features()), static_cast<int>(torch_.critic->l1->options.out_features()), 1) {
    from_torch();
    actor_adam_.learning_rate = critic_adam_.learning_rate = learning_rate;
    threads_ = std::max(1, std::min<int>(static_cast<int>(kChunks), resolve_threads(threads)));
  }

  void set_learning_rate(double learning_rate) override { actor_adam_.learning_rate = critic_adam_.learning_rate = learning_rate; }
  void set_average_decay(double decay) override { average_decay_ = decay; }

  void logits(const float* obs, int rows, float* out, int lane) override {
    forward(actor_, obs, rows, static_cast<int>(torch_.actor->l3->options.out_features()), out, lane);
  }
  void values(const float* observations, const float* in, int rows, float* out, int lane) override {
    forward(critic_, critic_rows(observations, in), rows, 1, out, lane);
  }
  int lanes() const override { return kLanes; }

  UpdateStats step(Minibatch& b, const PpoSettings& s) override {
    if (b.critic_observation != critic_observation_) throw std::logic_error("FastPpo: the batch's critic input is not the network's");
    const int R = b.rows, as = actor_.out_stride(), vs = critic_.out_stride();
    const std::size_t na = actor_.size(), np = na + critic_.size();
    logits_.resize(static_cast<std::size_t>(R) * as);
    values_.resize(static_cast<std::size_t>(R) * vs);
    dlogits_.assign(logits_.size(), 0.0f);
    dvalues_.assign(values_.size(), 0.0f);
    const double per_active = inverse_active(b);
    // Runs of rows sharing their critic columns (Minibatch::share): the critic's first layer takes
    // them once per run (fast::Mlp::Rows::tail_share), so chunks and pieces hold whole runs.
    const int share = b.share > 1 && critic_observation_ > 0 ? b.share : 1;
    if (R % share != 0) throw std::logic_error("FastPpo: a minibatch of shared rows holds a part of a run");
    const int piece_rows = std::max(share, kPieceRows / share * share);
    // The minibatch in kChunks fixed halves, each forward, loss and backward into its own gradient
    // (on its own thread when run.threads allows), summed in chunk order: the same numbers for
    // any thread count.
    UpdateStats parts[kChunks];
    parallel_for(kChunks, threads_, [&](std::size_t c) {
      const long runs = R / share;
      const int first = static_cast<int>(runs * static_cast<long>(c) / kChunks) * share;
      const int last = static_cast<int>(runs * static_cast<long>(c + 1) / kChunks) * share;
      auto& g = chunk_grad_[c];
      g.assign(np, 0.0f);
      // In pieces of kPieceRows rows, whose activations stay in the core's L2 cache from the
      // forward pass to the backward; each weight's gradient still sums its rows in order, so the
      // pieces change no bit of it.
      for (int lo = first; lo < last; lo += piece_rows) {
        const int hi = std::min(last, lo + piece_rows);
        float* lg = logits_.data() + static_cast<std::size_t>(lo) * as;
        float* vl = values_.data() + static_cast<std::size_t>(lo) * vs;
        float* dl = dlogits_.data() + static_cast<std::size_t>(lo) * as;
        float* dv = dvalues_.data() + static_cast<std::size_t>(lo) * vs;
        b.ready(lo, hi);
        actor_.forward(b.observations.data() + static_cast<std::size_t>(lo) * b.obs_width, hi - lo, lg, &actor_cache_[c]);
        fast::Mlp::Rows critic_in = critic_rows(b.observations.data() + static_cast<std::size_t>(lo) * b.obs_width,
                                                b.critic_inputs.data() + static_cast<std::size_t>(lo) * b.critic_own());
        critic_in.tail_share = share;
        critic_.forward(critic_in, hi - lo, vl, &critic_cache_[c]);
        parts[c].add(ppo_loss_rows(b, s, lo, hi, per_active, lg, as, vl, vs, dl, dv), 1.0);
        actor_.backward(actor_cache_[c], dl, g.data());
        critic_.backward(critic_cache_[c], dv, g.data() + na);
      }
    });
    UpdateStats u;
    for (std::size_t c = 0; c < kChunks; ++c) u.add(parts[c], 1.0);
    // The chunks' gradients summed, each parameter's in chunk order (the parameters in halves, on
    // the threads); then the global norm, clipping (LibTorch's clip_grad_norm_ rule), and Adam
    // and the packed copies for each network on a thread of its own.
    grad_.resize(np);
    parallel_for(2, threads_, [&](std::size_t half) {
      for (std::size_t i = np * half / 2, end = np * (half + 1) / 2; i < end; ++i) {
        float g = 0.0f;
        for (std::size_t c = 0; c < kChunks; ++c) g += chunk_grad_[c][i];
        grad_[i] = g;
      }
    });
    u.grad_norm = fast::norm(grad_);
    const double coef = s.grad_clip > 0 ? s.grad_clip / (u.grad_norm + 1e-6) : 1.0;
    parallel_for(2, threads_, [&](std::size_t net) {
      fast::Mlp& mlp = net == 0 ? actor_ : critic_;
      float* g = grad_.data() + (net == 0 ? 0 : na);
      if (coef < 1)
        for (std::size_t i = 0; i < mlp.size(); ++i) g[i] = static_cast<float>(g[i] * coef);
      (net == 0 ? actor_adam_ : critic_adam_).step(mlp.params().data(), g, mlp.size());
      mlp.refresh();
    });
    if (average_decay_ > 0) {
      const auto& w = actor_.params();
      if (average_.empty()) average_ = w;
      else fast::polyak(average_.data(), w.data(), w.size(), static_cast<float>(average_decay_));
    }
    return u;
  }

  void save(const std::string& path, const nlohmann::json& meta, bool optimiser) override {
    to_torch();
    if (!optimiser && !average_.empty()) write_average(torch_.actor);  // the published actor: the average
    std::function<void(torch::serialize::OutputArchive&)> extra;
    if (optimiser)
      extra = [this](torch::serialize::OutputArchive& a) {
        if (!average_.empty()) {
          MlpNet average = actor_like(torch_.actor);
          write_average(average);
          write_module(a, kActorAverage, *average);
        }
        torch::serialize::OutputArchive sub;
        auto put = [&](const char* key, const std::vector<float>& v) {
          sub.write(key, torch::from_blob(const_cast<float*>(v.data()), {static_cast<int64_t>(v.size())}).clone());
        };
        put("actor_m", actor_adam_.m);
        put("actor_v", actor_adam_.v);
        put("critic_m", critic_adam_.m);
        put("critic_v", critic_adam_.v);
        sub.write("steps", torch::tensor(actor_adam_.steps, torch::kInt64));
        a.write("fast_adam", sub);
      };
    marl::save(path, meta, torch_, nullptr, extra);
  }

  void load(const std::string& path, bool optimiser) override {
    if (!optimiser) average_.clear();  // a published policy: its actor is the weights, no average
    std::function<void(torch::serialize::InputArchive&)> extra;
    if (optimiser)
      extra = [&](torch::serialize::InputArchive& a) {
        torch::serialize::InputArchive sub;
        if (!a.try_read("fast_adam", sub)) throw InputError("policy '" + path + "' holds no optimiser state: cannot resume from it");
        auto get = [&](const char* key, std::vector<float>& v) {
          torch::Tensor t;
          sub.read(key, t);
          t = t.to(torch::kFloat).contiguous();
          v.assign(t.data_ptr<float>(), t.data_ptr<float>() + t.numel());
        };
        get("actor_m", actor_adam_.m);
        get("actor_v", actor_adam_.v);
        get("critic_m", critic_adam_.m);
        get("critic_v", critic_adam_.v);
        average_.clear();
        MlpNet average = actor_like(torch_.actor);
        if (read_module(a, kActorAverage, *average)) {
          fast::Mlp packed(actor_.in(), actor_.hidden(), actor_.out());
          packed.set_torch_layout(layout(average));
          average_ = packed.params();
        }
        torch::Tensor steps;
        sub.read("steps", steps);
        actor_adam_.steps = critic_adam_.steps = steps.item<std::int64_t>();
        if (actor_adam_.m.size() != actor_.size() || critic_adam_.m.size() != critic_.size())
          throw InputError("policy '" + path + "': its optimiser state does not match its networks");
      };
    marl::load(path, torch_, nullptr, extra);
    from_torch();
  }

 private:
  static std::array<torch::Tensor, 6> tensors(MlpNet& net) {
    return {net->l1->weight, net->l1->bias, net->l2->weight, net->l2->bias, net->l3->weight, net->l3->bias};
  }
  /// A CPU network's weights in Mlp::set_torch_layout's order (pointers into the tensors).
  static std::array<const float*, 6> layout(MlpNet& net) {
    const auto t = tensors(net);
    std::array<const float*, 6> p{};
    for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
    return p;
  }
  void from_torch() {
    for (auto [net, fast] : {std::pair<MlpNet*, fast::Mlp*>{&torch_.actor, &actor_}, {&torch_.critic, &critic_}}) fast->set_torch_layout(layout(*net));
  }
  /// The average (in the actor's packed layout) into `net`'s tensors.
  void write_average(MlpNet& net) {
    fast::Mlp packed(actor_.in(), actor_.hidden(), actor_.out());
    packed.params() = average_;
    torch::NoGradGuard ng;
    const auto t = tensors(net);
    std::array<float*, 6> p{};
    for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
    packed.get_torch_layout(p);
  }
  void to_torch() {
    torch::NoGradGuard ng;
    for (auto [net, fast] : {std::pair<MlpNet*, fast::Mlp*>{&torch_.actor, &actor_}, {&torch_.critic, &critic_}}) {
      const auto t = tensors(*net);
      std::array<float*, 6> p{};
      for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
      fast->get_torch_layout(p);
    }
  }
  /// Each row's outputs are the same bits whatever the other rows (the kernels sum every element
  /// over its inputs in order), so lanes split a batch without changing a number.
  /// The critic's input rows: the observation's rows (when it reads them), then its own.
  fast::Mlp::Rows critic_rows(const float* observations, const float* own) const {
    const int own_width = critic_.in() - critic_observation_;
    if (critic_observation_ == 0) return critic_.rows_of(own);
    return fast::Mlp::Rows{observations, critic_observation_, actor_.in(), own, own_width};
  }
  void forward(const fast::Mlp& net, const float* in, int rows, int width, float* out, int lane) {
    forward(net, net.rows_of(in), rows, width, out, lane);
  }
  void forward(const fast::Mlp& net, const fast::Mlp::Rows& in, int rows, int width, float* out, int lane) {
    if (lane < 0 || lane >= kLanes) throw std::logic_error("FastPpo: lane " + std::to_string(lane) + " outside 0.." + std::to_string(kLanes - 1));
    auto& scratch = scratch_[lane];
    scratch.resize(static_cast<std::size_t>(rows) * net.out_stride());
    net.forward(in, rows, scratch.data(), &infer_cache_[lane]);
    for (int i = 0; i < rows; ++i)
      std::copy(scratch.data() + static_cast<std::size_t>(i) * net.out_stride(),
                scratch.data() + static_cast<std::size_t>(i) * net.out_stride() + width, out + static_cast<std::size_t>(i) * width);
  }

  static constexpr std::size_t kChunks = 2;
  static constexpr int kLanes = kCollectLanes;
  static constexpr int kPieceRows = 192;
  int critic_observation_;  // the critic's leading input columns that are the observation (0 or its width)
  Nets torch_;  // the archive's form of the weights (written on save, read on load)
  fast::Mlp actor_, critic_;
  fast::Adam actor_adam_, critic_adam_;
  double average_decay_ = 0;
  std::vector<float> average_;  // the actor's Polyak average in its packed layout (empty before the first step)
  int threads_ = 1;
  fast::Mlp::Cache actor_cache_[kChunks], critic_cache_[kChunks], infer_cache_[kLanes];
  std::vector<float> chunk_grad_[kChunks];
  std::vector<float> grad_, logits_, values_, dlogits_, dvalues_, scratch_[kLanes];
};

}  // namespace

std::unique_ptr<PpoNetworks> make_ppo_networks(PpoBackend backend, int obs_width, int critic_width, int hidden,
                                               double learning_rate, const torch::Device& device, std::uint64_t seed,
                                               int threads, int actions, int critic_observation) {
  if (critic_observation != 0 && (critic_observation != obs_width || critic_width < obs_width))
    throw std::logic_error("make_ppo_networks: the critic reads the whole observation or none of it");
  auto nets = initial_nets(obs_width, critic_width, hidden, actions, seed);
  if (backend == PpoBackend::Torch) return std::make_unique<TorchPpo>(std::move(nets), learning_rate, device, critic_observation);
  if (device.is_cuda())
    throw InputError("marl.backend = \"fast\" runs on the CPU: with nn.device = \"cuda\" set marl.backend = \"torch\"");
  return std::make_unique<FastPpo>(std::move(nets), learning_rate, threads, critic_observation);
}

}  // namespace marl
}  // namespace skyloop
