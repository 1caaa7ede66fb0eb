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

/// Positions, one entity per row, in metres: [rows x 2] (x_i, y_i) or [rows x 3] (x_i, y_i, z_i).
/// Users stand on the ground (two columns; their antennas at scenario.user_height_m). UAVs: the
/// environment's positions have three columns, z their altitude; two columns mean every UAV flies
/// at the scenario altitude H (scenario.altitude_m). Read a UAV's altitude with altitude_of.
using Positions = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Row n's altitude: its third column, or `fixed` (H) where the positions have two.
inline double altitude_of(const Positions& p, Eigen::Index n, double fixed) { return p.cols() > 2 ? p(n, 2) : fixed; }

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
