#pragma once
// The small-scale fading seam, beside path loss (channel_model.hpp's PathLossModel): from a link's
// large-scale state and its steering vector, the channel h of one fast slot. ChannelModel owns one,
// made from channel.fading by make_fading; every cluster, network, the rate oracle and the DP read
// channels through it.
//
//   none (the paper):  h = sqrt(beta) a                (K = +infinity, one fast slot)
//   rician:            h = sqrt(beta) (sqrt(K / (K + 1)) a + sqrt(1 / (K + 1)) g),  g ~ CN(0, I_L),
//                      K = channel.rician_k_db, or rising linearly in dB with the elevation from
//                      rician_k_min_db at 0 deg to rician_k_max_db at 90 deg (channel.rician_k =
//                      elevation); an NLoS link is Rayleigh (K = 0: its direct path is blocked).
//
// g's entries are pure functions of a key per (channel.seed, UAV position, user position, fast
// slot) and the antenna: revisiting a position sees the same realisations, so the memo and the DP
// stay exact. docs/extending/channel-model.md: adding a model (a class and a row of fading_models()).
#include <array>
#include <cstdint>
#include <memory>
#include <string_view>
#include <utility>

#include "skyloop/core/config.hpp"
#include "skyloop/core/registry.hpp"
#include "skyloop/core/types.hpp"

namespace skyloop {

struct LinkState;

class FadingModel {
 public:
  virtual ~FadingModel() = default;
  /// Realisations per trajectory slot: channel.fast_slots where h is random, else 1.
  virtual int fast_slots() const = 0;
  /// Whether h has a random part (then realise reads `draws`).
  virtual bool random() const = 0;
  /// The link's Rician K in dB (+infinity: no scattered part; -infinity: Rayleigh).
  virtual double k_factor_db(const LinkState& s) const = 0;
  /// h of the link in one fast slot from its state and steering vector a; `draws` keys the slot's
  /// standard normals (unit_normals(derive_seed(draws, l)) for antenna l).
  virtual VectorXcd realise(const LinkState& s, const VectorXcd& a, std::uint64_t draws) const = 0;
};

/// A model's factory, from channel.fading's settings (channel.rician_k and its K, channel.fast_slots).
using FadingFactory = std::unique_ptr<FadingModel> (*)(const ChannelConfig&);
/// Every model, the paper's first: channel.fading's allowed values, their help and factories.
const Registry<FadingFactory>& fading_models();

/// The model named by channel.fading.
std::unique_ptr<FadingModel> make_fading(const ChannelConfig& c);

/// Two independent standard normals that are a pure function of `key` (Box-Muller on two mixed words).
std::pair<double, double> unit_normals(std::uint64_t key);

}  // namespace skyloop
