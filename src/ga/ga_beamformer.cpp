#include "skyloop/beamforming/ga.hpp"

#include <algorithm>
#include <cmath>
#include <pagmo/algorithm.hpp>
#include <pagmo/algorithms/bee_colony.hpp>
#include <pagmo/algorithms/cmaes.hpp>
#include <pagmo/algorithms/de.hpp>
#include <pagmo/algorithms/gwo.hpp>
#include <pagmo/algorithms/pso.hpp>
#include <pagmo/algorithms/sade.hpp>
#include <pagmo/algorithms/sga.hpp>
#include <pagmo/algorithms/xnes.hpp>
#include <pagmo/population.hpp>
#include <pagmo/problem.hpp>

#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {
namespace {

/// Sum rate of one cluster as a pagmo user-defined problem (minimised: fitness = -sum rate).
struct SumRateProblem {
  MatrixXcd G;   // [K x L]
  double p_max = 1.0;
  double noise = 1.0;
  PowerScaling scaling = PowerScaling::Full;

  Eigen::Index K() const { return G.rows(); }
  Eigen::Index L() const { return G.cols(); }

  /// Scale factor a such that W = a * X meets the budget; X = x as [L x K] complex.
  double alpha(const pagmo::vector_double& x) const {
    double norm2 = 0.0;
    for (double v : x) norm2 += v * v;
    if (norm2 <= 0.0) return 0.0;
    // W = sqrt(P) X s with s = 1 / ||X|| (full) or min(1, 1 / ||X||) (cap).
    const double s = 1.0 / std::sqrt(norm2);
    return std::sqrt(p_max) * (scaling == PowerScaling::Cap ? std::min(1.0, s) : s);
  }

  MatrixXcd to_w(const pagmo::vector_double& x) const {
    const Eigen::Index n = L() * K();
    MatrixXcd W(L(), K());
    for (Eigen::Index i = 0; i < n; ++i) W.data()[i] = cdouble(x[static_cast<std::size_t>(i)], x[static_cast<std::size_t>(n + i)]);
    return W * alpha(x);
  }

  pagmo::vector_double fitness(const pagmo::vector_double& x) const {
    const double a2 = [&] { const double a = alpha(x); return a * a; }();
    const Eigen::Index k_users = K(), l_ant = L(), n = l_ant * k_users;
    double total = 0.0;
    for (Eigen::Index k = 0; k < k_users; ++k) {
      double signal = 0.0, interference = 0.0;
      for (Eigen::Index j = 0; j < k_users; ++j) {
        cdouble m(0.0, 0.0);  // g_k x_j
        for (Eigen::Index l = 0; l < l_ant; ++l) {
          const auto idx = static_cast<std::size_t>(l + l_ant * j);
          m += G(k, l) * cdouble(x[idx], x[static_cast<std::size_t>(n) + idx]);
        }
        (j == k ? signal : interference) += std::norm(m);
      }
      total += std::log2(1.0 + a2 * signal / (a2 * interference + noise));
    }
    return {-total};
  }

  std::pair<pagmo::vector_double, pagmo::vector_double> get_bounds() const {
    const auto dim = static_cast<std::size_t>(2 * L() * K());
    return {pagmo::vector_double(dim, -1.0), pagmo::vector_double(dim, 1.0)};
  }
  std::string get_name() const { return "skyloop cluster sum rate"; }
};

pagmo::algorithm make_algorithm(const GaOptions& o, std::size_t dim, unsigned seed) {
  const auto gen = static_cast<unsigned>(o.generations);
  switch (o.algorithm) {
    case GaAlgorithm::Sga:
      return pagmo::algorithm(pagmo::sga(gen, 0.9, 15.0, 1.0 / static_cast<double>(dim), 20.0, 2u, "sbx",
                                         "polynomial", "tournament", seed));
    case GaAlgorithm::De: return pagmo::algorithm(pagmo::de(gen, 0.8, 0.9, 2u, 1e-12, 1e-12, seed));
    case GaAlgorithm::Sade: return pagmo::algorithm(pagmo::sade(gen, 2u, 1u, 1e-12, 1e-12, false, seed));
    case GaAlgorithm::Pso: return pagmo::algorithm(pagmo::pso(gen, 0.7298, 2.05, 2.05, 0.5, 5u, 2u, 4u, false, seed));
    case GaAlgorithm::Cmaes:
      return pagmo::algorithm(pagmo::cmaes(gen, -1, -1, -1, -1, 0.5, 1e-12, 1e-12, false, true, seed));
    case GaAlgorithm::Xnes: return pagmo::algorithm(pagmo::xnes(gen, -1, -1, -1, -1, 1e-12, 1e-12, false, true, seed));
    case GaAlgorithm::Gwo: return pagmo::algorithm(pagmo::gwo(gen, seed));
    case GaAlgorithm::BeeColony: return pagmo::algorithm(pagmo::bee_colony(gen, 20u, seed));
  }
  throw std::logic_error("make_algorithm: an enumerator without a case");
}

}  // namespace

GaBeamformer::GaBeamformer(GaOptions opt) : opt_(std::move(opt)) {
  if (opt_.population < 8)
    throw InputError("ga.population = " + std::to_string(opt_.population) + " is out of range: allowed >= 8");
  if (opt_.generations < 1)
    throw InputError("ga.generations = " + std::to_string(opt_.generations) + " is out of range: allowed >= 1");
}

MatrixXcd GaBeamformer::design(const Cluster& c) const {
  if (c.G.rows() == 0) return MatrixXcd(c.G.cols(), 0);
  SumRateProblem udp{c.G, c.p_max, c.noise, opt_.scaling};
  const auto seed = derive_seed(opt_.seed, cluster_hash(c));
  const auto pop_seed = static_cast<unsigned>(seed & 0xffffffffu);
  const auto algo_seed = static_cast<unsigned>(seed >> 32);
  pagmo::problem prob(udp);
  pagmo::population pop(prob, static_cast<pagmo::population::size_type>(opt_.population), pop_seed);
  pagmo::algorithm algo = make_algorithm(opt_, prob.get_nx(), algo_seed);
  pop = algo.evolve(pop);
  return udp.to_w(pop.champion_x());
}

void register_ga_beamformers(BeamformerRegistry& reg) {
  reg.add("ga", "pagmo2 global optimiser (default sga = the paper's GA); 'ga=pso' etc. picks another",
          [](const Config& cfg, const std::string& arg) {
            GaOptions o{arg.empty() ? cfg.ga.algorithm : parse_choice<GaAlgorithm>("ga=NAME's NAME", arg), cfg.ga.population, cfg.ga.generations, cfg.run.seed,
                        cfg.beamforming.power_scaling};
            return std::make_unique<GaBeamformer>(o);
          });
}

}  // namespace skyloop
