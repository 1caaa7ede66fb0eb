#include "skyloop/beamforming/registry.hpp"

#include <algorithm>

#include "skyloop/beamforming/coordinated.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/beamforming/wmmse.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/text.hpp"

namespace skyloop {

std::unique_ptr<Beamformer> BeamformerRegistry::create(const std::string& spec, const Config& cfg) const {
  const auto eq = spec.find('=');
  const std::string name = spec.substr(0, eq);
  const std::string arg = eq == std::string::npos ? "" : spec.substr(eq + 1);
  if (eq != std::string::npos && arg.empty())
    throw InputError("method '" + spec + "' has an empty argument after '=': allowed '" + name + "' or '" + name + "=ARG'");
  const Row* row = find(name);
  if (!row) throw InputError(unknown(spec));
  return row->entry(cfg, arg);
}

const std::vector<std::string>& learned_beamformer_names() {
  static const std::vector<std::string> names{"gnn", "deepsets", "mspointnet", "ignn"};
  return names;
}

std::string learned_beamformer_description(const std::string& name) {
  return "learned " + name + " beamformer; '" + name + "=PATH' loads PATH (model.pt or its directory)";
}

bool is_learned_beamformer(const std::string& spec) {
  const auto& names = learned_beamformer_names();
  return std::find(names.begin(), names.end(), spec.substr(0, spec.find('='))) != names.end();
}

void register_classical_beamformers(BeamformerRegistry& reg) {
  auto no_arg = [](const std::string& name, const std::string& arg) {
    if (!arg.empty()) throw InputError("method '" + name + "=" + arg + "' takes no argument: allowed '" + name + "'");
  };
  reg.add("mrt", "maximum ratio transmission, equal power", [no_arg](const Config&, const std::string& arg) {
    no_arg("mrt", arg);
    return std::make_unique<MrtBeamformer>();
  });
  reg.add("zf", "zero forcing (pseudo-inverse), beamforming.zf_power_allocation",
          [no_arg](const Config& cfg, const std::string& arg) {
            no_arg("zf", arg);
            return std::make_unique<ZfBeamformer>(cfg.beamforming.zf_power_allocation == PowerAllocation::WaterFilling);
          });
  reg.add("zfsel", "zero forcing with greedy user selection, water-filled", [no_arg](const Config&, const std::string& arg) {
    no_arg("zfsel", arg);
    return std::make_unique<ZfSelectBeamformer>();
  });
  reg.add("zfgain", "zero forcing, users joining in the order of their channel gain while the sum rate rises (one pass)",
          [no_arg](const Config&, const std::string& arg) {
            no_arg("zfgain", arg);
            return std::make_unique<ZfGainBeamformer>();
          });
  reg.add("rzf", "regularised zero forcing (MMSE precoder), full power", [no_arg](const Config&, const std::string& arg) {
    no_arg("rzf", arg);
    return std::make_unique<RzfBeamformer>();
  });
  reg.add("wmmse", "WMMSE sum-rate maximisation, [wmmse] settings", [no_arg](const Config& cfg, const std::string& arg) {
    no_arg("wmmse", arg);
    WmmseOptions opt{cfg.wmmse.tolerance, cfg.wmmse.max_iterations, cfg.wmmse.bisection_tolerance};
    return std::make_unique<WmmseBeamformer>(opt, cfg.wmmse.init, cfg.wmmse.restarts, cfg.run.seed,
                                             cfg.beamforming.power_scaling);
  });
  // Coordinated (network-level) beamformers: see beamforming/coordinated.hpp.
  const std::string starts = join(network_wmmse_starts());
  reg.add("nwmmse",
          "network WMMSE over all UAVs (interfering broadcast channel), per-UAV budgets, the best of its runs from "
          "every start (" + starts + "); 'nwmmse=czfsel' or 'nwmmse=crzf+czfsel' runs from those alone",
          [](const Config& cfg, const std::string& arg) {
            auto chosen = parse_network_wmmse_starts(arg);
            WmmseOptions opt{cfg.wmmse.tolerance, cfg.wmmse.max_iterations, cfg.wmmse.bisection_tolerance};
            auto start = std::make_shared<WmmseBeamformer>(opt, cfg.wmmse.init, cfg.wmmse.restarts, cfg.run.seed,
                                                           PowerScaling::Full);
            return std::make_unique<NetworkWmmseBeamformer>(opt, std::move(start), std::move(chosen));
          });
  reg.add("crzf", "coordinated RZF, regularised toward every served user of the network", [no_arg](const Config&, const std::string& arg) {
    no_arg("crzf", arg);
    return std::make_unique<CoordinatedRzfBeamformer>();
  });
  reg.add("czf", "coordinated ZF: ZF-SEL's users plus nulls toward the strongest other-cluster users", [no_arg](const Config&, const std::string& arg) {
    no_arg("czf", arg);
    return std::make_unique<CoordinatedZfBeamformer>();
  });
  reg.add("czfsel", "network ZF with greedy user selection: every active beam nulls every other active user, water-filled per UAV",
          [no_arg](const Config&, const std::string& arg) {
            no_arg("czfsel", arg);
            return std::make_unique<CoordinatedZfSelectBeamformer>();
          });
}

std::vector<std::string> split_methods(const std::string& list, const std::string& flag) {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (true) {
    const auto comma = list.find(',', start);
    std::string item = list.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (item.empty()) throw InputError(flag + " '" + list + "' has an empty item: allowed a comma-separated list of distinct names");
    if (std::find(out.begin(), out.end(), item) != out.end())
      throw InputError(flag + " '" + list + "' names '" + item + "' twice: allowed a comma-separated list of distinct names");
    out.push_back(item);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

}  // namespace skyloop
