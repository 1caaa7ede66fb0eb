// A beamformer of your own, registered by name and compared with the built-in ones on the same
// seeded snapshots (docs/extending/beamformer.md). Built and run by the test suite
// (ctest -R examples.my_beamformer).
//
// The precoder: zero forcing with equal power per user (the classic ZF with the power shared
// evenly instead of water-filled), an example of a design() that sees one cluster.
#include <cmath>
#include <cstdio>
#include <memory>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/experiments/builtin.hpp"

namespace {

class EqualPowerZf final : public skyloop::Beamformer {
 public:
  std::string name() const override { return "eqzf"; }
  // W: [L x K_n], column k = w_k, within the cluster's budget c.p_max (||W||_F^2 <= P_max).
  skyloop::MatrixXcd design(const skyloop::Cluster& c) const override {
    const skyloop::MatrixXcd H = c.G.adjoint();                          // [L x K_n], column k = h_k
    skyloop::MatrixXcd W = H * (c.G * H).inverse();                     // G W = I: no intra-cluster interference
    for (Eigen::Index k = 0; k < W.cols(); ++k) W.col(k) *= std::sqrt(c.p_max / W.cols()) / W.col(k).norm();
    return W;
  }
};

}  // namespace

int main() {
  // Registered by name: from here on "eqzf" works wherever a method is named in this process.
  skyloop::builtin_beamformers().add("eqzf", "ZF with equal power per user", [](const skyloop::Config&, const std::string&) {
    return std::make_unique<EqualPowerZf>();
  });
  const skyloop::Config cfg;  // the paper's Section VI settings: N = 3, K = 12, L = 4, 30 dBm
  const skyloop::SystemModel model(cfg);
  const char* methods[] = {"eqzf", "zf", "mrt", "wmmse"};
  double total[4] = {0, 0, 0, 0};
  const int samples = 50;
  for (int i = 0; i < samples; ++i) {
    // Snapshot i of `skyloop beamform eval --seed 1`: the same channels that command sees.
    const auto snap = model.random_snapshot(cfg.scenario.uavs, cfg.scenario.users, skyloop::derive_seed(1, i));
    for (int m = 0; m < 4; ++m) {
      const auto bf = skyloop::builtin_beamformers().create(methods[m], cfg);
      for (const auto& c : model.clusters(snap)) {
        const auto W = bf->design(c);
        skyloop::check_beamformer_output(*bf, c, W);  // shape, finiteness and budget, as every evaluation checks
        total[m] += skyloop::sum_rate(c, W);
      }
    }
  }
  for (int m = 0; m < 4; ++m) std::printf("%-6s %8.3f bit/s/Hz\n", methods[m], total[m] / samples);
  // What the example claims: equal power loses to water-filled ZF's selection and to WMMSE, and
  // beats matched filtering in these correlated LoS clusters.
  return total[0] > total[2] && total[0] < total[3] ? 0 : 1;
}
