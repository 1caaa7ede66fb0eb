#pragma once
// The air-to-ground path-loss models skyloop knows: one registry (path_loss_models(), its rows in
// channel_model.cpp beside the models), read by the configuration's allowed values, the CLI's help,
// Python and the channel model (channel_model.hpp). Each model gives, for a
// link of geometry (d_2D, d_3D, UAV height h, elevation theta), its LoS probability P_LoS, its mean
// path loss in each state and the shadowing spread in each state.
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
#include <memory>
#include <string>
#include <string_view>

#include "skyloop/core/registry.hpp"

namespace skyloop {

class PathLossModel;   // channel_model.hpp
struct ChannelConfig;  // core/config.hpp

/// A path-loss model's row: where its formulas hold, and its factory (from channel.carrier_ghz,
/// channel.environment, ...).
struct PathLossInfo {
  double min_height_m, max_height_m;  // the UAV altitude the formulas hold for (exclusive, inclusive)
  double max_horizontal_m;            // the largest d_2D they hold for (0: no limit)
  std::unique_ptr<PathLossModel> (*make)(const ChannelConfig&);
};

/// Every model, the paper's first: channel.pathloss's allowed values and their help.
const Registry<PathLossInfo>& path_loss_models();

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

inline const PathLossInfo* find_path_loss(const std::string& name) {
  const auto* row = path_loss_models().find(name);
  return row ? &row->entry : nullptr;
}

inline const AirToGroundEnvironment* find_environment(std::string_view name) {
  for (const auto& e : kAlHouraniEnvironments)
    if (e.name == name) return &e;
  return nullptr;
}

}  // namespace skyloop
