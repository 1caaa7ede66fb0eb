// The PPO core's phases (collect, compute_advantages, update) each on its own, and the fast
// backend's fused passes against LibTorch's autograd.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>

#include "../../src/marl/fast_mlp.hpp"
#include "../../src/marl/ppo.hpp"
#include "../scratch.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/vec_env.hpp"

using namespace skyloop;
using namespace skyloop::marl;

namespace {

torch::Tensor to_double(const torch::Tensor& t) { return t.detach().to(torch::kDouble); }

/// Max |a - b| over two tensors (any dtype).
double max_error(const torch::Tensor& a, const torch::Tensor& b) { return (to_double(a) - to_double(b)).abs().max().item<double>(); }

/// Float32's unit roundoff, 2^-24.
constexpr double kUnitRoundoff = 5.9604644775390625e-08;

/// The magnitudes a float32 evaluation's error is proportional to, entry by entry, for an MLP's
/// output and each parameter gradient: the running error analysis of Higham, "Accuracy and
/// Stability of Numerical Algorithms" (2nd ed.), sec. 3.1 and 3.5, carried through the layers in
/// float64 with every quantity replaced by its absolute value. A sum's rounding error is at most
/// gamma times the sum of its terms' magnitudes (the gradient of a bias: sum_r |dz_r|; of a weight:
/// |dz|^T |h|), and a product carries the errors of both factors. Each tanh adds one unit of its
/// own; dz = dh (1 - h^2) carries dh's error (1 - h^2 <= 1) and 2|h| <= 2 times h's, E + 1: 3 + 2 E.
struct RoundingMagnitudes {
  torch::Tensor out;
  std::array<torch::Tensor, 6> grad;
};

RoundingMagnitudes rounding_magnitudes(MlpNet& net64, const torch::Tensor& x, const torch::Tensor& dout) {
  torch::NoGradGuard ng;
  const auto W1 = net64->l1->weight.abs(), b1 = net64->l1->bias.abs(), W2 = net64->l2->weight.abs(),
             b2 = net64->l2->bias.abs(), W3 = net64->l3->weight.abs(), b3 = net64->l3->bias.abs();
  const auto xa = x.abs(), dy = dout.abs();
  const auto t1 = torch::tanh(net64->l1(x));
  const auto h1 = t1.abs(), h2 = torch::tanh(net64->l2(t1)).abs();
  // Forward: E_l bounds the error of layer l's pre-activation; a tanh adds 1 and passes E on.
  const auto e1 = xa.mm(W1.t()) + b1;
  const auto e2 = h1.mm(W2.t()) + b2 + (e1 + 1).mm(W2.t());
  const auto out = h2.mm(W3.t()) + b3 + (e2 + 1).mm(W3.t());
  // Backward: G bounds dh = dz_next W, Z bounds dz = dh (1 - h^2) with h's error through 2 h.
  const auto z2 = dy.mm(W3) * (3 + 2 * e2);
  const auto z1 = z2.mm(W2) * (3 + 2 * e1);
  return {out,
          {z1.t().mm(xa), z1.sum(0), z2.t().mm(h1 + e1 + 1), z2.sum(0), dy.t().mm(h2 + e2 + 1), dy.sum(0)}};
}

/// "Within float32 rounding", entry by entry: |computed - exact| <= lambda sqrt(n) u M, with M
/// from rounding_magnitudes and n the longest sum (the rows, the input or the hidden width). This
/// is the probabilistic bound of Higham and Mary, "A new approach to probabilistic rounding error
/// analysis" (SIAM J. Sci. Comput. 41, 2019), thm. 2.4: with independent rounding errors it fails
/// with probability at most 2 exp(-lambda^2 / 2), 7.5e-6 at lambda = 5. The worst-case bound,
/// n u M, is too loose to see a dropped row (M / n); this one sees it on every shape below. Both
/// the fast path and LibTorch's float32 must meet it: they sum the same products in other orders.
double rounding_ratio(const torch::Tensor& computed, const torch::Tensor& exact, const torch::Tensor& magnitude, int n) {
  constexpr double kLambda = 5;
  const auto bound = kLambda * std::sqrt(static_cast<double>(n)) * kUnitRoundoff * magnitude.to(torch::kDouble).reshape(exact.sizes());
  return ((to_double(computed) - to_double(exact)).abs() / bound).max().item<double>();
}

void expect_within_rounding(const torch::Tensor& fast, const torch::Tensor& torch32, const torch::Tensor& exact,
                            const torch::Tensor& magnitude, int n, const std::string& what) {
  const double f = rounding_ratio(fast, exact, magnitude, n), t = rounding_ratio(torch32, exact, magnitude, n);
  EXPECT_LE(f, 1.0) << what << ": the fast path's error is " << f << " of the bound";
  EXPECT_LE(t, 1.0) << what << ": LibTorch float32's error is " << t << " of the bound";
}

std::vector<float> as_vector(const torch::Tensor& t) {
  const auto c = t.detach().to(torch::kFloat).contiguous();
  return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
}

/// The fast twin of a LibTorch MlpNet.
fast::Mlp twin(MlpNet& net) {
  fast::Mlp m(static_cast<int>(net->l1->options.in_features()), static_cast<int>(net->l1->options.out_features()),
              static_cast<int>(net->l3->options.out_features()));
  std::array<torch::Tensor, 6> t{net->l1->weight.detach().contiguous(), net->l1->bias.detach().contiguous(),
                                 net->l2->weight.detach().contiguous(), net->l2->bias.detach().contiguous(),
                                 net->l3->weight.detach().contiguous(), net->l3->bias.detach().contiguous()};
  std::array<const float*, 6> p{};
  for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
  m.set_torch_layout(p);
  return m;
}

/// A packed parameter-sized vector (a gradient) in LibTorch's layout, as 6 tensors.
std::array<torch::Tensor, 6> unpack(const fast::Mlp& shape, const std::vector<float>& packed) {
  fast::Mlp m(shape.in(), shape.hidden(), shape.out());
  m.params() = packed;
  std::array<torch::Tensor, 6> t{torch::zeros({shape.hidden(), shape.in()}), torch::zeros({shape.hidden()}),
                                 torch::zeros({shape.hidden(), shape.hidden()}), torch::zeros({shape.hidden()}),
                                 torch::zeros({shape.out(), shape.hidden()}), torch::zeros({shape.out()})};
  std::array<float*, 6> p{};
  for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
  m.get_torch_layout(p);
  return t;
}

/// A minibatch with every case of the loss: masked moves, inactive agents, ratios inside and
/// outside the clip range on both signs of the advantage, values inside and outside the value clip.
Minibatch random_minibatch(int rows, int obs_width, int critic_width, std::uint64_t seed) {
  std::mt19937_64 g(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  Minibatch b;
  b.rows = rows, b.obs_width = obs_width, b.critic_width = critic_width;
  for (int i = 0; i < rows * obs_width; ++i) b.observations.push_back(2 * u(g));
  for (int i = 0; i < rows * critic_width; ++i) b.critic_inputs.push_back(2 * u(g));
  for (int i = 0; i < rows; ++i) {
    ActionSet allowed = action_bit(kStay);
    for (int k = 0; k < kGridActions; ++k)
      if (u(g) > -0.3f) allowed |= 1u << k;
    for (int k = 0; k < kGridActions; ++k) b.allowed.push_back(allowed >> k & 1u ? 1.0f : 0.0f);
    int a;
    do a = static_cast<int>(g() % kGridActions);
    while (!(allowed >> a & 1u));
    b.actions.push_back(a);
    b.logprobs.push_back(std::log(0.2f) + 0.6f * u(g));  // ratios from about 0.5 to 2
    b.advantages.push_back(2 * u(g));
    b.active.push_back(u(g) > -0.6f ? 1.0f : 0.0f);
    b.values.push_back(u(g));
    b.returns.push_back(b.values.back() + 0.5f * u(g));
  }
  return b;
}

/// eq:total_loss in LibTorch from given logits and values (the torch backend's expression).
torch::Tensor torch_loss(const Minibatch& b, const PpoSettings& s, const torch::Tensor& logits, const torch::Tensor& v,
                         torch::ScalarType type) {
  const int64_t R = b.rows;
  auto t = [&](const std::vector<float>& x, std::vector<int64_t> shape) {
    return torch::from_blob(const_cast<float*>(x.data()), shape).to(type);
  };
  const auto active = t(b.active, {R});
  const auto logp_all = torch::log_softmax(masked_logits(logits, t(b.allowed, {R, kGridActions})), 1);
  const auto actions = torch::tensor(b.actions, torch::kInt64);
  const auto logp = logp_all.gather(1, actions.unsqueeze(1)).squeeze(1);
  const auto entropy = masked_mean(-(logp_all.exp() * logp_all).sum(1), active);
  const auto policy = -masked_mean(clipped_surrogate(logp, t(b.logprobs, {R}), t(b.advantages, {R}), s.clip), active);
  const auto value = clipped_value_loss(v.view({R}), t(b.values, {R}), t(b.returns, {R}), s.clip);
  return policy + s.value_coef * value - s.entropy_coef * entropy;
}

}  // namespace

// The fused forward and backward passes against autograd, in float32 and float64, on the shapes
// the learners use (the paper's 11-real observation, the agent state, the set observation's
// width, a batch of one, a hidden width that is no multiple of the kernel's block).
TEST(PpoCore, FastMlpMatchesAutogradWithinFloat32Rounding) {
  struct Shape {
    int in, hidden, out, rows;
  };
  for (const Shape sh : {Shape{11, 64, 5, 1536}, Shape{37, 64, 1, 1536}, Shape{130, 64, 5, 7}, Shape{3, 20, 5, 1},
                         Shape{11, 96, 1, 13}}) {
    const std::string what = "in " + std::to_string(sh.in) + ", hidden " + std::to_string(sh.hidden) + ", out " +
                             std::to_string(sh.out) + ", rows " + std::to_string(sh.rows);
    torch::manual_seed(7);
    MlpNet net(sh.in, sh.hidden, sh.out);
    auto net64 = MlpNet(sh.in, sh.hidden, sh.out);
    {
      torch::NoGradGuard ng;
      for (std::size_t i = 0; i < net->parameters().size(); ++i) net64->parameters()[i].copy_(net->parameters()[i]);
    }
    net64->to(torch::kDouble);
    const auto x = torch::rand({sh.rows, sh.in}) * 4 - 2;
    const auto dout = torch::randn({sh.rows, sh.out});
    // LibTorch, float32 and float64.
    const auto y32 = net(x);
    (y32 * dout).sum().backward();
    const auto y64 = net64(x.to(torch::kDouble));
    (y64 * dout.to(torch::kDouble)).sum().backward();
    // The fast path.
    const auto fast = twin(net);
    fast::Mlp::Cache cache;
    const auto xs = as_vector(x);
    std::vector<float> out(static_cast<std::size_t>(sh.rows) * fast.out_stride());
    fast.forward(xs.data(), sh.rows, out.data(), &cache);
    std::vector<float> dpad(out.size(), 0.0f), grad(fast.size(), 0.0f);
    const auto dv = as_vector(dout);
    for (int r = 0; r < sh.rows; ++r)
      for (int k = 0; k < sh.out; ++k) dpad[static_cast<std::size_t>(r) * fast.out_stride() + k] = dv[static_cast<std::size_t>(r * sh.out + k)];
    fast.backward(cache, dpad.data(), grad.data());
    auto yf = torch::from_blob(out.data(), {sh.rows, fast.out_stride()}).narrow(1, 0, sh.out);
    const auto m = rounding_magnitudes(net64, x.to(torch::kDouble), dout.to(torch::kDouble));
    const int n = std::max({sh.rows, sh.in, sh.hidden});
    expect_within_rounding(yf, y32, y64, m.out, n, what + ": output");
    const auto g = unpack(fast, grad);
    for (std::size_t i = 0; i < 6; ++i)
      expect_within_rounding(g[i], net->parameters()[i].grad(), net64->parameters()[i].grad(), m.grad[i], n,
                             what + ": gradient " + std::to_string(i));
    // The bound is tight enough to see a row left out of the batch's sums.
    if (sh.rows > 1) {
      fast::Mlp::Cache short_cache;
      std::vector<float> short_out(out.size()), short_grad(fast.size(), 0.0f);
      fast.forward(xs.data(), sh.rows - 1, short_out.data(), &short_cache);
      fast.backward(short_cache, dpad.data(), short_grad.data());
      const auto gs = unpack(fast, short_grad);
      double seen = 0;
      for (std::size_t i = 0; i < 6; ++i) seen = std::max(seen, rounding_ratio(gs[i], net64->parameters()[i].grad(), m.grad[i], n));
      EXPECT_GT(seen, 1.0) << what << ": a dropped row stays within the rounding bound";
    }
    // Padding stays zero: the packed gradient re-packs to itself.
    std::array<const float*, 6> p{};
    for (std::size_t i = 0; i < 6; ++i) p[i] = g[i].data_ptr<float>();
    fast::Mlp repacked(sh.in, sh.hidden, sh.out);
    repacked.set_torch_layout(p);
    EXPECT_EQ(repacked.params(), grad) << what << ": gradient written into the padding";
  }
}

// The loss's gradient with respect to the logits and values (written out by hand) against
// autograd on the same expression in float64.
TEST(PpoCore, LossGradientMatchesAutograd) {
  const PpoSettings s{0.2, 0.5, 0.03, 10.0};
  for (std::uint64_t seed : {1, 2, 3}) {
    const auto b = random_minibatch(400, 1, 1, seed);
    torch::manual_seed(seed);
    const auto logits = (torch::randn({b.rows, kGridActions}) * 2).to(torch::kDouble).requires_grad_(true);
    const auto values = torch::randn({b.rows, 1}).to(torch::kDouble).requires_grad_(true);
    torch_loss(b, s, logits, values, torch::kDouble).backward();
    const auto l32 = as_vector(logits), v32 = as_vector(values);
    std::vector<float> dl(l32.size(), 0.0f), dv(v32.size(), 0.0f);
    const auto u = ppo_loss(b, s, l32.data(), kGridActions, v32.data(), 1, dl.data(), dv.data());
    const auto dl_t = torch::from_blob(dl.data(), {b.rows, kGridActions}), dv_t = torch::from_blob(dv.data(), {b.rows, 1});
    const double gl = logits.grad().abs().max().item<double>(), gv = values.grad().abs().max().item<double>();
    // ppo_loss works in float64 from the float32 inputs and rounds its output to float32.
    EXPECT_LE(max_error(dl_t, logits.grad()), 1e-6 * gl + 1e-9) << "seed " << seed;
    EXPECT_LE(max_error(dv_t, values.grad()), 1e-6 * gv + 1e-9) << "seed " << seed;
    // The statistics are those of the same expression.
    const auto total = u.policy_loss + s.value_coef * u.value_loss - s.entropy_coef * u.entropy;
    EXPECT_NEAR(total, torch_loss(b, s, logits.detach(), values.detach(), torch::kDouble).item<double>(), 1e-6) << "seed " << seed;
    EXPECT_GT(u.clipfrac, 0.05) << "the minibatch should exercise the clip";
    EXPECT_LT(u.clipfrac, 0.95);
  }
}

// One optimiser step of each backend from the same initial weights on the same minibatch: the
// same losses, approximate KL, clip fraction and gradient norm, and after 10 steps the same losses.
TEST(PpoCore, BackendsTakeTheSameSteps) {
  const PpoSettings s{0.2, 0.5, 0.03, 0.1};  // a small clip norm, so the clipping is exercised
  auto b = random_minibatch(512, 11, 37, 5);
  auto fast = make_ppo_networks(PpoBackend::Fast, 11, 37, 64, 3e-4, torch::kCPU, 9);
  auto ref = make_ppo_networks(PpoBackend::Torch, 11, 37, 64, 3e-4, torch::kCPU, 9);
  std::vector<float> lf(static_cast<std::size_t>(b.rows) * kGridActions), lr(lf.size());
  fast->logits(b.observations.data(), b.rows, lf.data());
  ref->logits(b.observations.data(), b.rows, lr.data());
  for (std::size_t i = 0; i < lf.size(); ++i) ASSERT_NEAR(lf[i], lr[i], 1e-5) << "same initial weights";
  for (int step = 0; step < 10; ++step) {
    const auto uf = fast->step(b, s), ur = ref->step(b, s);
    const double tol = step == 0 ? 1e-5 : 1e-3;  // after the first Adam step, near-zero gradients may differ in sign
    EXPECT_NEAR(uf.policy_loss, ur.policy_loss, tol * (1 + std::abs(ur.policy_loss))) << "step " << step;
    EXPECT_NEAR(uf.value_loss, ur.value_loss, tol * (1 + std::abs(ur.value_loss))) << "step " << step;
    EXPECT_NEAR(uf.entropy, ur.entropy, tol * (1 + std::abs(ur.entropy))) << "step " << step;
    EXPECT_NEAR(uf.approx_kl, ur.approx_kl, tol) << "step " << step;
    EXPECT_NEAR(uf.clipfrac, ur.clipfrac, step == 0 ? 1e-6 : 0.01) << "step " << step;
    EXPECT_NEAR(uf.grad_norm, ur.grad_norm, tol * ur.grad_norm) << "step " << step;
    if (step == 0) EXPECT_GT(ur.grad_norm, s.grad_clip) << "the clip should act";
  }
}

// The critic's first input columns may be the actor's observation (the set encoder's MAPPO: the
// observation, then the compact state), read from the minibatch's observations rather than stored
// twice. The fast backend gives the same bits as on whole critic rows (its first layer sums the
// same columns in the same order, the observation's then the rest), LibTorch's autograd the same
// numbers within float32 rounding; a batch laid out otherwise than the networks is refused.
TEST(PpoCore, TheCriticReadsTheActorsObservationInPlace) {
  const PpoSettings s{0.2, 0.5, 0.03, 0.1};
  const int rows = 512, obs = 11, own = 26, width = obs + own;
  Minibatch split = random_minibatch(rows, obs, own, 5);  // critic_inputs: the critic's own columns
  split.critic_width = width;
  split.critic_observation = obs;
  Minibatch whole = split;
  whole.critic_observation = 0;
  whole.critic_inputs.clear();
  for (int r = 0; r < rows; ++r) {
    const auto o = split.observations.begin() + static_cast<std::ptrdiff_t>(r) * obs;
    const auto c = split.critic_inputs.begin() + static_cast<std::ptrdiff_t>(r) * own;
    whole.critic_inputs.insert(whole.critic_inputs.end(), o, o + obs);
    whole.critic_inputs.insert(whole.critic_inputs.end(), c, c + own);
  }
  auto in_place = make_ppo_networks(PpoBackend::Fast, obs, width, 64, 3e-4, torch::kCPU, 9, 2, kGridActions, obs);
  auto copied = make_ppo_networks(PpoBackend::Fast, obs, width, 64, 3e-4, torch::kCPU, 9, 2);
  auto ref = make_ppo_networks(PpoBackend::Torch, obs, width, 64, 3e-4, torch::kCPU, 9, 1, kGridActions, obs);
  std::vector<float> vi(rows), vc(rows), vr(rows);
  for (int step = 0; step < 6; ++step) {
    in_place->values(split.observations.data(), split.critic_inputs.data(), rows, vi.data());
    copied->values(nullptr, whole.critic_inputs.data(), rows, vc.data());
    ref->values(split.observations.data(), split.critic_inputs.data(), rows, vr.data());
    ASSERT_EQ(vi, vc) << "step " << step;
    for (int r = 0; r < rows; ++r) ASSERT_NEAR(vi[static_cast<std::size_t>(r)], vr[static_cast<std::size_t>(r)], step == 0 ? 1e-5 : 1e-3);
    const auto ui = in_place->step(split, s), uc = copied->step(whole, s), ur = ref->step(split, s);
    EXPECT_EQ(ui.policy_loss, uc.policy_loss) << "step " << step;
    EXPECT_EQ(ui.value_loss, uc.value_loss) << "step " << step;
    EXPECT_EQ(ui.entropy, uc.entropy) << "step " << step;
    EXPECT_EQ(ui.approx_kl, uc.approx_kl) << "step " << step;
    EXPECT_EQ(ui.grad_norm, uc.grad_norm) << "step " << step;
    const double tol = step == 0 ? 1e-5 : 1e-3;
    EXPECT_NEAR(ui.value_loss, ur.value_loss, tol * (1 + std::abs(ur.value_loss))) << "step " << step;
    EXPECT_NEAR(ui.grad_norm, ur.grad_norm, tol * ur.grad_norm) << "step " << step;
  }
  EXPECT_THROW(in_place->step(whole, s), std::logic_error);
  EXPECT_THROW(copied->step(split, s), std::logic_error);
  EXPECT_THROW(ref->step(whole, s), std::logic_error);
}

// marl.minibatch = steps: the agents of a step share the critic's state columns (the compact
// state), and the fast backend multiplies them once per step (Minibatch::share), summing the
// step's output gradients before the weight gradient. The same loss to float32 rounding as
// LibTorch's autograd on every row and as the fast path row by row, over 6 steps; the same bits
// on one thread and two; a minibatch that splits a step is refused.
TEST(PpoCore, AgentsOfAStepShareTheCriticsStateColumns) {
  const PpoSettings s{0.2, 0.5, 0.03, 0.1};
  const int agents = 3, rows = agents * 171, obs = 11, own = 26, width = obs + own;
  Minibatch shared = random_minibatch(rows, obs, own, 7);
  shared.critic_width = width;
  shared.critic_observation = obs;
  for (int r = 0; r < rows; ++r)  // each step's state: its first agent's row
    std::copy_n(shared.critic_inputs.begin() + static_cast<std::ptrdiff_t>(r - r % agents) * own, own,
                shared.critic_inputs.begin() + static_cast<std::ptrdiff_t>(r) * own);
  shared.share = agents;
  Minibatch by_row = shared;
  by_row.share = 1;
  auto two = make_ppo_networks(PpoBackend::Fast, obs, width, 64, 3e-4, torch::kCPU, 9, 2, kGridActions, obs);
  auto one = make_ppo_networks(PpoBackend::Fast, obs, width, 64, 3e-4, torch::kCPU, 9, 1, kGridActions, obs);
  auto rows_apart = make_ppo_networks(PpoBackend::Fast, obs, width, 64, 3e-4, torch::kCPU, 9, 2, kGridActions, obs);
  auto ref = make_ppo_networks(PpoBackend::Torch, obs, width, 64, 3e-4, torch::kCPU, 9, 1, kGridActions, obs);
  for (int step = 0; step < 6; ++step) {
    const auto u2 = two->step(shared, s), u1 = one->step(shared, s), ua = rows_apart->step(by_row, s), ur = ref->step(shared, s);
    EXPECT_EQ(u2.policy_loss, u1.policy_loss) << "step " << step;
    EXPECT_EQ(u2.value_loss, u1.value_loss) << "step " << step;
    EXPECT_EQ(u2.grad_norm, u1.grad_norm) << "step " << step;
    const double tol = step == 0 ? 1e-5 : 1e-3;
    for (const auto* other : {&ua, &ur}) {
      EXPECT_NEAR(u2.policy_loss, other->policy_loss, tol * (1 + std::abs(other->policy_loss))) << "step " << step;
      EXPECT_NEAR(u2.value_loss, other->value_loss, tol * (1 + std::abs(other->value_loss))) << "step " << step;
      EXPECT_NEAR(u2.grad_norm, other->grad_norm, tol * other->grad_norm) << "step " << step;
    }
    if (step == 0) EXPECT_GT(ur.grad_norm, s.grad_clip) << "the clip should act";
  }
  std::vector<float> v2(rows), vr(rows);
  two->values(shared.observations.data(), shared.critic_inputs.data(), rows, v2.data());
  ref->values(shared.observations.data(), shared.critic_inputs.data(), rows, vr.data());
  for (int r = 0; r < rows; ++r) ASSERT_NEAR(v2[static_cast<std::size_t>(r)], vr[static_cast<std::size_t>(r)], 1e-3) << "row " << r;
  Minibatch split = shared;
  split.share = 4;  // 513 rows are not whole runs of 4
  EXPECT_THROW(two->step(split, s), std::logic_error);
}

// update() with marl.minibatch = steps: every minibatch holds whole steps, each step's agents in
// consecutive rows in agent order, every step once per epoch; Minibatch::share is the agent
// count where the rollout's critic columns are shared and 1 where they are not.
TEST(PpoCore, MinibatchesOfWholeSteps) {
  class Probe final : public PpoNetworks {
   public:
    int agents = 0;
    std::vector<std::vector<int>> seen;  // per step call: the steps in the minibatch's runs
    std::vector<int> shares;
    void logits(const float*, int, float*, int) override {}
    void values(const float*, const float*, int, float*, int) override {}
    UpdateStats step(Minibatch& b, const PpoSettings&) override {
      b.ready(0, b.rows);
      shares.push_back(b.share);
      std::vector<int> steps;
      EXPECT_EQ(b.rows % agents, 0);
      for (int k = 0; k < b.rows; ++k) {
        const float* o = b.observations.data() + static_cast<std::size_t>(k) * 2;
        EXPECT_EQ(static_cast<int>(o[1]), k % agents) << "row " << k;
        if (k % agents == 0) steps.push_back(static_cast<int>(o[0]));
        else EXPECT_EQ(static_cast<int>(o[0]), steps.back()) << "row " << k;
      }
      seen.push_back(steps);
      return {};
    }
    void set_learning_rate(double) override {}
    void set_average_decay(double) override {}
    void save(const std::string&, const nlohmann::json&, bool) override {}
    void load(const std::string&, bool) override {}
  };
  const int T = 10, M = 3, N = 3;
  Rollout r(T, M, N, 2, 3);
  for (int t = 0; t < T; ++t)
    for (int e = 0; e < M; ++e)
      for (int n = 0; n < N; ++n) {
        const std::size_t i = r.at(t, e, n);
        r.observations[i * 2] = static_cast<float>(t * M + e);
        r.observations[i * 2 + 1] = static_cast<float>(n);
        r.active[i] = 1.0f;
        r.advantages[i] = static_cast<float>(i % 7);
      }
  MarlConfig m;
  m.minibatch = MinibatchLayout::Steps;
  m.minibatches = 4, m.epochs = 2;
  for (const bool shared : {false, true}) {
    r.critic_shared = shared;
    Probe probe;
    probe.agents = N;
    RunningStats norm;
    Rng rng(3);
    Minibatch scratch;
    update(r, probe, norm, m, rng, scratch);
    ASSERT_EQ(probe.seen.size(), 8u);  // 30 steps in 4 minibatches of 7, twice
    for (int epoch = 0; epoch < 2; ++epoch) {
      std::vector<int> all;
      for (int k = 0; k < 4; ++k) {
        const auto& steps = probe.seen[static_cast<std::size_t>(epoch * 4 + k)];
        EXPECT_EQ(steps.size(), 7u);
        all.insert(all.end(), steps.begin(), steps.end());
      }
      std::sort(all.begin(), all.end());
      EXPECT_TRUE(std::adjacent_find(all.begin(), all.end()) == all.end()) << "a step twice in an epoch";
    }
    for (int share : probe.shares) EXPECT_EQ(share, shared ? N : 1);
  }
}

// marl.lr_schedule sets the optimiser's rate between updates, on both backends: at rate 0 a step
// leaves the actor exactly as it was; Adam's first step is the rate times g / (|g| + eps), so at
// half the rate the logits move half as far (to first order in the step: within 2%).
TEST(PpoCore, TheLearningRateIsSetBetweenSteps) {
  const PpoSettings s{0.2, 0.5, 0.03, 10};
  auto b = random_minibatch(256, 11, 37, 8);
  const std::size_t L = static_cast<std::size_t>(b.rows) * kGridActions;
  for (const PpoBackend backend : {PpoBackend::Fast, PpoBackend::Torch}) {
    std::vector<float> before(L), full(L), half(L), frozen(L);
    auto logits_after = [&](double rate, std::vector<float>& out) {
      auto nets = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 9);
      nets->logits(b.observations.data(), b.rows, before.data());
      nets->set_learning_rate(rate);
      nets->step(b, s);
      nets->logits(b.observations.data(), b.rows, out.data());
    };
    logits_after(3e-4, full);
    logits_after(1.5e-4, half);
    logits_after(0, frozen);
    EXPECT_EQ(frozen, before) << name_of(backend) << ": rate 0 moved the actor";
    double moved = 0, off = 0;
    for (std::size_t i = 0; i < L; ++i) {
      moved += std::abs(full[i] - before[i]);
      off += std::abs((half[i] - before[i]) - 0.5 * (full[i] - before[i]));
    }
    EXPECT_GT(moved, 0) << name_of(backend);
    EXPECT_LT(off, 0.02 * 0.5 * moved) << name_of(backend) << ": half the rate, not half the step";
  }
}

// marl.average_decay: on both backends the published actor (save without the optimiser: policy.pt
// and what validation scores) is the Polyak average a <- d a + (1 - d) w of the weights after each
// step, a = w after the first; last.pt (with the optimiser) keeps w and the average, so a run
// resumed from it continues the same average bit for bit; training and logits() go on with w.
TEST(PpoCore, ThePublishedActorIsThePolyakAverage) {
  const PpoSettings s{0.2, 0.5, 0.03, 10};
  auto b = random_minibatch(256, 11, 37, 8);
  const double d = 0.75;
  const nlohmann::json meta = nlohmann::json::object();
  const auto dir = skyloop::test::scratch_path("polyak");
  std::filesystem::create_directories(dir);
  auto file = [&](const std::string& name) { return (dir / name).string(); };
  auto actor_in = [](const std::string& path) {  // the actor an archive holds
    Nets nets;
    nets.actor = MlpNet(11, 64, kGridActions);
    nets.critic = MlpNet(37, 64, 1);
    marl::load(path, nets, nullptr);
    std::vector<torch::Tensor> out;
    for (auto& p : nets.actor->parameters()) out.push_back(p.detach().to(torch::kDouble).clone());
    return out;
  };
  for (const PpoBackend backend : {PpoBackend::Fast, PpoBackend::Torch}) {
    SCOPED_TRACE(name_of(backend));
    auto nets = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 9);
    nets->set_average_decay(d);
    std::vector<torch::Tensor> average;  // in float64, from each step's trained weights
    for (int step = 0; step < 4; ++step) {
      nets->step(b, s);
      nets->save(file("last.pt"), meta, true);
      const auto w = actor_in(file("last.pt"));
      if (average.empty()) average = w;
      else
        for (std::size_t i = 0; i < w.size(); ++i) average[i] = d * average[i] + (1 - d) * w[i];
    }
    nets->save(file("policy.pt"), meta, false);
    const auto published = actor_in(file("policy.pt")), trained = actor_in(file("last.pt"));
    double moved = 0;
    for (std::size_t i = 0; i < average.size(); ++i) {
      const double scale = average[i].abs().max().item<double>();
      EXPECT_LE(max_error(published[i], average[i]), 1e-6 * scale) << "parameter " << i;
      moved = std::max(moved, max_error(trained[i], average[i]) / scale);
    }
    EXPECT_GT(moved, 1e-5) << "the trained weights are not the average";
    // logits() acts with the trained weights, not the average.
    std::vector<float> with_w(static_cast<std::size_t>(b.rows) * kGridActions), reloaded(with_w.size());
    nets->logits(b.observations.data(), b.rows, with_w.data());
    auto from_last = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 1);
    from_last->load(file("last.pt"), true);
    from_last->logits(b.observations.data(), b.rows, reloaded.data());
    EXPECT_EQ(with_w, reloaded);
    // Resumed from last.pt after two steps, two more steps publish what four uninterrupted steps do.
    auto straight = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 9);
    auto first = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 9);
    auto resumed = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 5);
    for (auto* n : {straight.get(), first.get(), resumed.get()}) n->set_average_decay(d);
    for (int step = 0; step < 4; ++step) straight->step(b, s);
    for (int step = 0; step < 2; ++step) first->step(b, s);
    first->save(file("half.pt"), meta, true);
    resumed->load(file("half.pt"), true);
    for (int step = 0; step < 2; ++step) resumed->step(b, s);
    straight->save(file("straight.pt"), meta, false);
    resumed->save(file("resumed.pt"), meta, false);
    const auto a = actor_in(file("straight.pt")), r = actor_in(file("resumed.pt"));
    for (std::size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(torch::equal(a[i], r[i])) << "parameter " << i;
    // Off (the default): the published actor is the trained one.
    auto plain = make_ppo_networks(backend, 11, 37, 64, 3e-4, torch::kCPU, 9);
    for (int step = 0; step < 2; ++step) plain->step(b, s);
    plain->save(file("plain_policy.pt"), meta, false);
    plain->save(file("plain_last.pt"), meta, true);
    const auto pp = actor_in(file("plain_policy.pt")), pl = actor_in(file("plain_last.pt"));
    for (std::size_t i = 0; i < pp.size(); ++i) EXPECT_TRUE(torch::equal(pp[i], pl[i])) << "parameter " << i;
  }
}

// The fast backend splits every minibatch into two fixed halves (one per thread when allowed):
// the same numbers, bit for bit, on one thread or two.
TEST(PpoCore, FastBackendIsTheSameOnAnyThreadCount) {
  const PpoSettings s{0.2, 0.5, 0.03, 0.1};
  auto b = random_minibatch(333, 11, 37, 6);  // an odd row count: unequal halves
  auto one = make_ppo_networks(PpoBackend::Fast, 11, 37, 64, 3e-4, torch::kCPU, 4, 1);
  auto two = make_ppo_networks(PpoBackend::Fast, 11, 37, 64, 3e-4, torch::kCPU, 4, 2);
  for (int step = 0; step < 5; ++step) {
    const auto u1 = one->step(b, s), u2 = two->step(b, s);
    EXPECT_EQ(u1.policy_loss, u2.policy_loss) << "step " << step;
    EXPECT_EQ(u1.value_loss, u2.value_loss) << "step " << step;
    EXPECT_EQ(u1.grad_norm, u2.grad_norm) << "step " << step;
  }
  std::vector<float> l1(static_cast<std::size_t>(b.rows) * kGridActions), l2(l1.size());
  one->logits(b.observations.data(), b.rows, l1.data());
  two->logits(b.observations.data(), b.rows, l2.data());
  EXPECT_EQ(l1, l2);
}

namespace {
Config small_scene() {
  Config cfg;
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = 120;
  cfg.scenario.users = 6;
  cfg.trajectory.starts = {{0, 0}, {120, 120}};
  cfg.trajectory.destinations = {{120, 40}, {0, 80}};
  cfg.trajectory.t_max = 12;
  cfg.env.oracle = "zf";
  return cfg;
}
}  // namespace

TEST(PpoCore, CollectFillsEveryCellOfTheRollout) {
  Config cfg = small_scene();
  auto oracle = std::make_shared<RateOracle>(cfg, std::make_shared<ZfBeamformer>(), make_users(cfg, 6, 3));
  const Encoder enc = encoder_of(cfg, false);
  const CriticReader critic = CriticReader::of(cfg, enc);
  auto run = [&](Rollout& r) {
    VecEnv vec(cfg, oracle, 3);
    auto nets = make_ppo_networks(PpoBackend::Fast, enc.width(vec.env(0)), critic.width(vec.env(0)), 16, 3e-4, torch::kCPU, 1);
    Rng rng(11);
    EpisodeStats stats;
    collect(vec, enc, critic, SafetyOptions{true, true}, *nets, RunningStats{}, rng, r, stats);
    return stats;
  };
  const UavEnv probe(cfg, oracle);
  Rollout r(30, 3, 2, enc.width(probe), critic.width(probe));
  const auto stats = run(r);
  EXPECT_GE(stats.episodes, 3) << "30 steps of T_max = 12 episodes end at least once per environment";
  int done = 0;
  for (int t = 0; t < r.T; ++t)
    for (int e = 0; e < r.M; ++e) {
      done += r.dones[static_cast<std::size_t>(t * r.M + e)] > 0;
      EXPECT_TRUE(std::isfinite(r.rewards[static_cast<std::size_t>(t * r.M + e)]));
      for (int n = 0; n < r.N; ++n) {
        const auto i = r.at(t, e, n);
        const auto a = r.actions[i];
        ASSERT_GE(a, 0);
        ASSERT_LT(a, kGridActions);
        EXPECT_EQ(r.allowed[i * kGridActions + static_cast<std::size_t>(a)], 1.0f) << "t " << t << " e " << e << " n " << n;
        if (r.active[i] == 0) {
          EXPECT_EQ(a, kStay) << "an arrived UAV stays";
          EXPECT_EQ(r.logprobs[i], 0.0f);
        } else {
          EXPECT_LE(r.logprobs[i], 0.0f);
        }
        EXPECT_TRUE(std::isfinite(r.values[i]));
      }
    }
  EXPECT_EQ(done, stats.episodes);
  // Same seed, same rollout, bit for bit.
  Rollout again(30, 3, 2, r.obs_width, r.critic_width);
  run(again);
  EXPECT_EQ(again.observations, r.observations);
  EXPECT_EQ(again.actions, r.actions);
  EXPECT_EQ(again.logprobs, r.logprobs);
  EXPECT_EQ(again.rewards, r.rewards);
  EXPECT_EQ(again.next_values, r.next_values);
}

// collect() prepares the environments in kCollectLanes fixed groups, one per thread, each
// environment sampling from a stream of its own; the set observation's kernel maps are written
// inside the lanes too. Each environment's rows are its own, so the rollout is the same floats on
// one thread and on two: for the set encoder on layouts resampled every episode, for the MLP
// encoder on one scenario, with the look-ahead on one scenario (it asks the oracle, whose memo the
// environments share: written on the calling thread), with the look-ahead and the radio map on
// resampled layouts (each environment asks an oracle of its own: written in the lanes), and for
// continuous commands. Five environments: lanes of two and three.
TEST(PpoCore, CollectIsTheSameOnOneThreadAndOnTwo) {
  struct Case {
    const char* name;
    std::function<void(Config&)> set;
  };
  const std::vector<Case> cases{
      {"set encoder, resampled layouts",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.env.resample_users = true;
       }},
      {"mlp encoder, one scenario", [](Config&) {}},
      {"set encoder with the look-ahead, one scenario (one shared oracle)",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.marl.lookahead = true;
       }},
      {"set encoder with the look-ahead and the radio map, resampled layouts (an oracle per environment)",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.marl.lookahead = true;
         c.marl.rate_map = 2;
         c.env.resample_users = true;
       }},
      {"continuous commands", [](Config& c) { c.trajectory.mobility = "continuous"; }},
      {"sequential choices with the look-ahead, one scenario (one shared oracle: the lanes in turn)",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.marl.lookahead = true;
         c.marl.sequential = true;
       }},
      {"sequential choices with the look-ahead and the radio map, resampled layouts",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.marl.lookahead = true;
         c.marl.rate_map = 2;
         c.marl.sequential = true;
         c.env.resample_users = true;
       }},
      {"sequential choices in two passes (marl.sequential_passes), resampled layouts",
       [](Config& c) {
         c.marl.encoder = ObservationKind::Set;
         c.marl.lookahead = true;
         c.marl.sequential = true;
         c.marl.sequential_passes = 2;
         c.env.resample_users = true;
       }},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(k.name);
    Config cfg = small_scene();
    k.set(cfg);
    auto beamformer = std::make_shared<ZfBeamformer>();
    auto rollout_on = [&](int threads) {
      cfg.run.threads = threads;
      const Encoder enc = encoder_of(cfg, false);
      const CriticReader critic = CriticReader::of(cfg, enc);
      // A fresh oracle per run: its memo's hits and misses must not differ between the runs.
      VecEnv vec = cfg.env.resample_users ? VecEnv(cfg, beamformer, 5, 7)
                                          : VecEnv(cfg, std::make_shared<RateOracle>(cfg, beamformer, make_users(cfg, 6, 3)), 5);
      const int dims = vec.env(0).dynamics().actions().dims;
      Rollout r(30, 5, 2, enc.width(vec.env(0)), critic.width(vec.env(0)), dims > 0 ? 0 : vec.env(0).actions(), dims,
                critic.observation_width(vec.env(0)));
      auto nets = make_ppo_networks(PpoBackend::Fast, r.obs_width, r.critic_width, 16, 3e-4, torch::kCPU, 1, 1,
                                    dims > 0 ? 2 * dims : r.A, r.critic_observation);
      EXPECT_EQ(nets->lanes(), kCollectLanes);
      Rng rng(11);
      EpisodeStats stats;
      collect(vec, enc, critic, SafetyOptions{true, true}, *nets, RunningStats{}, rng, r, stats, threads);
      EXPECT_GE(stats.episodes, 5) << "30 steps of T_max = 12: every environment ends an episode";
      return r;
    };
    const Rollout one = rollout_on(1), two = rollout_on(2);
    EXPECT_EQ(one.observations, two.observations);
    EXPECT_EQ(one.critic_inputs, two.critic_inputs);
    EXPECT_EQ(one.actions, two.actions);
    EXPECT_EQ(one.raw_actions, two.raw_actions);
    EXPECT_EQ(one.allowed, two.allowed);
    EXPECT_EQ(one.logprobs, two.logprobs);
    EXPECT_EQ(one.values, two.values);
    EXPECT_EQ(one.rewards, two.rewards);
    EXPECT_EQ(one.dones, two.dones);
    EXPECT_EQ(one.next_values, two.next_values);
  }
  // Every encoder may write in the lanes; the observations that ask the rate oracle say so (collect
  // writes them on the calling thread where the environments share one oracle).
  Config cfg = small_scene();
  cfg.run.threads = 2;
  cfg.marl.encoder = ObservationKind::Set;
  EXPECT_EQ(encoder_of(cfg, false).threads, 2);
  EXPECT_FALSE(encoder_of(cfg, false).asks_oracle);
  cfg.marl.lookahead = true;
  EXPECT_EQ(encoder_of(cfg, false).threads, 2);
  EXPECT_TRUE(encoder_of(cfg, false).asks_oracle);
  cfg.marl.lookahead = false;
  cfg.marl.rate_map = 2;
  EXPECT_TRUE(encoder_of(cfg, false).asks_oracle);
  cfg.marl.rate_map = 0;
  cfg.marl.encoder = ObservationKind::Paper;  // the paper's observation reads the environment alone
  EXPECT_EQ(encoder_of(cfg, false).threads, 2);
  EXPECT_FALSE(encoder_of(cfg, false).asks_oracle);
  auto beamformer = std::make_shared<ZfBeamformer>();
  EXPECT_FALSE(VecEnv(cfg, beamformer, 2, 7).shares_oracle());
  EXPECT_TRUE(VecEnv(cfg, std::make_shared<RateOracle>(cfg, beamformer, make_users(cfg, 6, 3)), 2).shares_oracle());
}

// marl.sequential: the UAVs choose in shield order (least slack first), and what the actor read
// for each is its observation with the landings of the UAVs that chose before it shown
// (UavEnv::show_decided): replayed here on a copy of the environment from the rollout's own
// actions, every row of every step is the observation written that way, and the critic's input
// holds the same observation. Three UAVs, so a UAV is seen by one chooser and by two.
TEST(PpoCore, SequentialAgentsReadTheLandingsChosenBeforeThem) {
  Config cfg = small_scene();
  cfg.trajectory.starts = {{0, 0}, {120, 120}, {0, 120}};
  cfg.trajectory.destinations = {{120, 40}, {0, 80}, {120, 80}};
  cfg.marl.encoder = ObservationKind::Set;
  cfg.marl.lookahead = true;
  cfg.marl.rate_map = 1;
  cfg.marl.sequential = true;
  validate(cfg);
  const Encoder enc = encoder_of(cfg, false);
  ASSERT_TRUE(enc.sequential);
  const CriticReader critic = CriticReader::of(cfg, enc);
  auto oracle = std::make_shared<RateOracle>(cfg, std::make_shared<ZfBeamformer>(), make_users(cfg, 6, 3));
  VecEnv vec(cfg, oracle, 1);
  UavEnv replay = vec.env(0);
  const int N = 3, D = enc.width(replay);
  Rollout r(30, 1, N, D, critic.width(replay), kGridActions, 0, critic.observation_width(replay));
  ASSERT_EQ(r.critic_observation, D) << "the critic reads the actor's observation row";
  auto nets = make_ppo_networks(PpoBackend::Fast, r.obs_width, r.critic_width, 16, 3e-4, torch::kCPU, 1, 1, r.A, r.critic_observation);
  Rng rng(5);
  EpisodeStats stats;
  collect(vec, enc, critic, SafetyOptions{true, true}, *nets, RunningStats{}, rng, r, stats, 1);
  ASSERT_GE(stats.episodes, 2);
  int shown = 0, differs = 0;
  for (int t = 0; t < r.T; ++t) {
    const auto order = shield_order(replay);
    std::vector<float> state(static_cast<std::size_t>(UavEnv::compact_state_size()));
    replay.write_compact_state(state.data());
    std::vector<int> act(N, replay.hover());
    for (int n = 0; n < N; ++n) act[static_cast<std::size_t>(n)] = static_cast<int>(r.actions[r.at(t, 0, n)]);
    std::vector<float> want(static_cast<std::size_t>(D)), plain(static_cast<std::size_t>(D));
    for (const int n : order) {
      replay.write_set_observation(n, want.data());
      const float* got = r.observations.data() + r.at(t, 0, n) * static_cast<std::size_t>(D);
      ASSERT_EQ(std::vector<float>(got, got + D), want) << "t = " << t << ", UAV " << n;
      const float* own = r.critic_inputs.data() + r.at(t, 0, n) * static_cast<std::size_t>(r.critic_own());  // after the observation
      ASSERT_EQ(std::vector<float>(own, own + r.critic_own()), state) << "t = " << t << ", UAV " << n;
      if (shown > 0) {
        UavEnv fresh = replay;
        fresh.clear_decided();
        fresh.write_set_observation(n, plain.data());
        if (plain != want) ++differs;
      }
      const auto l = replay.landing(n, act[static_cast<std::size_t>(n)]);
      replay.show_decided(n, l.x, l.y, l.z);
      ++shown;
    }
    shown = 0;
    replay.clear_decided();
    replay.step(act);
    if (replay.done()) replay.reset();
  }
  EXPECT_GT(differs, 10) << "the landings chosen before change what a later UAV reads";
}

// Each environment samples from its own stream: environment e's moves do not depend on how many
// environments share the rollout (the first two of five act as the two of two).
TEST(PpoCore, EachEnvironmentSamplesFromAStreamOfItsOwn) {
  Config cfg = small_scene();
  auto oracle = std::make_shared<RateOracle>(cfg, std::make_shared<ZfBeamformer>(), make_users(cfg, 6, 3));
  const Encoder enc = encoder_of(cfg, false);
  const CriticReader critic = CriticReader::of(cfg, enc);
  auto draws = [&](int envs) {
    VecEnv vec(cfg, oracle, envs);
    Rollout r(12, envs, 2, enc.width(vec.env(0)), critic.width(vec.env(0)));
    auto nets = make_ppo_networks(PpoBackend::Fast, r.obs_width, r.critic_width, 16, 3e-4, torch::kCPU, 1);
    Rng rng(5);
    EpisodeStats stats;
    collect(vec, enc, critic, SafetyOptions{true, true}, *nets, RunningStats{}, rng, r, stats, 2);
    return r;
  };
  const Rollout five = draws(5), two = draws(2);
  for (int t = 0; t < 12; ++t)
    for (int e = 0; e < 2; ++e)
      for (int n = 0; n < 2; ++n) {
        EXPECT_EQ(five.actions[five.at(t, e, n)], two.actions[two.at(t, e, n)]) << "t " << t << " e " << e << " n " << n;
        EXPECT_EQ(five.logprobs[five.at(t, e, n)], two.logprobs[two.at(t, e, n)]);
      }
  // and the streams differ between environments: the same scene, other moves.
  int differ = 0;
  for (int t = 0; t < 12; ++t)
    for (int n = 0; n < 2; ++n) differ += five.actions[five.at(t, 0, n)] != five.actions[five.at(t, 1, n)];
  EXPECT_GT(differ, 0);
}

TEST(PpoCore, AdvantagesAreGaePerEnvironmentAndAgent) {
  Rollout r(9, 3, 2, 1, 1);
  std::mt19937_64 g(4);
  std::uniform_real_distribution<float> u(-1, 1);
  for (auto& x : r.rewards) x = u(g);
  for (auto& x : r.dones) x = u(g) > 0.5f ? 1.0f : 0.0f;
  for (auto& x : r.values) x = u(g);
  for (auto& x : r.next_values) x = u(g);
  compute_advantages(r, 0.9, 0.8);
  for (int e = 0; e < r.M; ++e)
    for (int n = 0; n < r.N; ++n) {
      std::vector<double> rew, val;
      std::vector<int> done;
      for (int t = 0; t < r.T; ++t) {
        rew.push_back(r.rewards[static_cast<std::size_t>(t * r.M + e)]);
        done.push_back(r.dones[static_cast<std::size_t>(t * r.M + e)] > 0);
        val.push_back(r.values[r.at(t, e, n)]);
      }
      val.push_back(r.next_values[static_cast<std::size_t>(e * r.N + n)]);
      const auto a = gae(rew, val, done, 0.9, 0.8);
      for (int t = 0; t < r.T; ++t) {
        EXPECT_NEAR(r.advantages[r.at(t, e, n)], a[static_cast<std::size_t>(t)], 1e-6);
        EXPECT_NEAR(r.returns[r.at(t, e, n)], a[static_cast<std::size_t>(t)] + val[static_cast<std::size_t>(t)], 1e-6);
      }
    }
}

TEST(PpoCore, ExplainedVarianceOverActiveAgents) {
  Rollout r(4, 1, 1, 1, 1);
  r.returns = {1, 2, 3, 100};
  r.active = {1, 1, 1, 0};  // the inactive row is ignored
  r.values = {1, 2, 3, -50};
  EXPECT_NEAR(explained_variance(r), 1.0, 1e-12);
  r.values = {0, 0, 0, 0};
  EXPECT_NEAR(explained_variance(r), 0.0, 1e-12);
  r.values = {2, 2, 2, 0};  // residuals 1 - 2, 0, 1: Var = 2/3 = Var[returns]
  EXPECT_NEAR(explained_variance(r), 0.0, 1e-12);
  r.values = {1.5, 2, 2.5, 0};  // residuals -0.5, 0, 0.5: Var = 1/6, 1 - (1/6)/(2/3) = 0.75
  EXPECT_NEAR(explained_variance(r), 0.75, 1e-12);
  r.returns = {2, 2, 2, 0};
  EXPECT_TRUE(std::isnan(explained_variance(r)));
}

// update() moves the policy towards the actions with positive advantages, on both backends.
TEST(PpoCore, UpdateRaisesTheProbabilityOfAdvantageousActions) {
  for (const PpoBackend backend : {PpoBackend::Fast, PpoBackend::Torch}) {
    Rollout r(64, 2, 2, 6, 6);
    std::mt19937_64 g(8);
    std::uniform_real_distribution<float> u(-1, 1);
    for (auto& x : r.observations) x = u(g);
    r.critic_inputs = r.observations;
    std::fill(r.allowed.begin(), r.allowed.end(), 1.0f);
    std::fill(r.active.begin(), r.active.end(), 1.0f);
    auto nets = make_ppo_networks(backend, 6, 6, 32, 1e-3, torch::kCPU, 3);
    std::vector<float> before(r.samples() * kGridActions);
    nets->logits(r.observations.data(), static_cast<int>(r.samples()), before.data());
    for (std::size_t i = 0; i < r.samples(); ++i) {
      r.actions[i] = static_cast<std::int64_t>(g() % kGridActions);
      const float* z = before.data() + i * kGridActions;
      double sum = 0;
      for (int k = 0; k < kGridActions; ++k) sum += std::exp(z[k]);
      r.logprobs[i] = static_cast<float>(z[r.actions[i]] - std::log(sum));
      r.advantages[i] = r.actions[i] == kRight ? 1.0f : -0.25f;
      r.values[i] = 0;
      r.returns[i] = r.advantages[i];
    }
    MarlConfig m;
    m.epochs = 4;
    m.minibatches = 4;
    RunningStats vn;
    Rng rng(2);
    Minibatch scratch;
    const auto stats = update(r, *nets, vn, m, rng, scratch);
    EXPECT_GT(stats.approx_kl, 0.0) << name_of(backend);
    EXPECT_LT(stats.policy_loss, 0.0) << name_of(backend);
    std::vector<float> after(before.size());
    nets->logits(r.observations.data(), static_cast<int>(r.samples()), after.data());
    auto mean_p_east = [&](const std::vector<float>& z) {
      double s = 0;
      for (std::size_t i = 0; i < r.samples(); ++i) {
        double sum = 0;
        for (int k = 0; k < kGridActions; ++k) sum += std::exp(z[i * kGridActions + static_cast<std::size_t>(k)]);
        s += std::exp(z[i * kGridActions + kRight]) / sum;
      }
      return s / static_cast<double>(r.samples());
    };
    EXPECT_GT(mean_p_east(after), mean_p_east(before) + 0.05) << name_of(backend);
  }
}

// ---- the squashed Gaussian policy (continuous mobility) -------------------------------------------

// log pi(tanh(z)) = log N(z; mu, sigma^2) - log(1 - tanh(z)^2) at points computed by hand from that
// formula (double precision, outside skyloop): (z, mu, log sigma) = (0.5, 0.2, -0.3): -0.4607048653;
// (-1.3, 0.4, 0.5): -0.5935293029; (0, 0, 0): -0.9189385332 (= -log(2 pi) / 2). The Jacobian term
// at z = 20, 2 (log 2 - 20 - log1p(e^-40)) = -38.6137056389, where 1 - tanh^2 underflows in float.
TEST(PpoCore, SquashedGaussianLogProbabilityAtHandComputedPoints) {
  EXPECT_NEAR(squashed_gaussian_logprob(0.5, 0.2, -0.3), -0.4607048653, 1e-9);
  EXPECT_NEAR(squashed_gaussian_logprob(-1.3, 0.4, 0.5), -0.5935293029, 1e-9);
  EXPECT_NEAR(squashed_gaussian_logprob(0.0, 0.0, 0.0), -0.9189385332, 1e-9);
  EXPECT_NEAR(tanh_log_jacobian(20.0), -38.6137056389, 1e-9);
  EXPECT_NEAR(tanh_log_jacobian(-20.0), -38.6137056389, 1e-9);  // even in z
  // log sigma is clamped to [kLogStdMin, kLogStdMax].
  EXPECT_EQ(squashed_gaussian_logprob(0.5, 0.2, 3.0), squashed_gaussian_logprob(0.5, 0.2, kLogStdMax));
  EXPECT_EQ(squashed_gaussian_logprob(0.5, 0.2, -9.0), squashed_gaussian_logprob(0.5, 0.2, kLogStdMin));
  // A density on (-1, 1): exp(log pi(u)) integrates to 1 (midpoint rule in u, z = atanh(u)).
  for (const auto& [mu, ls] : {std::pair<double, double>{0.3, -0.5}, {-1.5, 0.2}, {2.0, -1.0}}) {
    const int n = 200000;
    double mass = 0;
    for (int i = 0; i < n; ++i) {
      const double u = -1 + (i + 0.5) * 2.0 / n;
      mass += std::exp(squashed_gaussian_logprob(std::atanh(u), mu, ls)) * 2.0 / n;
    }
    EXPECT_NEAR(mass, 1.0, 2e-3) << "mu " << mu << ", log sigma " << ls;
  }
}

namespace {
/// A continuous minibatch: samples z near and far from the actor's means, old log-probabilities
/// spread so the ratio meets the clip on both sides.
Minibatch gaussian_minibatch(int rows, int obs_width, int critic_width, std::uint64_t seed) {
  Minibatch b = random_minibatch(rows, obs_width, critic_width, seed);
  std::mt19937_64 g(seed + 100);
  std::normal_distribution<float> n(0, 1);
  b.dims = 2, b.action_count = 0;
  b.allowed.clear(), b.actions.assign(static_cast<std::size_t>(rows), 0);
  b.raw_actions.clear();
  for (int i = 0; i < rows * 2; ++i) b.raw_actions.push_back(1.5f * n(g));
  for (int i = 0; i < rows; ++i) b.logprobs[static_cast<std::size_t>(i)] = -2.0f + 0.6f * n(g);
  return b;
}

/// eq:total_loss with the squashed Gaussian, in LibTorch, written independently of the backend:
/// log(1 - tanh(z)^2) directly (fine in float64 for these z), the clamp by min / max.
torch::Tensor torch_gaussian_loss(const Minibatch& b, const PpoSettings& s, const torch::Tensor& out, const torch::Tensor& v) {
  const int64_t R = b.rows;
  auto t = [&](const std::vector<float>& x, std::vector<int64_t> shape) {
    return torch::from_blob(const_cast<float*>(x.data()), shape).to(torch::kDouble);
  };
  const auto active = t(b.active, {R});
  const auto mu = out.narrow(1, 0, 2), ls = torch::min(torch::max(out.narrow(1, 2, 2), torch::tensor(kLogStdMin, torch::kDouble)),
                                                       torch::tensor(kLogStdMax, torch::kDouble));
  const auto z = t(b.raw_actions, {R, 2});
  const auto logp = (-0.5 * ((z - mu) / ls.exp()).pow(2) - ls - 0.5 * std::log(2 * M_PI) - torch::log(1 - z.tanh().pow(2))).sum(1);
  // The squashed distribution's entropy at z = mu + sigma e, e = (z - mu) / sigma held fixed.
  const auto zr = mu + ls.exp() * ((z - mu) / ls.exp()).detach();
  const auto entropy = masked_mean((ls + 0.5 + 0.5 * std::log(2 * M_PI) + torch::log(1 - zr.tanh().pow(2))).sum(1), active);
  const auto policy = -masked_mean(clipped_surrogate(logp, t(b.logprobs, {R}), t(b.advantages, {R}), s.clip), active);
  const auto value = clipped_value_loss(v.view({R}), t(b.values, {R}), t(b.returns, {R}), s.clip);
  return policy + s.value_coef * value - s.entropy_coef * entropy;
}
}  // namespace

TEST(PpoCore, GaussianLossGradientMatchesAutograd) {
  const PpoSettings s{0.2, 0.5, 0.03, 10.0};
  for (std::uint64_t seed : {1, 2, 3}) {
    auto b = gaussian_minibatch(400, 1, 1, seed);
    torch::manual_seed(seed);
    // Means near the samples, log sigma across the clamp (some rows outside [-5, 1]).
    auto o = torch::randn({b.rows, 4});
    o.narrow(1, 2, 2).mul_(2.5).sub_(1.0);
    const auto out = o.to(torch::kDouble).requires_grad_(true);
    {  // old log-probabilities within a factor of about e^0.6 of the current ones: ratios on both sides of the clip
      const auto ov = as_vector(o);
      std::mt19937_64 g(seed);
      std::uniform_real_distribution<double> d(-0.6, 0.6);
      for (int i = 0; i < b.rows; ++i) {
        double lp = 0;
        for (int k = 0; k < 2; ++k)
          lp += squashed_gaussian_logprob(b.raw_actions[static_cast<std::size_t>(2 * i + k)], ov[static_cast<std::size_t>(4 * i + k)],
                                          ov[static_cast<std::size_t>(4 * i + 2 + k)]);
        b.logprobs[static_cast<std::size_t>(i)] = static_cast<float>(lp + d(g));
      }
    }
    const auto values = torch::randn({b.rows, 1}).to(torch::kDouble).requires_grad_(true);
    torch_gaussian_loss(b, s, out, values).backward();
    const auto o32 = as_vector(out), v32 = as_vector(values);
    std::vector<float> dl(o32.size(), 0.0f), dv(v32.size(), 0.0f);
    const auto u = ppo_loss(b, s, o32.data(), 4, v32.data(), 1, dl.data(), dv.data());
    const auto dl_t = torch::from_blob(dl.data(), {b.rows, 4});
    const double gl = out.grad().abs().max().item<double>();
    EXPECT_LE(max_error(dl_t, out.grad()), 1e-6 * gl + 1e-9) << "seed " << seed;
    const auto total = u.policy_loss + s.value_coef * u.value_loss - s.entropy_coef * u.entropy;
    EXPECT_NEAR(total, torch_gaussian_loss(b, s, out.detach(), values.detach()).item<double>(), 1e-6) << "seed " << seed;
    EXPECT_GT(u.clipfrac, 0.05) << "the minibatch should exercise the clip";
    EXPECT_LT(u.clipfrac, 0.95);
    // With no advantage the actor's gradient is the entropy bonus's alone (the surrogate's, scaled by
    // 1 / sigma, would hide it above): the squashed entropy's reparameterised gradient.
    std::fill(b.advantages.begin(), b.advantages.end(), 0.0f);
    const auto out2 = out.detach().clone().requires_grad_(true);
    torch_gaussian_loss(b, s, out2, values.detach()).backward();
    std::fill(dl.begin(), dl.end(), 0.0f);
    const auto u2 = ppo_loss(b, s, o32.data(), 4, v32.data(), 1, dl.data(), dv.data());
    const double ge = out2.grad().abs().max().item<double>();
    EXPECT_GT(ge, 0.0);
    EXPECT_LE(max_error(torch::from_blob(dl.data(), {b.rows, 4}), out2.grad()), 1e-6 * ge + 1e-12) << "seed " << seed;
    EXPECT_NEAR(u2.entropy, u.entropy, 1e-12);
  }
}

TEST(PpoCore, BackendsTakeTheSameGaussianSteps) {
  const PpoSettings s{0.2, 0.5, 0.01, 0.1};
  auto b = gaussian_minibatch(512, 8, 37, 5);
  auto fast = make_ppo_networks(PpoBackend::Fast, 8, 37, 64, 3e-4, torch::kCPU, 9, 1, 4);
  auto ref = make_ppo_networks(PpoBackend::Torch, 8, 37, 64, 3e-4, torch::kCPU, 9, 1, 4);
  for (int step = 0; step < 10; ++step) {
    const auto uf = fast->step(b, s), ur = ref->step(b, s);
    const double tol = step == 0 ? 1e-5 : 1e-3;
    EXPECT_NEAR(uf.policy_loss, ur.policy_loss, tol * (1 + std::abs(ur.policy_loss))) << "step " << step;
    EXPECT_NEAR(uf.entropy, ur.entropy, tol * (1 + std::abs(ur.entropy))) << "step " << step;
    EXPECT_NEAR(uf.approx_kl, ur.approx_kl, tol) << "step " << step;
    EXPECT_NEAR(uf.grad_norm, ur.grad_norm, tol * ur.grad_norm) << "step " << step;
  }
}
