#include "models.hpp"

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

Readout parse_readout(const std::string& s) {
  if (s == "direct") return Readout::Direct;
  if (s == "structured") return Readout::Structured;
  throw std::invalid_argument("nn.readout = \"" + s + "\" is not allowed: allowed one of direct, structured");
}

std::string to_string(Readout r) { return r == Readout::Direct ? "direct" : "structured"; }

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

std::shared_ptr<BeamNetImpl> make_model(const std::string& name, int64_t antennas, int64_t hidden, int64_t layers,
                                        Readout readout) {
  if (name == "gnn") return std::make_shared<GnnImpl>(antennas, hidden, layers, readout);
  if (name == "deepsets") return std::make_shared<DeepSetsImpl>(antennas, hidden, readout);
  if (name == "mspointnet") return std::make_shared<MsPointNetImpl>(antennas, hidden, readout);
  throw std::invalid_argument("nn.model = \"" + name + "\" is not allowed: allowed one of gnn, deepsets, mspointnet");
}

}  // namespace skyloop::nn
