#pragma once
// The air-to-ground path-loss models skyloop knows: one table, read by the configuration's allowed
// values, the CLI's help, Python and the channel model (channel_model.hpp). Each model gives, for a
// link of geometry (d_2D, d_3D, UAV height h, elevation theta), its LoS probability P_LoS, its mean
// path loss in each state and the shadowing spread in each state. Dependency-free.
//
//   free-space   the paper: beta = beta0 (d0 / d_3D)^2, always LoS, no shadowing.
//   3gpp-uma-av  3GPP TR 36.777 Annex B, urban macro, aerial end at 22.5 m < h <= 300 m,
//   3gpp-umi-av  urban micro, 22.5 m < h <= 300 m,     d_2D <= 4 km (UMa, UMi)
//   3gpp-rma-av  rural macro, 10 m < h <= 300 m,       d_2D <= 10 km
//                (Table B-1 P_LoS, Table B-2 LoS / NLoS path loss, Table B-3 shadowing std).
//   al-hourani   Al-Hourani, Kandeepan, Lardner, IEEE WCL 2014: P_LoS = 1 / (1 + a exp(-b (theta - a)))
//                with theta in degrees; path loss = 20 log10(4 pi d_3D f_c / c) + eta_LoS or eta_NLoS
//                (mean excess losses; the source gives no shadowing spread, so none is drawn).
// The UAV is the aerial end (TR 36.777's h_UT is the UAV's altitude), the user the ground end.
#include <array>
#include <string>
#include <string_view>

namespace skyloop {

struct PathLossInfo {
  std::string_view name;
  std::string_view description;
  double min_height_m, max_height_m;  // the UAV altitude the formulas hold for (exclusive, inclusive)
  double max_horizontal_m;            // the largest d_2D they hold for (0: no limit)
};

inline constexpr std::array<PathLossInfo, 5> kPathLossModels{{
    {"free-space", "the paper: beta0 (d0/d)^2, line of sight everywhere", 0, 1e300, 0},
    {"3gpp-uma-av", "3GPP TR 36.777 urban macro, aerial UAV (22.5 m < H <= 300 m, d_2D <= 4 km)", 22.5, 300, 4000},
    {"3gpp-umi-av", "3GPP TR 36.777 urban micro, aerial UAV (22.5 m < H <= 300 m, d_2D <= 4 km)", 22.5, 300, 4000},
    {"3gpp-rma-av", "3GPP TR 36.777 rural macro, aerial UAV (10 m < H <= 300 m, d_2D <= 10 km)", 10, 300, 10000},
    {"al-hourani", "Al-Hourani et al. (IEEE WCL 2014): sigmoid P_LoS in elevation, excess losses over free space", 0, 1e300, 0},
}};

/// Al-Hourani et al.'s environments (IEEE WCL 2014, Table I, at 2 GHz): the S-curve parameters a
/// and b (theta in degrees), the mean excess losses eta_LoS and eta_NLoS (dB) over free space, and
/// the elevation that maximises coverage in their paper (degrees), against which skyloop's
/// rate-optimal altitude is compared.
struct AirToGroundEnvironment {
  std::string_view name;
  double a, b, eta_los_db, eta_nlos_db, optimal_elevation_deg;
};

inline constexpr std::array<AirToGroundEnvironment, 4> kAlHouraniEnvironments{{
    {"suburban", 4.88, 0.43, 0.1, 21.0, 20.34},
    {"urban", 9.61, 0.16, 1.0, 20.0, 42.44},
    {"dense-urban", 12.08, 0.11, 1.6, 23.0, 54.62},
    {"highrise-urban", 27.23, 0.08, 2.3, 34.0, 75.52},
}};

inline const PathLossInfo* find_path_loss(std::string_view name) {
  for (const auto& m : kPathLossModels)
    if (m.name == name) return &m;
  return nullptr;
}

inline const AirToGroundEnvironment* find_environment(std::string_view name) {
  for (const auto& e : kAlHouraniEnvironments)
    if (e.name == name) return &e;
  return nullptr;
}

}  // namespace skyloop
