#pragma once
// Closed-form linear precoders. All three transmit at the full budget, ||W||_F^2 = P_max.
//
// MRT:  w_k = sqrt(P/K_n) h_k / ||h_k||                       (equal power per user)
// ZF:   directions v_k = column k of G^+ (= G^H (G G^H)^{-1} when G has full row rank), so
//       h_j^H v_k = 0 for j != k; w_k = sqrt(p_k) v_k / ||v_k||, and user k's SINR is
//       p_k / (sigma^2 ||v_k||^2).
//       Power: "waterfilling" (default) p_k = (mu - sigma^2 ||v_k||^2)^+ with sum p_k = P, the
//       sum-rate-optimal allocation for ZF directions; "equal" p_k = P / K_n.
//       When G is rank-deficient (K_n > L, or two users with the same angle cos(theta) = H/d,
//       whose LoS channels are parallel) interference cannot be nulled: skyloop then keeps the
//       pseudo-inverse directions (least-squares) with equal power, and the SINR counts the
//       residual interference. A cluster of more than 256 users (and more than L) takes
//       G^+ = ((G^H)^+)^H, O(K_n L^2) time and O(K_n L) memory instead of a K_n x K_n solve.
// ZF-SEL: ZF with greedy user selection (Dimic & Sidiropoulos 2005): starting from no user, add
//       the user that most raises the water-filled ZF sum rate of the selected set, while it
//       rises (at most L users); unselected users get w_k = 0. In this LoS model the users of a
//       cluster see angles cos(theta) in [H/R_c, 1], a narrow range, so G is badly conditioned
//       (condition numbers of 1e4 are common at K_n = L = 4) and dropping one user often beats
//       serving all; this is also WMMSE's default starting point.
// RZF:  W = c G^H (G G^H + (K_n sigma^2 / P) I)^{-1}, c scaling ||W||_F^2 to P (the MMSE
//       precoder); defined for every K_n.
#include "skyloop/beamforming/beamformer.hpp"

namespace skyloop {

MatrixXcd mrt(const Cluster& c);
MatrixXcd zf(const Cluster& c, bool waterfilling = true);
MatrixXcd rzf(const Cluster& c);
/// ZF with greedy user selection; `selected` (if given) receives the chosen users, ascending.
MatrixXcd zf_select(const Cluster& c, std::vector<int>* selected = nullptr);
/// ZF with user selection in a given order (`ranking`: users, best first, each at most once): one
/// pass that adds each user in turn while it raises the water-filled ZF sum rate of the selected
/// set (at most L users). O(K L^2) per cluster where ZF-SEL's greedy search costs O(K L^3) (each
/// candidate set's Cholesky factor grows by one row); with a good ranking it selects what ZF-SEL
/// selects. `selected` (if given) receives the kept users,
/// ascending.
MatrixXcd zf_ranked(const Cluster& c, const std::vector<int>& ranking, std::vector<int>* selected = nullptr);

/// Water-filling of `budget` over channels with noise-to-gain ratios `floor` (p_k = (mu - floor_k)^+).
VectorXd waterfill(const VectorXd& floor, double budget);

class MrtBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "mrt"; }
  MatrixXcd design(const Cluster& c) const override { return mrt(c); }
};

class ZfBeamformer final : public Beamformer {
 public:
  explicit ZfBeamformer(bool waterfilling = true) : waterfilling_(waterfilling) {}
  std::string name() const override { return "zf"; }
  MatrixXcd design(const Cluster& c) const override { return zf(c, waterfilling_); }

 private:
  bool waterfilling_;
};

class ZfSelectBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "zfsel"; }
  MatrixXcd design(const Cluster& c) const override { return zf_select(c); }
};

/// ZF-GAIN: zf_ranked in the order of the users' channel gains ||h_k|| (strongest first), the
/// ranking that needs no search and no learning; the control for the learned beamformers'
/// nn.selection = "ranked", which replaces this order with the network's.
class ZfGainBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "zfgain"; }
  MatrixXcd design(const Cluster& c) const override;
};

class RzfBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "rzf"; }
  MatrixXcd design(const Cluster& c) const override { return rzf(c); }
};

}  // namespace skyloop
