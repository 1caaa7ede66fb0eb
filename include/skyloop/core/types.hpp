#pragma once
// Basic value types shared by every stage. Eigen and std only.
#include <Eigen/Dense>
#include <complex>
#include <vector>

namespace skyloop {

using cdouble = std::complex<double>;
using VectorXcd = Eigen::VectorXcd;
using MatrixXcd = Eigen::MatrixXcd;
using VectorXd = Eigen::VectorXd;

/// Horizontal positions, one entity per row: [rows x 2] real, row i = (x_i, y_i) in metres.
/// UAVs fly at the scenario altitude H; users stand on the ground (z = 0).
using Positions = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

struct Point2 {
  double x = 0.0;
  double y = 0.0;
  friend bool operator==(const Point2& a, const Point2& b) { return a.x == b.x && a.y == b.y; }
  friend bool operator!=(const Point2& a, const Point2& b) { return !(a == b); }
};

/// dBm -> Watt and dB -> linear ratio.
inline double dbm_to_watt(double dbm) { return std::pow(10.0, (dbm - 30.0) / 10.0); }
inline double db_to_linear(double db) { return std::pow(10.0, db / 10.0); }
inline double linear_to_db(double x) { return 10.0 * std::log10(x); }

}  // namespace skyloop
