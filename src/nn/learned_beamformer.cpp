#include <algorithm>
#include <filesystem>
#include <numeric>

#include "checkpoint.hpp"
#include "models.hpp"
#include "data.hpp"
#include "fast_model.hpp"
#include "network_batch.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/paths.hpp"

namespace skyloop {

namespace {

/// Calls pass(begin, end) over the clusters [first, last) in consecutive pieces of at most
/// max_rows users (a cluster larger than that alone): what one pass holds stays bounded whatever
/// the batch. A cluster's beams do not depend on the others in its pass.
template <typename Pass>
void in_pieces(const std::vector<const Cluster*>& clusters, std::size_t first, std::size_t last, int max_rows, Pass pass) {
  for (std::size_t begin = first; begin < last;) {
    std::size_t end = begin;
    for (int rows = 0; end < last && (end == begin || rows + clusters[end]->size() <= max_rows); ++end) rows += clusters[end]->size();
    pass(begin, end);
    begin = end;
  }
}

}  // namespace

struct LearnedBeamformer::Impl {
  ModelInfo info;
  std::shared_ptr<nn::BeamNetImpl> model;
  torch::Device device{torch::kCPU};
  PowerScaling scaling = PowerScaling::Full;
  torch::ScalarType dtype = torch::kFloat32;
  bool ranked = false;                    // nn.selection = "ranked"
  std::unique_ptr<nn::fast::Model> fast;  // the fused float32 path; null: LibTorch serves

  /// A served cluster's beams: the network's, scaled onto the budget, then (nn.selection =
  /// "ranked") the better of them and water-filled ZF over the users selected in the order of
  /// the rates the network's beams give them (zf_ranked); ties keep the network's beams.
  MatrixXcd finish(const Cluster& c, MatrixXcd W) const {
    W = skyloop::scale_to_budget(std::move(W), c.p_max, scaling);
    if (!ranked || c.size() == 0) return W;
    std::vector<int> order(static_cast<std::size_t>(c.size()));
    std::iota(order.begin(), order.end(), 0);
    const VectorXd rate = nn::fast::served_rates(c, W);  // rates(c, W) to rounding, without its K x K product
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return rate[a] > rate[b]; });
    std::vector<int> chosen;
    MatrixXcd Z = zf_ranked(c, order, &chosen);
    // Z's sum rate from its served users alone: a silent user has rate 0 and adds no interference
    // (exact zeros), so this equals sum_rate(c, Z) in O(L^3) instead of O(K^2 L).
    Cluster served;
    served.p_max = c.p_max;
    served.noise = c.noise;
    served.bandwidth = c.bandwidth;
    served.G.resize(static_cast<Eigen::Index>(chosen.size()), c.G.cols());
    MatrixXcd Zs(c.G.cols(), static_cast<Eigen::Index>(chosen.size()));
    for (std::size_t i = 0; i < chosen.size(); ++i) {
      served.G.row(static_cast<Eigen::Index>(i)) = c.G.row(chosen[i]);
      Zs.col(static_cast<Eigen::Index>(i)) = Z.col(chosen[i]);
    }
    return sum_rate(served, Zs) > rate.sum() ? Z : W;
  }
};

namespace {
/// The model's parameters by name, as float32 row-major arrays (the fast path's input).
nn::fast::Params parameters_of(nn::BeamNetImpl& model) {
  nn::fast::Params out;
  for (const auto& item : model.named_parameters(/*recurse=*/true)) {
    const auto t = item.value().detach().to(torch::kCPU).to(torch::kFloat32).contiguous();
    nn::fast::Param p;
    for (const auto s : t.sizes()) p.shape.push_back(static_cast<long>(s));
    p.data.assign(t.data_ptr<float>(), t.data_ptr<float>() + t.numel());
    out.emplace(item.key(), std::move(p));
  }
  return out;
}
}  // namespace

LearnedBeamformer::LearnedBeamformer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
LearnedBeamformer::~LearnedBeamformer() = default;

std::unique_ptr<LearnedBeamformer> LearnedBeamformer::load(const std::string& path, const Config& cfg) {
  auto impl = std::make_unique<Impl>();
  impl->device = nn::resolve_device(cfg.nn.device);
  auto ck = nn::load_checkpoint(path, impl->device);
  if (ck.info.antennas != cfg.channel.antennas)
    throw InputError("checkpoint '" + path + "' was trained for " + std::to_string(ck.info.antennas) +
                     " antennas but channel.antennas = " + std::to_string(cfg.channel.antennas) +
                     ": allowed a model trained for the configured L");
  ck.model->eval();
  // The fast path serves float32 on the CPU; float64 (a reference) and CUDA stay with LibTorch.
  if (cfg.nn.inference == Inference::Fast && cfg.nn.precision == Precision::Float32 && impl->device.is_cpu())
    impl->fast = nn::fast::Model::build(ck.info, parameters_of(*ck.model));
  if (cfg.nn.precision == Precision::Float64) {
    impl->dtype = torch::kFloat64;
    ck.model->to(torch::kFloat64);
  }
  impl->ranked = cfg.nn.selection == Selection::Ranked;
  if (impl->ranked && ck.model->network())
    throw InputError("nn.selection = \"ranked\" is not allowed for the " + ck.info.model +
                     " model (its beams are designed for the whole network): allowed soft");
  impl->info = ck.info;
  impl->model = ck.model;
  impl->scaling = cfg.beamforming.power_scaling;
  return std::unique_ptr<LearnedBeamformer>(new LearnedBeamformer(std::move(impl)));
}

std::string LearnedBeamformer::name() const { return impl_->info.model; }
const ModelInfo& LearnedBeamformer::info() const { return impl_->info; }

MatrixXcd LearnedBeamformer::design(const Cluster& c) const { return design_batch({c}).front(); }

bool LearnedBeamformer::coordinated() const { return impl_->model->network(); }

std::vector<MatrixXcd> LearnedBeamformer::design_network(const Network& net, int threads) const {
  if (!coordinated()) return design_batch(net.clusters, threads);
  return design_networks({net}, threads).front();
}

std::vector<std::vector<MatrixXcd>> LearnedBeamformer::design_networks(const std::vector<Network>& nets, int threads) const {
  if (!coordinated()) return Beamformer::design_networks(nets, threads);
  const int L = impl_->info.antennas;
  std::vector<std::vector<MatrixXcd>> out(nets.size());
  for (const auto& n : nets)
    for (const auto& c : n.clusters)
      if (c.antennas() != L)
        throw std::invalid_argument("cluster has " + std::to_string(c.antennas()) + " antennas; the " + impl_->info.model +
                                    " model was trained for " + std::to_string(L));
  if (impl_->fast) return design_networks_fast(nets, threads);
  c10::InferenceMode inference;
  // Padding costs: a batch is padded to its most clusters and its largest cluster, and big padded
  // tensors leave the cache. Networks are therefore served in chunks of similar shape (sorted by
  // cluster count, then largest cluster), at most kChunk at a time.
  constexpr std::size_t kChunk = 64;
  auto shape = [&](std::size_t i) {
    int kmax = 0;
    for (const auto& c : nets[i].clusters) kmax = std::max(kmax, c.size());
    return std::make_pair(static_cast<int>(nets[i].clusters.size()), kmax);
  };
  std::vector<std::size_t> order(nets.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return shape(a) < shape(b); });
  for (std::size_t first = 0; first < order.size(); first += kChunk) {
    const std::size_t last = std::min(order.size(), first + kChunk);
    std::vector<Network> chunk;
    for (std::size_t j = first; j < last; ++j) chunk.push_back(nets[order[j]]);
    const nn::NetSet set = nn::make_net_set(chunk, L);
    const auto ids = torch::arange(static_cast<int64_t>(chunk.size()), torch::kInt64);
    const nn::NetBatch b = nn::make_net_batch(set, ids, impl_->info.feature_scale, impl_->device, impl_->dtype);
    const auto raw = impl_->model->forward_network(b).to(torch::kCPU).to(torch::kFloat64).contiguous();
    const auto acc = raw.accessor<double, 4>();  // [B, C, K, 2L]
    for (std::size_t j = 0; j < chunk.size(); ++j) {
      const auto i = static_cast<int64_t>(j);
      for (std::size_t c = 0; c < chunk[j].clusters.size(); ++c) {
        const Cluster& cl = chunk[j].clusters[c];
        MatrixXcd W(L, cl.size());
        for (int k = 0; k < cl.size(); ++k)
          for (int l = 0; l < L; ++l)
            W(l, k) = cdouble(acc[i][static_cast<int64_t>(c)][k][l], acc[i][static_cast<int64_t>(c)][k][L + l]);
        out[order[first + j]].push_back(skyloop::scale_to_budget(std::move(W), cl.p_max, impl_->scaling));
      }
    }
  }
  return out;
}

std::vector<std::vector<MatrixXcd>> LearnedBeamformer::design_networks_fast(const std::vector<Network>& nets, int threads) const {
  // Slices of at least kSlice networks go to the threads; a slice is passed in pieces of at most
  // 2,048 rows (users and interference edges; a larger network alone), so that what a pass holds
  // stays bounded. A network's beams do not depend on the others in its pass: the same floats
  // whatever the slicing.
  constexpr std::size_t kSlice = 4;
  constexpr long kMaxRows = 2048;
  std::vector<std::vector<MatrixXcd>> out(nets.size());
  const std::size_t slices =
      std::max<std::size_t>(1, std::min<std::size_t>(static_cast<std::size_t>(resolve_threads(threads)), nets.size() / kSlice));
  auto rows = [&](std::size_t i) {
    return static_cast<long>(nets[i].served_count()) * static_cast<long>(std::max<std::size_t>(nets[i].clusters.size(), 1));
  };
  parallel_for(slices, static_cast<int>(slices), [&](std::size_t slice) {
    const std::size_t first = nets.size() * slice / slices, last = nets.size() * (slice + 1) / slices;
    std::vector<const Network*> part;
    for (std::size_t begin = first; begin < last;) {
      part.clear();
      std::size_t end = begin;
      for (long held = 0; end < last && (end == begin || held + rows(end) <= kMaxRows); ++end) {
        held += rows(end);
        part.push_back(&nets[end]);
      }
      auto raw = impl_->fast->forward_networks(part);
      for (std::size_t j = begin; j < end; ++j) {
        auto& W = raw[j - begin];
        for (std::size_t c = 0; c < W.size(); ++c)
          out[j].push_back(skyloop::scale_to_budget(std::move(W[c]), nets[j].clusters[c].p_max, impl_->scaling));
      }
      begin = end;
    }
  });
  return out;
}

std::vector<MatrixXcd> LearnedBeamformer::design_batch(const std::vector<Cluster>& clusters, int threads) const {
  std::vector<MatrixXcd> out(clusters.size());
  std::vector<std::size_t> where;  // the non-empty clusters; an empty one gets an [L x 0] W
  for (std::size_t i = 0; i < clusters.size(); ++i) {
    if (clusters[i].size() == 0) out[i] = MatrixXcd(clusters[i].antennas(), 0);
    else where.push_back(i);
  }
  if (where.empty()) return out;
  if (coordinated()) {  // each cluster as a network of its own (no other UAV)
    std::vector<Network> nets;
    for (std::size_t i : where) nets.push_back(Network::of(clusters[i]));
    auto W = design_networks(nets, threads);
    for (std::size_t j = 0; j < nets.size(); ++j) out[where[j]] = std::move(W[j].front());
    return out;
  }
  std::vector<const Cluster*> nonempty;  // the batch's own clusters, not copies
  for (std::size_t i : where) {
    if (clusters[i].antennas() != impl_->info.antennas)
      throw std::invalid_argument("cluster has " + std::to_string(clusters[i].antennas()) + " antennas; the " +
                                  impl_->info.model + " model was trained for " + std::to_string(impl_->info.antennas));
    nonempty.push_back(&clusters[i]);
  }
  if (impl_->fast) return design_fast(nonempty, where, std::move(out), threads);
  c10::InferenceMode inference;  // no autograd bookkeeping at all (cheaper than NoGradGuard)
  // In batches of at most 65,536 users, so that a batch's tensors stay bounded.
  const int L = impl_->info.antennas;
  in_pieces(nonempty, 0, nonempty.size(), 65536, [&](std::size_t begin, std::size_t end) {
    std::vector<Cluster> part;
    part.reserve(end - begin);
    for (std::size_t i = begin; i < end; ++i) part.push_back(*nonempty[i]);
    const std::vector<int> owner(part.size(), 0);
    const nn::ClusterSet set = nn::make_cluster_set(part, owner, 1);
    const auto ids = torch::arange(static_cast<int64_t>(part.size()), torch::kInt64);
    const nn::Batch b = nn::make_batch(set, ids, impl_->info.feature_scale, impl_->device, impl_->dtype);
    const auto raw = impl_->model->forward(b.x, b.graph).to(torch::kCPU).to(torch::kFloat64).contiguous();
    const auto acc = raw.accessor<double, 2>();
    int64_t row = 0;
    for (std::size_t i = begin; i < end; ++i) {
      const Cluster& c = *nonempty[i];
      MatrixXcd W(L, c.size());
      for (int k = 0; k < c.size(); ++k, ++row)
        for (int l = 0; l < L; ++l) W(l, k) = cdouble(acc[row][l], acc[row][L + l]);
      out[where[i]] = impl_->finish(c, std::move(W));
    }
  });
  return out;
}

std::vector<MatrixXcd> LearnedBeamformer::design_fast(const std::vector<const Cluster*>& nonempty,
                                                      const std::vector<std::size_t>& where, std::vector<MatrixXcd> out,
                                                      int threads) const {
  // One fused pass per slice of the batch; slices of at least kSlice clusters (a few hundred
  // microseconds of work, against a few microseconds to hand one over) go to the threads.
  constexpr std::size_t kSlice = 8;
  const std::size_t slices = std::max<std::size_t>(
      1, std::min<std::size_t>(static_cast<std::size_t>(resolve_threads(threads)), nonempty.size() / kSlice));
  // A slice is passed in pieces of at most 16,384 users: the activations a pass holds (about 5 KB
  // a user row, kept by the thread for the next pass) stay bounded, with the same floats.
  parallel_for(slices, static_cast<int>(slices), [&](std::size_t i) {
    std::vector<const Cluster*> part;
    in_pieces(nonempty, nonempty.size() * i / slices, nonempty.size() * (i + 1) / slices, 16384, [&](std::size_t begin, std::size_t end) {
      part.assign(nonempty.begin() + static_cast<std::ptrdiff_t>(begin), nonempty.begin() + static_cast<std::ptrdiff_t>(end));
      auto raw = impl_->fast->forward(part);
      for (std::size_t j = begin; j < end; ++j) out[where[j]] = impl_->finish(*nonempty[j], std::move(raw[j - begin]));
    });
  });
  return out;
}

bool LearnedBeamformer::fast() const { return impl_->fast != nullptr; }

namespace {
/// The configuration a model directory's own serving settings (DIR/serve.toml, optional) give on
/// top of `cfg`: a model validated with, say, nn.selection = "ranked" is served that way when it
/// is named by its directory. Only the serving keys nn.selection and nn.precision may appear.
Config served_as_its_directory_says(const Config& cfg, const std::filesystem::path& dir) {
  const auto file = dir / "serve.toml";
  if (!std::filesystem::exists(file)) return cfg;
  Config serving = cfg;
  apply_toml(serving, read_file(file.string(), "serving settings"), file.string());
  Config others = serving;
  others.nn.selection = cfg.nn.selection, others.nn.precision = cfg.nn.precision;
  if (to_toml(others) != to_toml(cfg))
    throw InputError(file.string() + " sets more than the model's serving: allowed nn.selection and nn.precision only");
  return serving;
}
}  // namespace

void register_learned_beamformers(BeamformerRegistry& reg, const std::string& models_dir) {
  for (const std::string& n : learned_beamformer_names()) {
    reg.add(n, learned_beamformer_description(n),
            [n, models_dir](const Config& cfg, const std::string& arg) {
              namespace fs = std::filesystem;
              const std::string root = models_dir.empty() ? (fs::path(data_dir()) / "models").string() : models_dir;
              std::string path = arg.empty() ? (fs::path(root) / n / "model.pt").string() : arg;
              // A relative path that is not there from here, but is one of the shipped files
              // ("models/gnn_structured"), names the shipped one: the docs' specs then work from
              // any directory, and from an installed package.
              if (!arg.empty() && fs::path(arg).is_relative() && !fs::exists(arg) && fs::exists(fs::path(data_dir()) / arg))
                path = (fs::path(data_dir()) / arg).string();
              Config serving = cfg;
              if (fs::is_directory(path)) {  // named by its directory: served as the directory says
                serving = served_as_its_directory_says(cfg, path);
                path = (fs::path(path) / "model.pt").string();
              }
              auto bf = LearnedBeamformer::load(path, serving);
              if (bf->info().model != n)
                throw InputError("method '" + n + "=" + arg + "' names a " + bf->info().model + " checkpoint: allowed a " + n + " model");
              return bf;
            });
  }
}

}  // namespace skyloop
