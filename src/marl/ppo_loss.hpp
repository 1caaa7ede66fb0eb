#pragma once
// What the PPO core's networks (ppo_networks.cpp) take of its losses (ppo_loss.cpp) beyond
// ppo.hpp: the loss of a range of a minibatch's rows, for a backend that shares a minibatch out
// among threads, and the constants both sides of the squashed Gaussian use.
#include "ppo.hpp"

namespace skyloop {
namespace marl {

constexpr double kHalfLog2Pi = 0.91893853320467274178;  // log(2 pi) / 2

/// ppo_loss over the rows [first, last) of the minibatch, with the whole minibatch's normalisers
/// (its active agents and its rows): the rows' share of the loss and of its gradient. The
/// pointers address row `first`.
UpdateStats ppo_loss_rows(const Minibatch& b, const PpoSettings& s, int first, int last, double per_active,
                          const float* logits, int logit_stride, const float* values, int value_stride, float* dlogits,
                          float* dvalues);

/// 1 / the minibatch's active agents (at least one).
double inverse_active(const Minibatch& b);

}  // namespace marl
}  // namespace skyloop
