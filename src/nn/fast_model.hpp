#pragma once
// Fast inference for the learned beamformers (the per-cluster GNN with either readout, DeepSets,
// MS-PointNet, and the network-level interference-aware GNN): the same weights as the LibTorch modules in models.hpp, read from the same
// checkpoint, evaluated with fused float32 kernels over a whole batch of clusters (fast_gemm.hpp)
// instead of ~300 LibTorch operators per call. LibTorch stays the training path and the reference;
// nn_test holds the two equal to float32 tolerance. Torch-free: the loader hands over the
// parameters by name (torch's named_parameters, e.g. "user_msg.0.l1.weight").
//
// Layout: every activation is a row-major float matrix, one row per user (or per UAV node),
// rows padded to the kernel's row block. A concatenated input ([u, m_a, max_j m_u]) is never
// built: the first layer's weight is split by input part, and a per-cluster part (m_a) is
// multiplied once per cluster and added to its users' rows. The interference-aware GNN's edges
// (one row per transmitting UAV and user of another cluster) read their UAV's and their user's
// rows the same way, by index; only the real users, clusters and edges have rows (no padding).
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/channel/network.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::nn::fast {

struct Param {
  std::vector<long> shape;
  std::vector<float> data;  // row-major, as torch stores a contiguous tensor
};
using Params = std::map<std::string, Param>;

class Model {
 public:
  /// The fast twin of a checkpoint's model, or nullptr for a model without one.
  /// Throws std::invalid_argument when a parameter is missing or has the wrong shape.
  static std::unique_ptr<Model> build(const ModelInfo& info, const Params& params);
  ~Model();

  /// Raw beamformers [L x K_n] (before scaling onto the budget) of non-empty clusters with the
  /// model's antenna count: the float32 forward pass of the LibTorch model on the same batch.
  /// Per-cluster models only.
  std::vector<MatrixXcd> forward(const std::vector<const Cluster*>& clusters) const;
  /// Raw beamformers of whole networks, per network and cluster [L x K_c] (before scaling onto the
  /// budget): the float32 forward pass of a network-level model (ignn) on the same networks.
  std::vector<std::vector<MatrixXcd>> forward_networks(const std::vector<const Network*>& nets) const;
  /// True for a network-level model (forward_networks).
  bool network() const;

  struct Impl;

 private:
  explicit Model(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Every user's rate b log2(1 + SINR) under the beams W [L x K_n], as skyloop::rates gives it, in
/// split real arithmetic vectorised over the beams (no K_n x K_n temporary): equal to rates(c, W)
/// to rounding (the antenna sums run in another order). The ranked selection's input
/// (nn.selection = "ranked"), which orders the users by it.
VectorXd served_rates(const Cluster& c, const MatrixXcd& W);

}  // namespace skyloop::nn::fast
