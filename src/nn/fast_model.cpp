#include "fast_model.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <complex>
#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <stdexcept>

#include "fast_gemm.hpp"

namespace skyloop::nn::fast {

namespace {

// The element-wise passes (norms, pooling, ReLU) in SSE2, AVX2 and AVX-512 variants chosen by the
// loader. They are vertical operations (no reassociation, no contraction: this file is compiled
// with -ffp-contract=off), so every variant gives the same bits.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SKYLOOP_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define SKYLOOP_CLONES
#endif

/// Row-major float activations; columns padded to the kernel's width.
struct Mat {
  int rows = 0, cols = 0, ld = 0;
  std::vector<float> v;
  void resize(int r, int c) {
    rows = r, cols = c, ld = pad_cols(c);
    const std::size_t need = static_cast<std::size_t>(r) * static_cast<std::size_t>(ld);
    if (v.size() < need) v.resize(need, 0.0f);
  }
  float* row(int r) { return v.data() + static_cast<std::size_t>(r) * static_cast<std::size_t>(ld); }
  const float* row(int r) const { return v.data() + static_cast<std::size_t>(r) * static_cast<std::size_t>(ld); }
};

/// Which rows belong to which graph instance (cluster): users start[c] .. start[c + 1] - 1.
struct Segments {
  std::vector<int> start;  // [C + 1]
  std::vector<int> seg;    // [U] cluster of each user row
  int clusters() const { return static_cast<int>(start.size()) - 1; }
  int users() const { return start.back(); }
};

enum class NormKind { None, Graph, Layer };

struct Norm {
  NormKind kind = NormKind::None;
  std::vector<float> gamma, beta, alpha;  // alpha: GraphNorm's mean shift
  float eps = 1e-5f;
};

SKYLOOP_CLONES void relu(Mat& m) {
  for (int r = 0; r < m.rows; ++r) {
    float* __restrict x = m.row(r);
    for (int c = 0; c < m.cols; ++c) x[c] = std::max(x[c], 0.0f);
  }
}

/// LayerNorm over each row's columns (biased variance), as torch::nn::LayerNorm, then the ReLU
/// that follows it in every block, in the last pass's store. The row sums run over 8 interleaved
/// partial sums (vectorisable without reassociating across the lanes' own order), folded in lane
/// order. R rows at a time, each row's arithmetic as alone: the rows' short dependent chains (the
/// folds, the square root and the division) overlap instead of waiting on one another (the
/// interference-aware GNN's exact optimum spent a sixth of its time here one row at a time).
typedef float v8 __attribute__((vector_size(8 * sizeof(float)), aligned(sizeof(float))));

template <int R>
__attribute__((always_inline)) inline void layer_norm_relu_rows(Mat& m, int r0, const float* __restrict gamma,
                                                                const float* __restrict beta, float eps) {
  const int d = m.cols;
  float* x[R];
  for (int r = 0; r < R; ++r) x[r] = m.row(r0 + r);
  // Lane i of part[r] sums row r's columns i, i + 8, ... in order; the lanes fold in order.
  auto fold = [](v8 p) {
    float t = 0.0f;
    for (int i = 0; i < 8; ++i) t += p[i];
    return t;
  };
  v8 part[R];
  for (int r = 0; r < R; ++r) part[r] = v8{};
  int c = 0;
  for (; c + 8 <= d; c += 8)
    for (int r = 0; r < R; ++r) part[r] += *reinterpret_cast<const v8*>(x[r] + c);
  float mean[R], inv[R];
  for (int r = 0; r < R; ++r) {
    mean[r] = fold(part[r]);
    for (int k = c; k < d; ++k) mean[r] += x[r][k];
    mean[r] /= static_cast<float>(d);
    part[r] = v8{};
  }
  c = 0;
  for (; c + 8 <= d; c += 8)
    for (int r = 0; r < R; ++r) {
      const v8 t = *reinterpret_cast<const v8*>(x[r] + c) - mean[r];
      part[r] += t * t;
    }
  for (int r = 0; r < R; ++r) {
    float var = fold(part[r]);
    for (int k = c; k < d; ++k) var += (x[r][k] - mean[r]) * (x[r][k] - mean[r]);
    inv[r] = 1.0f / std::sqrt(var / static_cast<float>(d) + eps);
  }
  for (int r = 0; r < R; ++r)
    for (c = 0; c < d; ++c) x[r][c] = std::max((x[r][c] - mean[r]) * inv[r] * gamma[c] + beta[c], 0.0f);
}

SKYLOOP_CLONES void layer_norm_relu(Mat& m, const Norm& n) {
  const float* gamma = n.gamma.data();
  const float* beta = n.beta.data();
  int r = 0;
  for (; r + 4 <= m.rows; r += 4) layer_norm_relu_rows<4>(m, r, gamma, beta, n.eps);
  for (; r < m.rows; ++r) layer_norm_relu_rows<1>(m, r, gamma, beta, n.eps);
}

/// GraphNorm over each cluster's user rows, as GraphNormImpl (models.cpp), then the ReLU that
/// follows it in every block. Two passes read a cluster's rows (mean, then variance) and one writes them:
/// x - mean is recomputed in the last, the same float as a stored one (no contraction here).
SKYLOOP_CLONES void graph_norm_relu(Mat& m, const Norm& n, const Segments& s, std::vector<float>& tmp) {
  const int d = m.cols;
  tmp.assign(static_cast<std::size_t>(2 * d), 0.0f);
  float* __restrict mean = tmp.data();
  float* __restrict var = tmp.data() + d;
  const float* __restrict gamma = n.gamma.data();
  const float* __restrict beta = n.beta.data();
  const float* __restrict alpha = n.alpha.data();
  for (int c = 0; c < s.clusters(); ++c) {
    const int a = s.start[static_cast<std::size_t>(c)], b = s.start[static_cast<std::size_t>(c) + 1];
    const float inv_k = 1.0f / static_cast<float>(b - a);
    std::fill(mean, mean + 2 * d, 0.0f);
    for (int r = a; r < b; ++r) {
      const float* __restrict x = m.row(r);
      for (int j = 0; j < d; ++j) mean[j] += x[j];
    }
    for (int j = 0; j < d; ++j) mean[j] = alpha[j] * (mean[j] * inv_k);
    for (int r = a; r < b; ++r) {
      const float* __restrict x = m.row(r);
      for (int j = 0; j < d; ++j) {
        const float t = x[j] - mean[j];
        var[j] += t * t;
      }
    }
    for (int j = 0; j < d; ++j) var[j] = gamma[j] / std::sqrt(var[j] * inv_k + n.eps);
    for (int r = a; r < b; ++r) {
      float* __restrict x = m.row(r);
      for (int j = 0; j < d; ++j) x[j] = std::max((x[j] - mean[j]) * var[j] + beta[j], 0.0f);
    }
  }
}

/// Per-cluster mean of user rows into a [C x d] matrix.
SKYLOOP_CLONES void segment_mean(const Mat& x, const Segments& s, Mat& out) {
  out.resize(s.clusters(), x.cols);
  for (int c = 0; c < s.clusters(); ++c) {
    float* __restrict o = out.row(c);
    std::fill(o, o + x.cols, 0.0f);
    const int a = s.start[static_cast<std::size_t>(c)], b = s.start[static_cast<std::size_t>(c) + 1];
    for (int r = a; r < b; ++r) {
      const float* __restrict v = x.row(r);
      for (int j = 0; j < x.cols; ++j) o[j] += v[j];
    }
    const float inv_k = 1.0f / static_cast<float>(b - a);
    for (int j = 0; j < x.cols; ++j) o[j] *= inv_k;
  }
}

/// Per-cluster max of user rows into a [C x d] matrix.
SKYLOOP_CLONES void segment_max(const Mat& x, const Segments& s, Mat& out) {
  out.resize(s.clusters(), x.cols);
  for (int c = 0; c < s.clusters(); ++c) {
    float* __restrict o = out.row(c);
    std::fill(o, o + x.cols, -std::numeric_limits<float>::infinity());
    for (int r = s.start[static_cast<std::size_t>(c)]; r < s.start[static_cast<std::size_t>(c) + 1]; ++r) {
      const float* __restrict v = x.row(r);
      for (int j = 0; j < x.cols; ++j) o[j] = std::max(o[j], v[j]);
    }
  }
}

/// For each user, the max over the other users of its cluster (a suffix max, then a running
/// prefix max: O(K d), branch-free); zeros for a single-user cluster.
SKYLOOP_CLONES void max_over_others(const Mat& x, const Segments& s, Mat& out, std::vector<float>& tmp) {
  const int d = x.cols;
  out.resize(x.rows, d);
  tmp.resize(static_cast<std::size_t>(d));
  float* __restrict prefix = tmp.data();
  for (int c = 0; c < s.clusters(); ++c) {
    const int a = s.start[static_cast<std::size_t>(c)], b = s.start[static_cast<std::size_t>(c) + 1];
    if (b - a < 2) {
      for (int r = a; r < b; ++r) std::fill(out.row(r), out.row(r) + d, 0.0f);
      continue;
    }
    std::copy(x.row(b - 1), x.row(b - 1) + d, out.row(b - 2));  // suffix maxima: out[r] = max_{j > r} x[j]
    for (int r = b - 3; r >= a; --r) {
      const float* __restrict next = out.row(r + 1);
      const float* __restrict v = x.row(r + 1);
      float* __restrict o = out.row(r);
      for (int j = 0; j < d; ++j) o[j] = std::max(next[j], v[j]);
    }
    std::copy(x.row(a), x.row(a) + d, prefix);  // then out[r] = max(max_{j < r} x[j], out[r])
    for (int r = a + 1; r < b - 1; ++r) {
      const float* __restrict v = x.row(r);
      float* __restrict o = out.row(r);
      for (int j = 0; j < d; ++j) {
        o[j] = std::max(prefix[j], o[j]);
        prefix[j] = std::max(prefix[j], v[j]);
      }
    }
    std::copy(prefix, prefix + d, out.row(b - 1));
  }
}

/// A parameter by name, checked against its expected shape.
const Param& get(const Params& p, const std::string& name, std::vector<long> shape) {
  const auto it = p.find(name);
  if (it == p.end()) throw std::invalid_argument("fast inference: the checkpoint has no parameter '" + name + "'");
  if (it->second.shape != shape) throw std::invalid_argument("fast inference: parameter '" + name + "' has an unexpected shape");
  return it->second;
}

/// MlpImpl (models.hpp) packed: Linear(in, hidden) -> norm -> ReLU -> Linear(hidden, out)
/// [-> norm -> ReLU unless final]. `parts` splits the first layer's input columns.
struct Block {
  std::vector<Dense> l1;
  Dense l2;
  Norm n1, n2;
  bool final = false;

  static Block load(const Params& p, const std::string& name, const std::vector<int>& parts, int hidden, int out,
                    NormKind norm, bool final) {
    Block b;
    int in = 0;
    for (int w : parts) in += w;
    const auto& w1 = get(p, name + ".l1.weight", {hidden, in});
    const auto& b1 = get(p, name + ".l1.bias", {hidden});
    int first = 0;
    for (std::size_t i = 0; i < parts.size(); ++i) {
      b.l1.push_back(pack(w1.data.data(), hidden, in, first, parts[i], i == 0 ? b1.data.data() : nullptr));
      first += parts[i];
    }
    b.l2 = pack(get(p, name + ".l2.weight", {out, hidden}).data.data(), out, hidden, 0, hidden,
                get(p, name + ".l2.bias", {out}).data.data());
    b.final = final;
    auto load_norm = [&](const std::string& n, int dim) {
      Norm r;
      r.kind = norm;
      if (norm == NormKind::Graph) {
        r.gamma = get(p, name + "." + n + ".gamma", {dim}).data;
        r.beta = get(p, name + "." + n + ".beta", {dim}).data;
        r.alpha = get(p, name + "." + n + ".alpha", {dim}).data;
      } else if (norm == NormKind::Layer) {
        r.gamma = get(p, name + "." + n + ".weight", {dim}).data;
        r.beta = get(p, name + "." + n + ".bias", {dim}).data;
      }
      return r;
    };
    b.n1 = load_norm("n1", hidden);
    if (!final) b.n2 = load_norm("n2", out);
    return b;
  }
};

/// One input part of a block: a matrix with a row per output row (gather = nullptr), or one whose
/// row gather[r] is output row r's (a cluster's row added to each of its users, a UAV's or a
/// user's row to each of its edges): the part's product is computed once per row of the matrix.
struct Part {
  const Mat* m;
  const std::vector<int>* gather;
};

struct Work {
  Mat h, tmp;
  std::vector<float> scratch;
};

/// The block's norm, then its ReLU (fused into the norm's last pass).
void norm_relu(Mat& m, const Norm& n, const Segments& s, Work& w) {
  if (n.kind == NormKind::Graph) graph_norm_relu(m, n, s, w.scratch);
  else if (n.kind == NormKind::Layer) layer_norm_relu(m, n);
  else relu(m);
}

/// out = block(parts) over `rows` rows (users, clusters or edges).
/// The parts come as an initializer list (on the stack: a forward allocates nothing per block).
void run(const Block& b, std::initializer_list<Part> parts, int rows, const Segments& s, Mat& out, Work& w) {
  const int hidden = b.l1.front().out;
  w.h.resize(rows, hidden);
  std::size_t i = 0;
  for (const Part& part : parts) {
    const Mat& in = *part.m;
    const bool accumulate = i > 0;  // the first part writes (with the bias), the others add
    if (!part.gather) {
      gemm(in.v.data(), in.ld, rows, b.l1[i++], w.h.v.data(), w.h.ld, accumulate);
      continue;
    }
    w.tmp.resize(in.rows, hidden);
    gemm(in.v.data(), in.ld, in.rows, b.l1[i++], w.tmp.v.data(), w.tmp.ld, false);
    const std::vector<int>& from = *part.gather;
    for (int r = 0; r < rows; ++r) {
      float* __restrict o = w.h.row(r);
      const float* __restrict t = w.tmp.row(from[static_cast<std::size_t>(r)]);
      if (accumulate)
        for (int j = 0; j < hidden; ++j) o[j] += t[j];
      else
        std::copy(t, t + hidden, o);
    }
  }
  norm_relu(w.h, b.n1, s, w);
  out.resize(rows, b.l2.out);
  gemm(w.h.v.data(), w.h.ld, rows, b.l2, out.v.data(), out.ld, false);
  if (!b.final) {
    norm_relu(out, b.n2, s, w);
  }
}

/// out[to[e]] += x[e] over the rows e in order (zeroed first, `rows` rows), then each row divided
/// by its count of terms (at least 1): index_add, then the division, as the LibTorch model does.
SKYLOOP_CLONES void scatter_mean(const Mat& x, const std::vector<int>& to, const std::vector<float>& count, int rows, Mat& out) {
  const int d = x.cols;
  out.resize(rows, d);
  for (int r = 0; r < rows; ++r) std::fill(out.row(r), out.row(r) + d, 0.0f);
  for (int e = 0; e < x.rows; ++e) {
    float* __restrict o = out.row(to[static_cast<std::size_t>(e)]);
    const float* __restrict v = x.row(e);
    for (int j = 0; j < d; ++j) o[j] += v[j];
  }
  for (int r = 0; r < rows; ++r) {
    float* __restrict o = out.row(r);
    const float c = count[static_cast<std::size_t>(r)];
    for (int j = 0; j < d; ++j) o[j] /= c;
  }
}

/// The encoders' input under nn.features = "log" (models.hpp, encode_features), in float as
/// LibTorch computes it on the float batch: each row's direction kept, its norm r mapped to
/// log1p(r / floor) / log1p(1 / floor).
void log_features(const Mat& x, Mat& out) {
  out.resize(x.rows, x.cols);
  const float unit = static_cast<float>(std::log1p(1.0 / kLogFeatureFloor)), floor = static_cast<float>(kLogFeatureFloor);
  for (int u = 0; u < x.rows; ++u) {
    const float* in = x.row(u);
    float* o = out.row(u);
    float r2 = 0.0f;
    for (int i = 0; i < x.cols; ++i) r2 += in[i] * in[i];
    const float norm = std::sqrt(r2);
    const float scale = std::log1p(norm / floor) / (unit * std::max(norm, 1e-30f));
    for (int i = 0; i < x.cols; ++i) o[i] = in[i] * scale;
  }
}

/// Row r of x = [Re h, Im h] * scale, h = conj(g) for the channel row g (h^H): the features of
/// eq:node_feature, cast to float after the scaling in double (as the LibTorch batch).
template <typename Row>
void write_features(const Row& g, double scale, float* x) {
  const auto L = g.size();
  for (Eigen::Index l = 0; l < L; ++l) {
    x[l] = static_cast<float>(g(l).real() * scale);
    x[L + l] = static_cast<float>(-g(l).imag() * scale);
  }
}

/// Structured readout (models.hpp, structured_beams), in double: v_k = (I + sum_j lambda_j h_j
/// h_j^H)^{-1} h_k over the columns j of H (every user the transmitter's beams reach in its
/// model), w_k = sqrt(share_k) v_k / ||v_k|| for its own users (columns own, own + K), share a
/// softmax over them; y row j = [log lambda_j, logit_j].
MatrixXcd structured_beams(const MatrixXcd& H, int own, int K, const Mat& y, int first_row) {
  const Eigen::Index L = H.rows();
  VectorXd lambda(H.cols());
  for (Eigen::Index j = 0; j < H.cols(); ++j)
    lambda(j) = std::exp(std::clamp(static_cast<double>(y.row(first_row + static_cast<int>(j))[0]), -30.0, 30.0));
  // A += lambda_j h_j h_j^H column by column, each entry conj(h_j[c]) (lambda_j h_j[r]) added in
  // j order: the products and sums of Eigen's outer product (A.noalias() += lambda_j h_j h_j^H),
  // bit for bit, without its per-term temporaries.
  MatrixXcd A = MatrixXcd::Identity(L, L);
  for (Eigen::Index j = 0; j < H.cols(); ++j) {
    const double lj = lambda(j);
    const std::complex<double>* h = H.col(j).data();
    for (Eigen::Index c = 0; c < L; ++c) {
      const std::complex<double> s = std::conj(h[c]);
      std::complex<double>* a = A.col(c).data();
      for (Eigen::Index r = 0; r < L; ++r) a[r] += s * (lj * h[r]);
    }
  }
  const MatrixXcd V = A.llt().solve(H.middleCols(own, K));
  double top = -std::numeric_limits<double>::infinity();
  for (int k = 0; k < K; ++k) top = std::max(top, static_cast<double>(y.row(first_row + own + k)[1]));
  double total = 0.0;
  VectorXd e(K);
  for (int k = 0; k < K; ++k) total += (e(k) = std::exp(static_cast<double>(y.row(first_row + own + k)[1]) - top));
  MatrixXcd W(L, K);
  for (int k = 0; k < K; ++k) W.col(k) = V.col(k) / (V.col(k).norm() + 1e-30) * std::sqrt(e(k) / total);
  return W;
}

}  // namespace

enum class Arch { Gnn, DeepSets, MsPointNet, Ignn };  // nn.model, resolved once when the model is built

struct Model::Impl {
  Arch arch = Arch::Gnn;
  bool structured = false;
  bool log_features = false;  // nn.features = "log" (models.hpp, encode_features)
  int antennas = 0;
  float feature_scale = 1.0f;
  // gnn, ignn
  Block user_enc, uav_enc, out;
  std::vector<Block> user_msg, uav_msg, user_upd, uav_upd;
  // ignn: the interference edges' encoder and messages
  Block edge_enc;
  std::vector<Block> int_msg, leak_msg;
  // deepsets / mspointnet
  Block phi1, phi2, head1, head2;
  Dense conv, mix, proj;  // mspointnet: the three convolutions as one map, 1x1 mix, projection
  int channels = 0;       // mspointnet: 3c

  /// Per-user head outputs for the batch described by x (features) and s.
  void head(const Mat& x, const Segments& s, Mat& y, Work& w) const;
  /// gnn, ignn: the users' embeddings u = user_enc(x) and the UAVs' a = uav_enc(mean of u over
  /// each cluster), into the buffers' u and a.
  void encode_nodes(const Mat& x, const Segments& s, Work& w) const;
  /// gnn, ignn: layer l's messages m_u = user_msg(u) and m_a = uav_msg(a), into mu and ma.
  void node_messages(std::size_t l, const Segments& s, Work& w) const;
  /// ignn: per-user head outputs of the networks whose users (x, by cluster in s) and
  /// interference edges (xe; e's transmitter cluster row tx[e], its user row rx[e]) are given.
  void network_head(const Mat& x, const Mat& xe, const Segments& s, const std::vector<int>& tx, const std::vector<int>& rx,
                    Mat& y, Work& w) const;
  /// ignn: what depends on one user row alone (u = user_enc(x), m_u of layer 0) and on one edge
  /// row alone (its part e W_e of every interference and leakage message), from the row caches.
  void user_rows(const Mat& x, const Segments& s, Work& w) const;
  void edge_rows(const Mat& xe, const Segments& s, Work& w) const;
  std::uint64_t id = 0;  // the row caches' owner: unique per model built in this process
};

namespace {

/// Rows of a function of one input row, keyed by the row's bits: the interference-aware GNN's
/// users and edges recur across the networks asked for (a UAV's channel to a user depends on their
/// two positions alone: the exact optimum's million joint states hold a few thousand distinct
/// rows). Every block is row-wise (LayerNorm), and a GEMM row's floats do not depend on the other
/// rows of its batch, so a cached row is the row computed afresh, bit for bit. Bounded (per
/// thread): full, it starts again empty, between two forward passes' lookups, never inside one.
struct RowCache {
  std::uint64_t owner = 0;
  int kw = 0, vw = 0;                   // floats per key, per value
  int used = 0, capacity = 0;
  std::vector<std::uint32_t> keys;      // [capacity x kw]
  std::vector<float> values;            // [capacity x vw]
  std::vector<std::int32_t> table;      // open addressing: a slot or -1; a power of two >= 2 capacity
  static constexpr int kCapacity = 4096;

  /// Ready for a pass of `rows` rows of this owner's shape: room for all of them at least.
  void prepare(std::uint64_t model, int key_floats, int value_floats, int rows) {
    if (owner == model && kw == key_floats && vw == value_floats && rows <= capacity) return;
    owner = model, kw = key_floats, vw = value_floats;
    capacity = std::max(kCapacity, rows);
    keys.resize(static_cast<std::size_t>(capacity) * static_cast<std::size_t>(kw));
    values.resize(static_cast<std::size_t>(capacity) * static_cast<std::size_t>(vw));
    std::size_t t = 1;
    while (t < 2 * static_cast<std::size_t>(capacity)) t <<= 1;
    table.resize(t);
    clear();
  }
  void clear() {
    used = 0;
    std::fill(table.begin(), table.end(), -1);
  }
  /// The slot of the row's key and whether it was there (false: a new slot, to be filled); slot
  /// -1 when the cache is full.
  std::pair<int, bool> find_or_add(const float* row) {
    const std::size_t bytes = sizeof(float) * static_cast<std::size_t>(kw);
    std::uint64_t h = 0xcbf29ce484222325ULL;
    for (int i = 0; i < kw; ++i) {
      std::uint32_t word;
      std::memcpy(&word, row + i, sizeof word);
      h = (h ^ word) * 0x100000001b3ULL;
    }
    const std::size_t mask = table.size() - 1;
    for (std::size_t t = (h ^ (h >> 29)) & mask;; t = (t + 1) & mask) {
      const std::int32_t at = table[t];
      if (at < 0) {
        if (used == capacity) return {-1, false};
        table[t] = used;
        std::memcpy(&keys[static_cast<std::size_t>(used) * static_cast<std::size_t>(kw)], row, bytes);
        return {used++, false};
      }
      if (std::memcmp(&keys[static_cast<std::size_t>(at) * static_cast<std::size_t>(kw)], row, bytes) == 0) return {at, true};
    }
  }
  float* value(int slot) { return values.data() + static_cast<std::size_t>(slot) * static_cast<std::size_t>(vw); }
};

struct Buffers {
  Work w;
  Mat x, xin, u, a, mu, ma, mo, mean, u2, a2, y, pooled, per_antenna;
  // ignn
  Mat xe, xein, e, he, heard, le, leaked, miss, part;
  std::vector<int> tx, rx, user_slot, edge_slot, missed;
  std::vector<float> to_user, to_uav;
  RowCache users, edges;
};

Buffers& buffers() {
  thread_local Buffers b;
  return b;
}

}  // namespace

void Model::Impl::encode_nodes(const Mat& x, const Segments& s, Work& w) const {
  Buffers& B = buffers();
  run(user_enc, {{&x, nullptr}}, s.users(), s, B.u, w);
  segment_mean(B.u, s, B.mean);
  run(uav_enc, {{&B.mean, nullptr}}, s.clusters(), s, B.a, w);
}

void Model::Impl::node_messages(std::size_t l, const Segments& s, Work& w) const {
  Buffers& B = buffers();
  run(user_msg[l], {{&B.u, nullptr}}, s.users(), s, B.mu, w);
  run(uav_msg[l], {{&B.a, nullptr}}, s.clusters(), s, B.ma, w);
}

void Model::Impl::head(const Mat& x, const Segments& s, Mat& y, Work& w) const {
  Buffers& B = buffers();
  const int U = s.users(), C = s.clusters();
  if (arch == Arch::Gnn) {
    encode_nodes(x, s, w);
    for (std::size_t l = 0; l < user_msg.size(); ++l) {
      node_messages(l, s, w);
      max_over_others(B.mu, s, B.mo, w.scratch);
      run(user_upd[l], {{&B.u, nullptr}, {&B.ma, &s.seg}, {&B.mo, nullptr}}, U, s, B.u2, w);
      std::swap(B.u, B.u2);
      // The readout reads the users' embeddings alone: the last layer's UAV update (and the mean
      // of messages it reads) would feed nothing.
      if (l + 1 == user_msg.size()) break;
      segment_mean(B.mu, s, B.mean);
      run(uav_upd[l], {{&B.a, nullptr}, {&B.mean, nullptr}}, C, s, B.a2, w);
      std::swap(B.a, B.a2);
    }
    run(out, {{&B.u, nullptr}}, U, s, y, w);
    return;
  }
  const Mat* feature = &B.u;
  if (arch == Arch::DeepSets) {
    run(phi1, {{&x, nullptr}}, U, s, B.u2, w);
    run(phi2, {{&B.u2, nullptr}}, U, s, B.u, w);
  } else {  // mspointnet: x -> [U, L * 3c] (antenna-major) -> mix per antenna -> projection
    B.u2.resize(U, antennas * channels);
    gemm(x.v.data(), x.ld, U, conv, B.u2.v.data(), B.u2.ld, false);
    relu(B.u2);
    // Each user row holds L antenna rows of 3c channels: the 1x1 mix is one GEMM over U * L rows.
    Mat& per_antenna = B.per_antenna;
    per_antenna.resize(U * antennas, channels);
    for (int r = 0; r < U; ++r)
      for (int l = 0; l < antennas; ++l)
        std::copy(B.u2.row(r) + l * channels, B.u2.row(r) + (l + 1) * channels, per_antenna.row(r * antennas + l));
    B.mo.resize(U * antennas, channels);
    gemm(per_antenna.v.data(), per_antenna.ld, U * antennas, mix, B.mo.v.data(), B.mo.ld, false);
    relu(B.mo);
    // Back to one row per user: [U, L * mix.out_pad], the projection's input order.
    B.mu.resize(U, antennas * mix.out_pad);
    for (int r = 0; r < U; ++r)
      for (int l = 0; l < antennas; ++l)
        std::copy(B.mo.row(r * antennas + l), B.mo.row(r * antennas + l) + mix.out_pad, B.mu.row(r) + l * mix.out_pad);
    B.u.resize(U, proj.out);
    gemm(B.mu.v.data(), B.mu.ld, U, proj, B.u.v.data(), B.u.ld, false);
    relu(B.u);
  }
  segment_max(*feature, s, B.pooled);
  run(head1, {{feature, nullptr}, {&B.pooled, &s.seg}}, U, s, B.a, w);
  run(head2, {{&B.a, nullptr}}, U, s, y, w);
}

/// The rows of `in` whose keys `cache` lacks, gathered into `miss`; slots[r] is row r's slot.
/// Returns how many were missing (their rows of `in`, in `missed`, whose slots are to be filled).
static int gather_misses(const Mat& in, RowCache& cache, std::vector<int>& slots, std::vector<int>& missed, Mat& miss) {
  slots.resize(static_cast<std::size_t>(in.rows));
  missed.clear();
  for (int r = 0; r < in.rows; ++r) {
    const auto [slot, found] = cache.find_or_add(in.row(r));
    if (slot < 0) {  // full: empty, then this pass's rows again (prepare made room for them all)
      cache.clear();
      missed.clear();
      r = -1;
      continue;
    }
    slots[static_cast<std::size_t>(r)] = slot;
    if (!found) missed.push_back(r);
  }
  miss.resize(static_cast<int>(missed.size()), in.cols);
  for (std::size_t i = 0; i < missed.size(); ++i) std::copy(in.row(missed[i]), in.row(missed[i]) + in.cols, miss.row(static_cast<int>(i)));
  return static_cast<int>(missed.size());
}

void Model::Impl::user_rows(const Mat& x, const Segments& s, Work& w) const {
  Buffers& B = buffers();
  const int d = user_enc.l2.out;
  B.users.prepare(id, x.cols, 2 * d, x.rows);
  const int n = gather_misses(x, B.users, B.user_slot, B.missed, B.miss);
  if (n > 0) {  // u, then layer 0's m_u: row-wise blocks
    run(user_enc, {{&B.miss, nullptr}}, n, s, B.u2, w);
    run(user_msg[0], {{&B.u2, nullptr}}, n, s, B.part, w);
    for (int i = 0; i < n; ++i) {
      float* v = B.users.value(B.user_slot[static_cast<std::size_t>(B.missed[static_cast<std::size_t>(i)])]);
      std::copy(B.u2.row(i), B.u2.row(i) + d, v);
      std::copy(B.part.row(i), B.part.row(i) + d, v + d);
    }
  }
  B.u.resize(x.rows, d);
  B.mu.resize(x.rows, d);
  for (int r = 0; r < x.rows; ++r) {
    const float* v = B.users.value(B.user_slot[static_cast<std::size_t>(r)]);
    std::copy(v, v + d, B.u.row(r));
    std::copy(v + d, v + 2 * d, B.mu.row(r));
  }
}

void Model::Impl::edge_rows(const Mat& xe, const Segments& s, Work& w) const {
  // Per edge row: e = edge_enc(xe), then its part e W_e of the first linear layer of each layer's
  // interference message and of each leakage message that is computed (not the last layer's).
  Buffers& B = buffers();
  const int d = edge_enc.l2.out, L = static_cast<int>(int_msg.size());
  const int parts = 2 * L - 1;
  B.edges.prepare(id, xe.cols, parts * d, xe.rows);
  const int n = gather_misses(xe, B.edges, B.edge_slot, B.missed, B.miss);
  if (n == 0) return;
  run(edge_enc, {{&B.miss, nullptr}}, n, s, B.e, w);
  B.part.resize(n, d);
  for (int p = 0; p < parts; ++p) {
    const Block& b = p < L ? int_msg[static_cast<std::size_t>(p)] : leak_msg[static_cast<std::size_t>(p - L)];
    gemm(B.e.v.data(), B.e.ld, n, b.l1[1], B.part.v.data(), B.part.ld, false);  // no bias: part 0 holds it
    for (int i = 0; i < n; ++i)
      std::copy(B.part.row(i), B.part.row(i) + d, B.edges.value(B.edge_slot[static_cast<std::size_t>(B.missed[static_cast<std::size_t>(i)])]) + p * d);
  }
}

/// An interference or leakage message over E edge rows: h = e W_e (its edge's cached part `p`)
/// + (node W_node + bias)[gather[e]], then the block's norm, second layer and norm.
static void run_edge_message(const Block& b, const Mat& node, const std::vector<int>& gather, RowCache& edges,
                             const std::vector<int>& slot, int p, int E, const Segments& s, Mat& out, Work& w) {
  const int hidden = b.l1.front().out;
  w.tmp.resize(node.rows, hidden);
  gemm(node.v.data(), node.ld, node.rows, b.l1[0], w.tmp.v.data(), w.tmp.ld, false);
  w.h.resize(E, hidden);
  for (int r = 0; r < E; ++r) {
    float* __restrict o = w.h.row(r);
    const float* __restrict e = edges.value(slot[static_cast<std::size_t>(r)]) + p * hidden;
    const float* __restrict t = w.tmp.row(gather[static_cast<std::size_t>(r)]);
    for (int j = 0; j < hidden; ++j) o[j] = e[j] + t[j];
  }
  norm_relu(w.h, b.n1, s, w);
  out.resize(E, b.l2.out);
  gemm(w.h.v.data(), w.h.ld, E, b.l2, out.v.data(), out.ld, false);
  if (!b.final) norm_relu(out, b.n2, s, w);
}

void Model::Impl::network_head(const Mat& x, const Mat& xe, const Segments& s, const std::vector<int>& tx,
                               const std::vector<int>& rx, Mat& y, Work& w) const {
  // IgnnImpl::forward_network (models.cpp) on lists of the real users, clusters and edges: per
  // layer, m_u and m_a; an edge's message to its user phi([m_a of its UAV, e]) and to its UAV
  // psi([m_u of its user, e]); the user's mean of what it hears, the UAV's of what it leaks. What
  // depends on one user's or one edge's features alone comes from the row caches (user_rows,
  // edge_rows): a message's first layer sums its edge part e W_e, then its node part.
  Buffers& B = buffers();
  const int U = s.users(), C = s.clusters(), E = xe.rows, L = static_cast<int>(user_msg.size());
  B.to_user.assign(static_cast<std::size_t>(U), 0.0f);
  B.to_uav.assign(static_cast<std::size_t>(C), 0.0f);
  for (int e = 0; e < E; ++e) {
    B.to_user[static_cast<std::size_t>(rx[static_cast<std::size_t>(e)])] += 1.0f;
    B.to_uav[static_cast<std::size_t>(tx[static_cast<std::size_t>(e)])] += 1.0f;
  }
  for (float& c : B.to_user) c = std::max(c, 1.0f);
  for (float& c : B.to_uav) c = std::max(c, 1.0f);
  edge_rows(xe, s, w);
  user_rows(x, s, w);  // u and layer 0's m_u
  segment_mean(B.u, s, B.mean);
  run(uav_enc, {{&B.mean, nullptr}}, C, s, B.a, w);
  for (int l = 0; l < L; ++l) {
    if (l > 0) run(user_msg[static_cast<std::size_t>(l)], {{&B.u, nullptr}}, U, s, B.mu, w);
    run(uav_msg[static_cast<std::size_t>(l)], {{&B.a, nullptr}}, C, s, B.ma, w);
    run_edge_message(int_msg[static_cast<std::size_t>(l)], B.ma, tx, B.edges, B.edge_slot, l, E, s, B.he, w);
    scatter_mean(B.he, rx, B.to_user, U, B.heard);
    max_over_others(B.mu, s, B.mo, w.scratch);
    run(user_upd[static_cast<std::size_t>(l)], {{&B.u, nullptr}, {&B.ma, &s.seg}, {&B.mo, nullptr}, {&B.heard, nullptr}}, U, s, B.u2, w);
    std::swap(B.u, B.u2);
    // The readout reads the users' embeddings alone: the last layer's UAV update (and the
    // leaked messages and the mean it reads) would feed nothing.
    if (l + 1 == L) break;
    run_edge_message(leak_msg[static_cast<std::size_t>(l)], B.mu, rx, B.edges, B.edge_slot, L + l, E, s, B.le, w);
    scatter_mean(B.le, tx, B.to_uav, C, B.leaked);
    segment_mean(B.mu, s, B.mean);
    run(uav_upd[static_cast<std::size_t>(l)], {{&B.a, nullptr}, {&B.mean, nullptr}, {&B.leaked, nullptr}}, C, s, B.a2, w);
    std::swap(B.a, B.a2);
  }
  run(out, {{&B.u, nullptr}}, U, s, y, w);
}

Model::Model(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Model::~Model() = default;

std::unique_ptr<Model> Model::build(const ModelInfo& info, const Params& p) {
  static std::atomic<std::uint64_t> models{0};
  auto m = std::make_unique<Impl>();
  m->id = ++models;
  m->structured = info.readout == Readout::Structured;
  m->log_features = info.features == Features::Log;
  m->antennas = info.antennas;
  m->feature_scale = static_cast<float>(info.feature_scale);
  const int L = info.antennas, d = info.hidden, out = m->structured ? 2 : 2 * L;
  if (info.model == "gnn") {
    m->arch = Arch::Gnn;
    m->user_enc = Block::load(p, "user_enc", {2 * L}, d, d, NormKind::Graph, false);
    m->uav_enc = Block::load(p, "uav_enc", {d}, d, d, NormKind::Layer, false);
    for (int l = 0; l < info.layers; ++l) {
      const std::string i = "." + std::to_string(l);
      m->user_msg.push_back(Block::load(p, "user_msg" + i, {d}, d, d, NormKind::Graph, false));
      m->uav_msg.push_back(Block::load(p, "uav_msg" + i, {d}, d, d, NormKind::Layer, false));
      m->user_upd.push_back(Block::load(p, "user_upd" + i, {d, d, d}, d, d, NormKind::Graph, false));
      m->uav_upd.push_back(Block::load(p, "uav_upd" + i, {d, d}, d, d, NormKind::Layer, false));
    }
    m->out = Block::load(p, "out", {d}, d, out, NormKind::Graph, true);
  } else if (info.model == "ignn") {
    m->arch = Arch::Ignn;
    m->user_enc = Block::load(p, "user_enc", {2 * L}, d, d, NormKind::Layer, false);
    m->edge_enc = Block::load(p, "edge_enc", {2 * L}, d, d, NormKind::Layer, false);
    m->uav_enc = Block::load(p, "uav_enc", {d}, d, d, NormKind::Layer, false);
    for (int l = 0; l < info.layers; ++l) {
      const std::string i = "." + std::to_string(l);
      m->user_msg.push_back(Block::load(p, "user_msg" + i, {d}, d, d, NormKind::Layer, false));
      m->uav_msg.push_back(Block::load(p, "uav_msg" + i, {d}, d, d, NormKind::Layer, false));
      m->int_msg.push_back(Block::load(p, "int_msg" + i, {d, d}, d, d, NormKind::Layer, false));
      m->leak_msg.push_back(Block::load(p, "leak_msg" + i, {d, d}, d, d, NormKind::Layer, false));
      m->user_upd.push_back(Block::load(p, "user_upd" + i, {d, d, d, d}, d, d, NormKind::Layer, false));
      m->uav_upd.push_back(Block::load(p, "uav_upd" + i, {d, d, d}, d, d, NormKind::Layer, false));
    }
    m->out = Block::load(p, "out", {d}, d, out, NormKind::Layer, true);
  } else if (info.model == "deepsets") {
    m->arch = Arch::DeepSets;
    const int w = 2 * d;
    m->phi1 = Block::load(p, "phi1", {2 * L}, w, w, NormKind::None, false);
    m->phi2 = Block::load(p, "phi2", {w}, w, w, NormKind::None, false);
    m->head1 = Block::load(p, "head1", {w, w}, w, w, NormKind::None, false);
    m->head2 = Block::load(p, "head2", {w}, w, out, NormKind::None, true);
  } else if (info.model == "mspointnet") {
    m->arch = Arch::MsPointNet;
    const int c = d / 2, w = 2 * d;
    m->channels = 3 * c;
    // Conv1d k = 1, 3, 5 (padding 0, 1, 2) over the antenna axis of s = [Re h; Im h] as one dense
    // map [2L -> L * 3c], output index l * 3c + (block * c + o).
    std::vector<float> conv_w(static_cast<std::size_t>(L * 3 * c) * static_cast<std::size_t>(2 * L), 0.0f);
    std::vector<float> conv_b(static_cast<std::size_t>(L * 3 * c), 0.0f);
    const int kernels[3] = {1, 3, 5};
    for (int blk = 0; blk < 3; ++blk) {
      const int k = kernels[blk], pad = k / 2;
      const std::string n = "conv" + std::to_string(k);
      const auto& W = get(p, n + ".weight", {c, 2, k});
      const auto& bias = get(p, n + ".bias", {c});
      for (int l = 0; l < L; ++l)
        for (int o = 0; o < c; ++o) {
          const int row = l * 3 * c + blk * c + o;
          conv_b[static_cast<std::size_t>(row)] = bias.data[static_cast<std::size_t>(o)];
          for (int ch = 0; ch < 2; ++ch)
            for (int t = 0; t < k; ++t) {
              const int src = l + t - pad;
              if (src < 0 || src >= L) continue;
              conv_w[static_cast<std::size_t>(row) * static_cast<std::size_t>(2 * L) + static_cast<std::size_t>(ch * L + src)] =
                  W.data[static_cast<std::size_t>((o * 2 + ch) * k + t)];
            }
        }
    }
    m->conv = pack(conv_w.data(), L * 3 * c, 2 * L, 0, 2 * L, conv_b.data());
    const auto& mw = get(p, "mix.weight", {3 * c, 3 * c, 1});
    m->mix = pack(mw.data.data(), 3 * c, 3 * c, 0, 3 * c, get(p, "mix.bias", {3 * c}).data.data());
    // Projection: torch flattens [3c, L] channel-major (ch * L + l); our rows are l * mix.out_pad + ch.
    const auto& pw = get(p, "proj.weight", {w, 3 * c * L});
    const int in = L * m->mix.out_pad;
    std::vector<float> proj_w(static_cast<std::size_t>(w) * static_cast<std::size_t>(in), 0.0f);
    for (int o = 0; o < w; ++o)
      for (int ch = 0; ch < 3 * c; ++ch)
        for (int l = 0; l < L; ++l)
          proj_w[static_cast<std::size_t>(o) * static_cast<std::size_t>(in) + static_cast<std::size_t>(l * m->mix.out_pad + ch)] =
              pw.data[static_cast<std::size_t>(o) * static_cast<std::size_t>(3 * c * L) + static_cast<std::size_t>(ch * L + l)];
    m->proj = pack(proj_w.data(), w, in, 0, in, get(p, "proj.bias", {w}).data.data());
    m->head1 = Block::load(p, "head1", {w, w}, w, w, NormKind::None, false);
    m->head2 = Block::load(p, "head2", {w}, w, out, NormKind::None, true);
  } else {
    return nullptr;
  }
  return std::unique_ptr<Model>(new Model(std::move(m)));
}

bool Model::network() const { return impl_->arch == Arch::Ignn; }

std::vector<MatrixXcd> Model::forward(const std::vector<const Cluster*>& clusters) const {
  const Impl& m = *impl_;
  if (m.arch == Arch::Ignn) throw std::logic_error("fast::Model::forward: a network-level model takes networks");
  const int L = m.antennas;
  Segments s;
  s.start.assign(1, 0);
  for (const Cluster* c : clusters) {
    if (c->size() == 0 || c->antennas() != L) throw std::logic_error("fast::Model::forward: empty cluster or antenna mismatch");
    for (int k = 0; k < c->size(); ++k) s.seg.push_back(static_cast<int>(s.start.size()) - 1);
    s.start.push_back(s.start.back() + c->size());
  }
  const int U = s.users();
  Buffers& B = buffers();
  // Features x = [Re h, Im h] * feature_scale with h = conj(row of G) (eq:node_feature); under
  // nn.features = "log" the encoders read B.xin, the structured readout the linear B.x.
  B.x.resize(U, 2 * L);
  int r = 0;
  for (const Cluster* c : clusters)
    for (int k = 0; k < c->size(); ++k, ++r) write_features(c->G.row(k), static_cast<double>(m.feature_scale), B.x.row(r));
  if (m.log_features) log_features(B.x, B.xin);
  m.head(m.log_features ? B.xin : B.x, s, B.y, B.w);

  std::vector<MatrixXcd> out;
  out.reserve(clusters.size());
  for (int c = 0; c < s.clusters(); ++c) {
    const int a = s.start[static_cast<std::size_t>(c)], K = s.start[static_cast<std::size_t>(c) + 1] - a;
    MatrixXcd W(L, K);
    if (!m.structured) {
      for (int k = 0; k < K; ++k)
        for (int l = 0; l < L; ++l) W(l, k) = cdouble(B.y.row(a + k)[l], B.y.row(a + k)[L + l]);
      out.push_back(std::move(W));
      continue;
    }
    MatrixXcd H(L, K);
    for (int k = 0; k < K; ++k)
      for (int l = 0; l < L; ++l) H(l, k) = cdouble(B.x.row(a + k)[l], B.x.row(a + k)[L + l]);
    out.push_back(structured_beams(H, 0, K, B.y, a));
  }
  return out;
}

std::vector<std::vector<MatrixXcd>> Model::forward_networks(const std::vector<const Network*>& nets) const {
  const Impl& m = *impl_;
  if (m.arch != Arch::Ignn) throw std::logic_error("fast::Model::forward_networks: a per-cluster model takes clusters");
  const int L = m.antennas;
  const double scale = static_cast<double>(m.feature_scale);
  Buffers& B = buffers();
  // Rows: users network by network, cluster by cluster (the served order); clusters likewise;
  // edges (tx, rx != tx, k) ascending within a network, as the LibTorch model lists them.
  Segments s;
  s.start.assign(1, 0);
  int edges = 0;
  for (const Network* n : nets) {
    for (const Cluster& c : n->clusters) {
      if (c.size() == 0 || c.antennas() != L) throw std::logic_error("fast::Model::forward_networks: empty cluster or antenna mismatch");
      for (int k = 0; k < c.size(); ++k) s.seg.push_back(static_cast<int>(s.start.size()) - 1);
      s.start.push_back(s.start.back() + c.size());
    }
    const int C = static_cast<int>(n->clusters.size());
    edges += n->served_count() * (C - 1);
  }
  B.x.resize(s.users(), 2 * L);
  B.xe.resize(edges, 2 * L);
  B.tx.resize(static_cast<std::size_t>(edges));
  B.rx.resize(static_cast<std::size_t>(edges));
  int user0 = 0, cluster0 = 0, e = 0;
  for (const Network* n : nets) {
    const int C = static_cast<int>(n->clusters.size());
    for (int c = 0; c < C; ++c) {
      const MatrixXcd& g = n->cross[static_cast<std::size_t>(c)];
      for (int r = n->offset[static_cast<std::size_t>(c)]; r < n->offset[static_cast<std::size_t>(c) + 1]; ++r)
        write_features(g.row(r), scale, B.x.row(user0 + r));
      for (int rx = 0; rx < C; ++rx) {
        if (rx == c) continue;
        for (int r = n->offset[static_cast<std::size_t>(rx)]; r < n->offset[static_cast<std::size_t>(rx) + 1]; ++r, ++e) {
          write_features(g.row(r), scale, B.xe.row(e));
          B.tx[static_cast<std::size_t>(e)] = cluster0 + c;
          B.rx[static_cast<std::size_t>(e)] = user0 + r;
        }
      }
    }
    user0 += n->served_count();
    cluster0 += C;
  }
  if (m.log_features) {
    log_features(B.x, B.xin);
    log_features(B.xe, B.xein);
  }
  m.network_head(m.log_features ? B.xin : B.x, m.log_features ? B.xein : B.xe, s, B.tx, B.rx, B.y, B.w);

  std::vector<std::vector<MatrixXcd>> out(nets.size());
  user0 = 0;
  for (std::size_t i = 0; i < nets.size(); ++i) {
    const Network& n = *nets[i];
    const int C = static_cast<int>(n.clusters.size()), Un = n.served_count();
    for (int c = 0; c < C; ++c) {
      const int own = n.offset[static_cast<std::size_t>(c)], K = n.clusters[static_cast<std::size_t>(c)].size();
      if (!m.structured) {
        MatrixXcd W(L, K);
        for (int k = 0; k < K; ++k)
          for (int l = 0; l < L; ++l) W(l, k) = cdouble(B.y.row(user0 + own + k)[l], B.y.row(user0 + own + k)[L + l]);
        out[i].push_back(std::move(W));
        continue;
      }
      // The transmitter's channels to every served user of the network (its model's features):
      // its own users' rows of B.x, the others' edge rows, as [L x U_n] in the served order.
      MatrixXcd H(L, Un);
      const MatrixXcd& g = n.cross[static_cast<std::size_t>(c)];
      for (int j = 0; j < Un; ++j)
        for (int l = 0; l < L; ++l)
          H(l, j) = cdouble(static_cast<float>(g(j, l).real() * scale), static_cast<float>(-g(j, l).imag() * scale));
      out[i].push_back(structured_beams(H, own, K, B.y, user0));
    }
    user0 += Un;
  }
  return out;
}

namespace {
/// p[j] = |g . w_j|^2 for one user's channel row g (real and imaginary parts gr, gi: L each) and
/// the beams in split form (wr, wi: L rows of K), summed over the antennas in order.
SKYLOOP_CLONES void received_powers(const double* __restrict gr, const double* __restrict gi, const double* __restrict wr,
                                    const double* __restrict wi, int L, int K, double* __restrict re, double* __restrict im,
                                    double* __restrict p) {
  std::fill(re, re + K, 0.0);
  std::fill(im, im + K, 0.0);
  for (int l = 0; l < L; ++l) {
    const double a = gr[l], b = gi[l];
    const double* __restrict xr = wr + static_cast<std::size_t>(l) * static_cast<std::size_t>(K);
    const double* __restrict xi = wi + static_cast<std::size_t>(l) * static_cast<std::size_t>(K);
    for (int j = 0; j < K; ++j) {
      re[j] += a * xr[j] - b * xi[j];
      im[j] += a * xi[j] + b * xr[j];
    }
  }
  for (int j = 0; j < K; ++j) p[j] = re[j] * re[j] + im[j] * im[j];
}
}  // namespace

VectorXd served_rates(const Cluster& c, const MatrixXcd& W) {
  const Eigen::Index K = c.G.rows(), L = c.G.cols();
  if (W.rows() != L || W.cols() != K)
    throw std::invalid_argument("served_rates: beamformer shape " + std::to_string(W.rows()) + "x" + std::to_string(W.cols()) +
                                " does not match the cluster: expected " + std::to_string(L) + "x" + std::to_string(K));
  const auto k = static_cast<std::size_t>(K), l = static_cast<std::size_t>(L);
  thread_local std::vector<double> wr, wi, re, im, p, gr, gi;
  wr.resize(l * k), wi.resize(l * k), re.resize(k), im.resize(k), p.resize(k), gr.resize(l), gi.resize(l);
  for (Eigen::Index j = 0; j < K; ++j)
    for (Eigen::Index a = 0; a < L; ++a) {
      const auto at = static_cast<std::size_t>(a) * k + static_cast<std::size_t>(j);
      wr[at] = W(a, j).real(), wi[at] = W(a, j).imag();
    }
  VectorXd out(K);
  for (Eigen::Index i = 0; i < K; ++i) {
    for (Eigen::Index a = 0; a < L; ++a) gr[static_cast<std::size_t>(a)] = c.G(i, a).real(), gi[static_cast<std::size_t>(a)] = c.G(i, a).imag();
    received_powers(gr.data(), gi.data(), wr.data(), wi.data(), static_cast<int>(L), static_cast<int>(K), re.data(), im.data(), p.data());
    double interference = 0.0;
    for (Eigen::Index j = 0; j < K; ++j)
      if (j != i) interference += p[static_cast<std::size_t>(j)];
    out[i] = c.bandwidth * std::log2(1.0 + p[static_cast<std::size_t>(i)] / (interference + c.noise));
  }
  return out;
}

}  // namespace skyloop::nn::fast
