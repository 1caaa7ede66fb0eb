#include "models.hpp"

#include "network_batch.hpp"
#include "skyloop/nn/learned.hpp"

#include <cmath>
#include <stdexcept>

namespace skyloop::nn {

torch::Tensor to_padded(const torch::Tensor& x, const Graph& g, double fill) {
  auto out = torch::full({g.clusters, g.kmax, x.size(1)}, fill, x.options());
  return out.index_put({g.seg, g.pos}, x);
}

torch::Tensor segment_mean(const torch::Tensor& x, const Graph& g) {
  return torch::zeros({g.clusters, x.size(1)}, x.options()).index_add(0, g.seg, x) / g.count;
}

torch::Tensor segment_max(const torch::Tensor& x, const Graph& g) {
  return std::get<0>(to_padded(x, g, -INFINITY).max(1));
}

torch::Tensor max_over_others(const torch::Tensor& x, const Graph& g) {
  if (g.kmax < 2) return torch::zeros_like(x);
  const auto top = to_padded(x, g, -INFINITY).topk(2, 1);
  const auto& values = std::get<0>(top);   // [C, 2, d]
  const auto& indices = std::get<1>(top);  // [C, 2, d]
  const auto first = values.select(1, 0).index_select(0, g.seg);
  const auto second = values.select(1, 1).index_select(0, g.seg);
  const auto is_max = indices.select(1, 0).index_select(0, g.seg).eq(g.pos.unsqueeze(1));
  const auto other = torch::where(is_max, second, first);
  return torch::where(torch::isinf(other), torch::zeros_like(other), other);
}

GraphNormImpl::GraphNormImpl(int64_t dim, double eps) : eps_(eps) {
  gamma_ = register_parameter("gamma", torch::ones({dim}));
  beta_ = register_parameter("beta", torch::zeros({dim}));
  alpha_ = register_parameter("alpha", torch::ones({dim}));
}

torch::Tensor GraphNormImpl::forward(const torch::Tensor& x, const Graph& g) {
  const auto centred = x - alpha_ * segment_mean(x, g).index_select(0, g.seg);
  const auto var = segment_mean(centred * centred, g).index_select(0, g.seg);
  return gamma_ * centred / torch::sqrt(var + eps_) + beta_;
}

MlpImpl::MlpImpl(int64_t in, int64_t hidden, int64_t out, Norm norm, bool final) : norm_(norm), final_(final) {
  l1_ = register_module("l1", torch::nn::Linear(in, hidden));
  l2_ = register_module("l2", torch::nn::Linear(hidden, out));
  if (norm == Norm::Graph) {
    g1_ = register_module("n1", GraphNorm(hidden));
    if (!final) g2_ = register_module("n2", GraphNorm(out));
  } else if (norm == Norm::Layer) {
    n1_ = register_module("n1", torch::nn::LayerNorm(torch::nn::LayerNormOptions({hidden})));
    if (!final) n2_ = register_module("n2", torch::nn::LayerNorm(torch::nn::LayerNormOptions({out})));
  }
}

torch::Tensor MlpImpl::forward(const torch::Tensor& x, const Graph& g) {
  auto norm = [&](const torch::Tensor& h, int which) {
    if (norm_ == Norm::Graph) return which == 1 ? g1_(h, g) : g2_(h, g);
    if (norm_ == Norm::Layer) return which == 1 ? n1_(h) : n2_(h);
    return h;
  };
  auto h = torch::relu(norm(l1_(x), 1));
  h = l2_(h);
  return final_ ? h : torch::relu(norm(h, 2));
}

torch::Tensor encode_features(const torch::Tensor& x, Features f) {
  if (f == Features::Linear) return x;
  const auto r = x.norm(2, -1, true);
  const double unit = std::log1p(1.0 / kLogFeatureFloor);
  return x * (torch::log1p(r / kLogFeatureFloor) / (unit * torch::clamp_min(r, 1e-30)));
}

int64_t head_width(Readout r, int64_t antennas) { return r == Readout::Direct ? 2 * antennas : 2; }

torch::Tensor structured_beams(const torch::Tensor& head, const torch::Tensor& x, const Graph& g) {
  const int64_t L = x.size(1) / 2;
  const auto dbl = x.to(torch::kFloat64);
  const auto hr = to_padded(dbl.narrow(1, 0, L), g, 0.0), hi = to_padded(dbl.narrow(1, L, L), g, 0.0);  // [C, K, L]
  const auto lambda = to_padded(torch::exp(head.select(1, 0).clamp(-30, 30)).to(torch::kFloat64).unsqueeze(1), g, 0.0);
  const auto lr = hr * lambda, li = hi * lambda;                                  // lambda_k h_k (padded: 0)
  const auto eye = torch::eye(L, dbl.options()).expand({g.clusters, L, L});
  // A = I + sum_k lambda_k h_k h_k^H = Ar + j Ai; its real form [[Ar, -Ai], [Ai, Ar]] is SPD.
  const auto ar = eye + torch::bmm(lr.transpose(1, 2), hr) + torch::bmm(li.transpose(1, 2), hi);
  const auto ai = torch::bmm(li.transpose(1, 2), hr) - torch::bmm(lr.transpose(1, 2), hi);
  const auto R = torch::cat({torch::cat({ar, -ai}, 2), torch::cat({ai, ar}, 2)}, 1);    // [C, 2L, 2L]
  const auto rhs = torch::cat({hr.transpose(1, 2), hi.transpose(1, 2)}, 1);            // [C, 2L, K]
  const auto v = torch::linalg::solve(R, rhs, /*left=*/true).transpose(1, 2).index({g.seg, g.pos});   // [U, 2L]
  const auto dir = v / (v.norm(2, 1, true) + 1e-30);
  // Power shares: softmax of the second head output over each cluster's users.
  const auto logit = head.select(1, 1).unsqueeze(1);
  const auto e = torch::exp(logit - segment_max(logit, g).index_select(0, g.seg));
  const auto share = e / torch::zeros({g.clusters, 1}, e.options()).index_add(0, g.seg, e).index_select(0, g.seg);
  return (dir * torch::sqrt(share.to(torch::kFloat64))).to(x.scalar_type());
}

GnnImpl::GnnImpl(int64_t antennas, int64_t hidden, int64_t layers, Readout readout) : BeamNetImpl(readout) {
  const int64_t d = hidden;
  user_enc_ = register_module("user_enc", Mlp(2 * antennas, d, d, Norm::Graph));
  uav_enc_ = register_module("uav_enc", Mlp(d, d, d, Norm::Layer));
  for (int64_t l = 0; l < layers; ++l) {
    user_msg_->push_back(Mlp(d, d, d, Norm::Graph));
    uav_msg_->push_back(Mlp(d, d, d, Norm::Layer));
    user_upd_->push_back(Mlp(3 * d, d, d, Norm::Graph));
    uav_upd_->push_back(Mlp(2 * d, d, d, Norm::Layer));
  }
  register_module("user_msg", user_msg_);
  register_module("uav_msg", uav_msg_);
  register_module("user_upd", user_upd_);
  register_module("uav_upd", uav_upd_);
  out_ = register_module("out", Mlp(d, d, head_width(readout, antennas), Norm::Graph, /*final=*/true));
}

torch::Tensor GnnImpl::head(const torch::Tensor& x, const Graph& g) {
  auto u = user_enc_(x, g);                    // u_k^(0)            [U, d]
  auto a = uav_enc_(segment_mean(u, g), g);    // a_n^(0)            [C, d]
  for (std::size_t l = 0; l < user_msg_->size(); ++l) {
    const auto mu = user_msg_[l]->as<Mlp>()->forward(u, g);  // m_{u_k}     [U, d]
    const auto ma = uav_msg_[l]->as<Mlp>()->forward(a, g);   // m_{a_n}     [C, d]
    const auto user_in = torch::cat({u, ma.index_select(0, g.seg), max_over_others(mu, g)}, 1);
    const auto uav_in = torch::cat({a, segment_mean(mu, g)}, 1);
    u = user_upd_[l]->as<Mlp>()->forward(user_in, g);
    a = uav_upd_[l]->as<Mlp>()->forward(uav_in, g);
  }
  return out_(u, g);                            // w~_k              [U, 2L]
}

DeepSetsImpl::DeepSetsImpl(int64_t antennas, int64_t hidden, Readout readout) : BeamNetImpl(readout) {
  const int64_t w = 2 * hidden;
  phi1_ = register_module("phi1", Mlp(2 * antennas, w, w, Norm::None));
  phi2_ = register_module("phi2", Mlp(w, w, w, Norm::None));
  head1_ = register_module("head1", Mlp(2 * w, w, w, Norm::None));
  head2_ = register_module("head2", Mlp(w, w, head_width(readout, antennas), Norm::None, /*final=*/true));
}

torch::Tensor DeepSetsImpl::head(const torch::Tensor& x, const Graph& g) {
  const auto phi = phi2_(phi1_(x, g), g);
  const auto pooled = segment_max(phi, g).index_select(0, g.seg);
  return head2_(head1_(torch::cat({phi, pooled}, 1), g), g);
}

MsPointNetImpl::MsPointNetImpl(int64_t antennas, int64_t hidden, Readout readout)
    : BeamNetImpl(readout), antennas_(antennas) {
  const int64_t c = hidden / 2, w = 2 * hidden;
  c1_ = register_module("conv1", torch::nn::Conv1d(torch::nn::Conv1dOptions(2, c, 1)));
  c3_ = register_module("conv3", torch::nn::Conv1d(torch::nn::Conv1dOptions(2, c, 3).padding(1)));
  c5_ = register_module("conv5", torch::nn::Conv1d(torch::nn::Conv1dOptions(2, c, 5).padding(2)));
  mix_ = register_module("mix", torch::nn::Conv1d(torch::nn::Conv1dOptions(3 * c, 3 * c, 1)));
  proj_ = register_module("proj", torch::nn::Linear(3 * c * antennas, w));
  head1_ = register_module("head1", Mlp(2 * w, w, w, Norm::None));
  head2_ = register_module("head2", Mlp(w, w, head_width(readout, antennas), Norm::None, /*final=*/true));
}

torch::Tensor MsPointNetImpl::head(const torch::Tensor& x, const Graph& g) {
  const auto s = x.view({x.size(0), 2, antennas_});  // channels Re, Im over the antenna axis
  auto h = torch::relu(torch::cat({c1_(s), c3_(s), c5_(s)}, 1));
  h = torch::relu(mix_(h));
  const auto f = torch::relu(proj_(h.flatten(1)));
  const auto pooled = segment_max(f, g).index_select(0, g.seg);
  return head2_(head1_(torch::cat({f, pooled}, 1), g), g);
}

torch::Tensor BeamNetImpl::forward_network(const NetBatch&) {
  throw std::logic_error("forward_network called on a per-cluster model");
}

namespace {

const Graph kNoGraph;  // Layer-norm blocks do not read the graph

/// For each user slot, max over the other real users of its cluster: x [B, C, K, d], mask [B, C, K].
/// Zeros for a single-user cluster (the max over an empty set), as max_over_others.
torch::Tensor dense_max_over_others(const torch::Tensor& x, const torch::Tensor& mask) {
  const auto K = x.size(2);
  if (K < 2) return torch::zeros_like(x);
  const auto filled = torch::where(mask.unsqueeze(-1) > 0, x, torch::full({}, -INFINITY, x.options()));
  const auto top = filled.topk(2, 2);
  const auto& values = std::get<0>(top);   // [B, C, 2, d]
  const auto& indices = std::get<1>(top);  // [B, C, 2, d]
  const auto pos = torch::arange(K, indices.options()).view({1, 1, K, 1});
  const auto is_max = indices.narrow(2, 0, 1).eq(pos);                           // [B, C, K, d]
  const auto other = torch::where(is_max, values.narrow(2, 1, 1), values.narrow(2, 0, 1));
  return torch::where(torch::isinf(other), torch::zeros_like(other), other) * mask.unsqueeze(-1);
}

}  // namespace

IgnnImpl::IgnnImpl(int64_t antennas, int64_t hidden, int64_t layers, Readout readout)
    : BeamNetImpl(readout), antennas_(antennas) {
  const int64_t d = hidden;
  user_enc_ = register_module("user_enc", Mlp(2 * antennas, d, d, Norm::Layer));
  edge_enc_ = register_module("edge_enc", Mlp(2 * antennas, d, d, Norm::Layer));
  uav_enc_ = register_module("uav_enc", Mlp(d, d, d, Norm::Layer));
  for (int64_t l = 0; l < layers; ++l) {
    user_msg_->push_back(Mlp(d, d, d, Norm::Layer));
    uav_msg_->push_back(Mlp(d, d, d, Norm::Layer));
    int_msg_->push_back(Mlp(2 * d, d, d, Norm::Layer));
    leak_msg_->push_back(Mlp(2 * d, d, d, Norm::Layer));
    user_upd_->push_back(Mlp(4 * d, d, d, Norm::Layer));
    uav_upd_->push_back(Mlp(3 * d, d, d, Norm::Layer));
  }
  register_module("user_msg", user_msg_);
  register_module("uav_msg", uav_msg_);
  register_module("int_msg", int_msg_);
  register_module("leak_msg", leak_msg_);
  register_module("user_upd", user_upd_);
  register_module("uav_upd", uav_upd_);
  out_ = register_module("out", Mlp(d, d, head_width(readout, antennas), Norm::Layer, /*final=*/true));
}

torch::Tensor IgnnImpl::head(const torch::Tensor&, const Graph&) {
  throw std::logic_error("the interference-aware GNN takes networks (forward_network), not clusters");
}

torch::Tensor IgnnImpl::forward_network(const NetBatch& b) {
  const auto& x = b.x;                                  // [B, C, C, K, 2L]
  const int64_t B = x.size(0), C = x.size(1), K = x.size(3), L2 = x.size(4);
  const auto um = b.umask.unsqueeze(-1);                // [B, C, K, 1]
  const auto own = x.diagonal(0, 1, 2).permute({0, 3, 1, 2});  // [B, C, K, 2L]: h from the serving UAV
  // Interference edges (tx != rx, both real): [B, C_tx, C_rx, K].
  const auto off_diag = 1 - torch::eye(C, x.options()).view({1, C, C, 1});
  const auto emask = b.cmask.view({B, C, 1, 1}) * b.umask.view({B, 1, C, K}) * off_diag;
  // Users and edges are computed as lists of the real ones only: a padded batch holds C x K user
  // slots and C x C x K edge slots per network, of which the served users, and those times
  // (C - 1), are real (on the paper's 3-UAV networks about half and a third). Every row's
  // arithmetic is its own (the layer norms are per row), so the lists compute what the padded
  // slots did, and sums over a list add the same terms in the same order as the padded sums,
  // whose masked terms were zeros. Layout: user r = flat slot (b, c, k), ascending; edge e = flat
  // slot (b, tx, rx, k), ascending, from cluster slot b C + tx to user slot (b C + rx) K + k.
  // The clusters stay padded ([B C] rows, almost all real).
  const auto users = b.umask.reshape({-1}).nonzero().squeeze(1);  // [U] user slots
  const auto user_cl = users.div(K, "floor");                     // [U] cluster slot b C + c
  const auto edges = emask.reshape({-1}).nonzero().squeeze(1);    // [E]
  const auto k_of = edges.remainder(K), rest = edges.div(K, "floor");
  const auto rx_of = rest.remainder(C), tx_slot = rest.div(C, "floor");  // tx_slot = b C + tx
  const auto rx_slot = (tx_slot.div(C, "floor") * C + rx_of) * K + k_of;
  const int64_t slots = B * C * K;
  // Rows [U, .] back to padded slots [B, C, K, .] (zero where no user) and per-cluster means.
  auto padded = [&](const torch::Tensor& rows) {
    return torch::zeros({slots, rows.size(1)}, rows.options()).index_copy(0, users, rows).view({B, C, K, rows.size(1)});
  };
  const auto per_cluster = torch::clamp_min(b.umask.sum(2).reshape({B * C, 1}), 1.0);
  auto cluster_mean = [&](const torch::Tensor& rows) {
    return torch::zeros({B * C, rows.size(1)}, rows.options()).index_add(0, user_cl, rows) / per_cluster;
  };
  const auto e = edge_enc_(encode_features(x.reshape({-1, L2}).index_select(0, edges), features()), kNoGraph);  // [E, d]
  auto u = user_enc_(encode_features(own.reshape({-1, L2}).index_select(0, users), features()), kNoGraph);  // u_k [U, d]
  const auto cm_rows = b.cmask.reshape({B * C, 1});  // 1 for a real cluster slot
  auto a = uav_enc_(cluster_mean(u), kNoGraph) * cm_rows;  // a_n [B C, d]
  const auto to_user = torch::clamp_min(emask.sum(1), 1.0).reshape({slots, 1}).index_select(0, users);  // [U, 1]
  const auto to_uav = torch::clamp_min(emask.sum({2, 3}), 1.0).reshape({B * C, 1});                   // [B C, 1]
  for (std::size_t l = 0; l < user_msg_->size(); ++l) {
    const auto mu = user_msg_[l]->as<Mlp>()->forward(u, kNoGraph);                          // m_{u_k}  [U, d]
    const auto ma = uav_msg_[l]->as<Mlp>()->forward(a, kNoGraph) * cm_rows;  // m_{a_n}  [B C, d]
    const int64_t d = mu.size(-1);
    const auto mu_slots = padded(mu);  // [B, C, K, d]
    const auto heard_e = int_msg_[l]->as<Mlp>()->forward(torch::cat({ma.index_select(0, tx_slot), e}, -1), kNoGraph);
    const auto leaked_e = leak_msg_[l]->as<Mlp>()->forward(torch::cat({mu_slots.reshape({slots, d}).index_select(0, rx_slot), e}, -1), kNoGraph);
    const auto heard = torch::zeros({slots, d}, mu.options()).index_add(0, rx_slot, heard_e).index_select(0, users) / to_user;
    const auto leaked = torch::zeros({B * C, d}, mu.options()).index_add(0, tx_slot, leaked_e) / to_uav;
    const auto others = dense_max_over_others(mu_slots, b.umask).reshape({slots, d}).index_select(0, users);
    const auto user_in = torch::cat({u, ma.index_select(0, user_cl), others, heard}, -1);
    const auto uav_in = torch::cat({a, cluster_mean(mu), leaked}, -1);
    u = user_upd_[l]->as<Mlp>()->forward(user_in, kNoGraph);
    a = uav_upd_[l]->as<Mlp>()->forward(uav_in, kNoGraph) * cm_rows;
  }
  const auto h = padded(out_(u, kNoGraph));             // [B, C, K, head]
  if (readout() == Readout::Direct) return h * um;
  // Structured: w_{n,k} ~ (I + sum_j lambda_j h_{n,j} h_{n,j}^H)^{-1} h_{n,k}, over every served j.
  const int64_t L = antennas_;
  const auto xd = x.to(torch::kFloat64);
  const auto lambda = torch::exp(h.select(-1, 0).clamp(-30, 30)).to(torch::kFloat64) * b.umask.to(torch::kFloat64);
  const auto hr = xd.narrow(-1, 0, L).reshape({B * C, C * K, L});  // per tx: every (rx, k)
  const auto hi = xd.narrow(-1, L, L).reshape({B * C, C * K, L});
  const auto lam = lambda.view({B, 1, C * K}).expand({B, C, C * K}).reshape({B * C, C * K, 1});
  const auto lr = hr * lam, li = hi * lam;
  const auto eye = torch::eye(L, xd.options()).expand({B * C, L, L});
  const auto ar = eye + torch::bmm(lr.transpose(1, 2), hr) + torch::bmm(li.transpose(1, 2), hi);
  const auto ai = torch::bmm(li.transpose(1, 2), hr) - torch::bmm(lr.transpose(1, 2), hi);
  const auto R = torch::cat({torch::cat({ar, -ai}, 2), torch::cat({ai, ar}, 2)}, 1);  // [B C, 2L, 2L]
  const auto od = own.to(torch::kFloat64).reshape({B * C, K, 2 * L});
  const auto rhs = torch::cat({od.narrow(2, 0, L).transpose(1, 2), od.narrow(2, L, L).transpose(1, 2)}, 1);  // [B C, 2L, K]
  const auto v = torch::linalg::solve(R, rhs, /*left=*/true).transpose(1, 2).reshape({B, C, K, 2 * L});
  // Written so that every gradient stays finite at the padded slots: an empty UAV slot has v = 0
  // (norm via sqrt(. + tiny), not norm(), whose gradient at 0 is NaN), and a padded user has
  // share 0 (amplitude exp(log_softmax / 2), not sqrt(share), whose gradient at 0 is infinite).
  const auto dir = v * torch::rsqrt((v * v).sum(-1, true) + 1e-30);
  const auto logit = torch::where(b.umask > 0, h.select(-1, 1), torch::full({}, -1e9, h.options()));
  const auto amplitude = torch::exp(0.5 * torch::log_softmax(logit.to(torch::kFloat64), 2));  // sqrt(power share)
  return (dir * amplitude.unsqueeze(-1)).to(x.scalar_type()) * um;
}

std::shared_ptr<BeamNetImpl> make_model(const std::string& name, int64_t antennas, int64_t hidden, int64_t layers,
                                        Readout readout) {
  if (name == "gnn") return std::make_shared<GnnImpl>(antennas, hidden, layers, readout);
  if (name == "deepsets") return std::make_shared<DeepSetsImpl>(antennas, hidden, readout);
  if (name == "mspointnet") return std::make_shared<MsPointNetImpl>(antennas, hidden, readout);
  if (name == "ignn") return std::make_shared<IgnnImpl>(antennas, hidden, layers, readout);
  throw std::invalid_argument("nn.model = \"" + name + "\" is not allowed: allowed one of gnn, deepsets, mspointnet, ignn");
}

}  // namespace skyloop::nn
