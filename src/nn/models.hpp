#pragma once
// The learned beamformers as torch modules. Every model maps a batch of clusters, flattened to
// user rows, to raw beamforming vectors [U, 2L] (Re then Im); power scaling and rates are applied
// outside (batch.hpp), so all three share training and serving.
//
// Shapes: U users in the batch, C clusters, d hidden size, L antennas.
//   x    [U, 2L]  float  user features [Re h_k, Im h_k] * feature_scale   (eq:node_feature)
//   seg  [U]      int64  cluster of each user row; pos [U] its index inside the cluster
//   count[C, 1]   float  users per cluster K_n
#include <memory>
#include <string>

#include "skyloop/core/choices.hpp"
#include "torch_fwd.hpp"

namespace skyloop::nn {

struct NetBatch;  // network_batch.hpp

struct Graph {
  torch::Tensor seg, pos, count;
  int64_t clusters = 0, kmax = 0;
};

/// [U, d] -> [C, Kmax, d], empty slots filled with `fill`; differentiable in x.
torch::Tensor to_padded(const torch::Tensor& x, const Graph& g, double fill);
/// Per-cluster mean of user rows: [U, d] -> [C, d].
torch::Tensor segment_mean(const torch::Tensor& x, const Graph& g);
/// Per-cluster max of user rows: [U, d] -> [C, d].
torch::Tensor segment_max(const torch::Tensor& x, const Graph& g);
/// For each user k, max over the other users j != k of its cluster; zeros for a single-user
/// cluster (the max over an empty set). [U, d] -> [U, d].
torch::Tensor max_over_others(const torch::Tensor& x, const Graph& g);

/// GraphNorm (Cai et al. 2021) over the user nodes of each graph instance (cluster):
/// GN(h) = gamma * (h - alpha * mu) / sqrt(var + eps) + beta, mu and var over the cluster's users,
/// var of the shifted values; gamma, beta, alpha learnable (init 1, 0, 1).
class GraphNormImpl : public torch::nn::Module {
 public:
  explicit GraphNormImpl(int64_t dim, double eps = 1e-5);
  torch::Tensor forward(const torch::Tensor& x, const Graph& g);

 private:
  torch::Tensor gamma_, beta_, alpha_;
  double eps_;
};
TORCH_MODULE(GraphNorm);

/// Normalisation inside an MLP block.
enum class Norm { Graph, Layer, None };

/// Two-layer MLP block: Linear(in, hidden) -> norm -> ReLU -> Linear(hidden, out) [-> norm -> ReLU
/// unless `final`]. Graph norm for user-node blocks; Layer norm for the UAV node (GraphNorm over
/// the one UAV node of a graph instance is degenerate: its centred value is zero).
class MlpImpl : public torch::nn::Module {
 public:
  MlpImpl(int64_t in, int64_t hidden, int64_t out, Norm norm, bool final = false);
  torch::Tensor forward(const torch::Tensor& x, const Graph& g);

 private:
  torch::nn::Linear l1_{nullptr}, l2_{nullptr};
  GraphNorm g1_{nullptr}, g2_{nullptr};
  torch::nn::LayerNorm n1_{nullptr}, n2_{nullptr};
  Norm norm_;
  bool final_;
};
TORCH_MODULE(Mlp);

/// How a network's per-user head becomes a beamforming vector.
///  Direct (the paper): the head emits 2L reals, w~_k = Re + j Im.
///  Structured (beyond the paper): the head emits 2 reals per user, a regularisation weight
///    lambda_k = exp(.) and a power logit; w_k = sqrt(p_k) v_k / ||v_k|| with
///    v_k = (I + sum_j lambda_j h~_j h~_j^H)^{-1} h~_k (h~ the normalised channels) and
///    p = softmax over the cluster's users. This is the known structure of the sum-rate-optimal
///    beamformer (it spans MRT, RZF and ZF, and switches users off with p_k -> 0), so the network
///    only has to choose 2 numbers per user. Solved in double precision.
// Readout: the enum of nn.readout (skyloop/core/choices.hpp).
/// Head outputs per user: 2L (direct) or 2 (structured).
int64_t head_width(Readout r, int64_t antennas);
/// Structured readout: head [U, 2], x [U, 2L] -> beamformers [U, 2L] with sum_k ||w_k||^2 = 1.
torch::Tensor structured_beams(const torch::Tensor& head, const torch::Tensor& x, const Graph& g);

/// What the encoders see of each channel vector x (last dimension, [Re h, Im h] * feature_scale).
///  Linear (the paper, eq:node_feature): x itself.
///  Log (beyond the paper): the direction of x with its norm r compressed,
///    x * log(1 + r / eps) / (r log(1 + 1 / eps)), eps = kLogFeatureFloor (learned.hpp): a user 60 dB below the
///    set's RMS still moves the input by O(1), where under the 3GPP and Al-Hourani channels the
///    linear features of far or shadowed users are ~1e-3 of the near ones'. Zero stays zero.
/// Readouts that use the channel (structured) always read the linear x.
// Features: the enum of nn.features (skyloop/core/choices.hpp).
/// x [..., 2L] -> the encoders' input of the same shape.
torch::Tensor encode_features(const torch::Tensor& x, Features f);

/// Common interface of the three networks.
class BeamNetImpl : public torch::nn::Module {
 public:
  explicit BeamNetImpl(Readout r) : readout_(r) {}
  /// Raw beamformers [U, 2L] (before scaling onto the budget).
  torch::Tensor forward(const torch::Tensor& x, const Graph& g) {
    const auto h = head(features_ == Features::Linear ? x : encode_features(x, features_), g);
    return readout_ == Readout::Structured ? structured_beams(h, x, g) : h;
  }
  Readout readout() const { return readout_; }
  Features features() const { return features_; }
  void set_features(Features f) { features_ = f; }
  /// True for a network-level model (forward_network: all clusters of a snapshot at once).
  virtual bool network() const { return false; }
  /// Raw beams [B, C, K, 2L] of a batch of networks (network models only).
  virtual torch::Tensor forward_network(const NetBatch& b);

 protected:
  /// Per-user head outputs [U, head_width].
  virtual torch::Tensor head(const torch::Tensor& x, const Graph& g) = 0;

 private:
  Readout readout_;
  Features features_ = Features::Linear;
};

/// The paper's GNN (Section IV): user encoder, UAV encoder on the mean user embedding, L_g
/// message-passing layers (user: concat(UAV message, max over the other users' messages); UAV:
/// mean of the user messages; updaters on concat(own, aggregated)), readout to 2L reals.
class GnnImpl : public BeamNetImpl {
 public:
  GnnImpl(int64_t antennas, int64_t hidden, int64_t layers, Readout readout = Readout::Direct);

 protected:
  torch::Tensor head(const torch::Tensor& x, const Graph& g) override;

 private:
  Mlp user_enc_{nullptr}, uav_enc_{nullptr}, out_{nullptr};
  torch::nn::ModuleList user_msg_, uav_msg_, user_upd_, uav_upd_;
};

/// DeepSets: per-user encoder phi, global max-pool over the cluster, per-user head on
/// [phi_k, pooled]. No normalisation (a plain set network), width 2 * hidden.
class DeepSetsImpl : public BeamNetImpl {
 public:
  DeepSetsImpl(int64_t antennas, int64_t hidden, Readout readout = Readout::Direct);

 protected:
  torch::Tensor head(const torch::Tensor& x, const Graph& g) override;

 private:
  Mlp phi1_{nullptr}, phi2_{nullptr}, head1_{nullptr}, head2_{nullptr};
};

/// MS-PointNet: per user, parallel 1-D convolutions with kernel sizes 1, 3 and 5 over the antenna
/// axis (channels Re, Im), concatenated, a 1x1 convolution and a linear projection to the user
/// feature; global max-pool over the cluster; per-user head on [feature_k, pooled]. Convolving
/// over antennas rather than over the (unordered) users keeps the network permutation
/// equivariant, as the paper requires.
class MsPointNetImpl : public BeamNetImpl {
 public:
  MsPointNetImpl(int64_t antennas, int64_t hidden, Readout readout = Readout::Direct);

 protected:
  torch::Tensor head(const torch::Tensor& x, const Graph& g) override;

 private:
  int64_t antennas_;
  torch::nn::Conv1d c1_{nullptr}, c3_{nullptr}, c5_{nullptr}, mix_{nullptr};
  torch::nn::Linear proj_{nullptr};
  Mlp head1_{nullptr}, head2_{nullptr};
};

/// The interference-aware GNN (beyond the paper, its future work): the paper's heterogeneous
/// graph over a whole network, with an interference edge from every UAV to every user of another
/// cluster carrying the cross channel h_{m,k}. Per layer, with e_{m,k} = enc(h_{m,k}):
///   user k of UAV n:  u_k <- upd_u([u_k, m_{a_n}, max_{j != k in n} m_{u_j},
///                                   mean_{m != n} phi([m_{a_m}, e_{m,k}])])
///   UAV n:            a_n <- upd_a([a_n, mean_{k in n} m_{u_k}, mean_{k not in n} psi([m_{u_k}, e_{n,k}])])
/// so a user hears who interferes with it and a UAV hears whom it interferes with. Every block is
/// an MLP with LayerNorm (per node; a cluster of one or two users makes GraphNorm degenerate).
/// Readouts: direct (2L reals per user, scaled per UAV onto its budget) or structured: the network
/// WMMSE fixed point's form w_{n,k} ~ (I + sum_{every served j} lambda_j h_{n,j} h_{n,j}^H)^{-1}
/// h_{n,k}, with lambda_j and a power share (softmax over the UAV's users) per user. Equivariant
/// to permutations of the users of a cluster and of the UAVs.
class IgnnImpl : public BeamNetImpl {
 public:
  IgnnImpl(int64_t antennas, int64_t hidden, int64_t layers, Readout readout = Readout::Direct);
  bool network() const override { return true; }
  torch::Tensor forward_network(const NetBatch& b) override;

 protected:
  torch::Tensor head(const torch::Tensor& x, const Graph& g) override;

 private:
  int64_t antennas_;
  Mlp user_enc_{nullptr}, edge_enc_{nullptr}, uav_enc_{nullptr}, out_{nullptr};
  torch::nn::ModuleList user_msg_, uav_msg_, int_msg_, leak_msg_, user_upd_, uav_upd_;
};

/// Builds a model by name ("gnn", "deepsets", "mspointnet", "ignn"); throws std::invalid_argument.
std::shared_ptr<BeamNetImpl> make_model(const std::string& name, int64_t antennas, int64_t hidden, int64_t layers,
                                        Readout readout = Readout::Direct);

/// The device `nn.device` names ("cpu" or "cuda"); "cuda" without a visible GPU (or in a LibTorch
/// without CUDA) throws InputError. Read by the beamformers' training and serving and the learners.
torch::Device resolve_device(ComputeDevice device);

}  // namespace skyloop::nn
