#include <gtest/gtest.h>

#include "skyloop/channel/rates.hpp"

using namespace skyloop;

TEST(Rates, HandMadeTwoUserSinr) {
  // G rows are h_k^H. Take h_1 = [1, 0], h_2 = [1, 1] / sqrt(2) (real), w_1 = [1, 0], w_2 = [0, 2].
  Cluster c;
  c.G.resize(2, 2);
  c.G << 1, 0, 1 / std::sqrt(2.0), 1 / std::sqrt(2.0);
  c.noise = 0.5;
  c.p_max = 10;
  MatrixXcd W(2, 2);
  W << 1, 0, 0, 2;
  // user 1: signal |h1^H w1|^2 = 1, interference |h1^H w2|^2 = 0 -> SINR 1 / 0.5 = 2.
  // user 2: signal |h2^H w2|^2 = (2/sqrt2)^2 = 2, interference |h2^H w1|^2 = 1/2 -> 2 / (0.5 + 0.5) = 2.
  const VectorXd g = sinr(c, W);
  EXPECT_NEAR(g[0], 2.0, 1e-12);
  EXPECT_NEAR(g[1], 2.0, 1e-12);
  EXPECT_NEAR(sum_rate(c, W), 2 * std::log2(3.0), 1e-12);
  EXPECT_NEAR(transmit_power(W), 5.0, 1e-12);
}

TEST(Rates, ComplexPhasesUseConjugateTranspose) {
  // h = [1, j]: h^H w with w = [1, j] / sqrt 2 is (1 + 1) / sqrt 2 = sqrt 2 -> |.|^2 = 2.
  Cluster c;
  c.G.resize(1, 2);
  c.G << cdouble(1, 0), cdouble(0, -1);  // row = h^H
  c.noise = 1.0;
  MatrixXcd W(2, 1);
  W << cdouble(1, 0) / std::sqrt(2.0), cdouble(0, 1) / std::sqrt(2.0);
  EXPECT_NEAR(sinr(c, W)[0], 2.0, 1e-12);
}

TEST(Rates, EmptyClusterAddsZeroAndShapeIsChecked) {
  Cluster c;
  c.G.resize(0, 4);
  EXPECT_EQ(sum_rate(c, MatrixXcd(4, 0)), 0.0);
  Cluster d;
  d.G = MatrixXcd::Ones(2, 4);
  EXPECT_THROW(sinr(d, MatrixXcd::Ones(4, 3)), std::invalid_argument);
}

TEST(Rates, BatchEqualsSingle) {
  Cluster a, b;
  a.G = MatrixXcd::Random(3, 4);
  b.G = MatrixXcd::Random(2, 4);
  a.noise = b.noise = 0.1;
  const std::vector<MatrixXcd> W{MatrixXcd::Random(4, 3), MatrixXcd::Random(4, 2)};
  const auto r = sum_rates({a, b}, W);
  EXPECT_EQ(r[0], sum_rate(a, W[0]));
  EXPECT_EQ(r[1], sum_rate(b, W[1]));
}
