#include "skyloop/experiments/snapshot_report.hpp"

#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

Snapshot load_scenario_file(const std::string& path, const Config& cfg) {
  const auto lists = read_point_lists(read_file(path, "scenario file"), path, {"uavs", "users"});
  return Snapshot{positions_in_area(lists[0], cfg, path + ": uavs"), positions_in_area(lists[1], cfg, path + ": users")};
}

SnapshotReport evaluate_snapshot(const Config& cfg, const Snapshot& s, const Beamformer& bf) {
  const SystemModel model(cfg);
  const Association a = model.associate(s);
  SnapshotReport r;
  r.method = bf.name();
  r.users.resize(static_cast<std::size_t>(s.users.rows()));
  for (Eigen::Index k = 0; k < s.users.rows(); ++k) {
    UserReport& u = r.users[static_cast<std::size_t>(k)];
    u.index = static_cast<int>(k);
    u.x = s.users(k, 0);
    u.y = s.users(k, 1);
    u.serving_uav = a.serving[static_cast<std::size_t>(k)];
    double nearest = INFINITY;
    for (Eigen::Index n = 0; n < s.uavs.rows(); ++n) {
      u.links.push_back(model.channel_model().link(s.uavs(n, 0), s.uavs(n, 1), model.altitude_of(s.uavs, n), u.x, u.y));
      if (u.links.back().geometry.distance_m < nearest) {  // the serving UAV is the nearest one
        nearest = u.links.back().geometry.distance_m;
        u.path_loss_db = u.links.back().path_loss_db;
      }
    }
    u.distance_m = nearest;
  }
  for (Eigen::Index k = 0; k < s.users.rows(); ++k)
    for (Eigen::Index n = 0; n < s.uavs.rows(); ++n)
      r.users[static_cast<std::size_t>(k)].cross.push_back(model.channel_model().channel_at(s.uavs(n, 0), s.uavs(n, 1), model.altitude_of(s.uavs, n), s.users(k, 0), s.users(k, 1)));
  const Network net = model.network(s, a);
  const std::vector<MatrixXcd> W = bf.design_network(net);
  check_network_output(bf, net, W);
  const auto powers = user_powers(net, W);
  r.spectrum = name_of(net.spectrum);
  for (Eigen::Index n = 0; n < s.uavs.rows(); ++n) {
    ClusterReport c;
    c.uav = static_cast<int>(n);
    c.x = s.uavs(n, 0);
    c.y = s.uavs(n, 1);
    c.users = a.users[static_cast<std::size_t>(n)];
    r.uavs.push_back(std::move(c));
  }
  for (std::size_t i = 0; i < net.clusters.size(); ++i) {
    const Cluster& cl = net.clusters[i];
    ClusterReport& c = r.uavs[static_cast<std::size_t>(cl.uav)];
    for (std::size_t j = 0; j < cl.users.size(); ++j) {
      UserReport& u = r.users[static_cast<std::size_t>(cl.users[j])];
      const auto jj = static_cast<Eigen::Index>(j);
      u.channel = cl.G.row(jj).adjoint();
      u.beamformer = W[i].col(jj);
      u.powers = powers[i][j];
      u.sinr = u.powers.sinr();
      u.rate = cl.bandwidth * std::log2(1.0 + u.sinr);
      c.sum_rate += u.rate;
    }
    c.power_w = transmit_power(W[i]);
  }
  for (const auto& c : r.uavs) r.total_sum_rate += c.sum_rate;
  return r;
}

std::string snapshot_json(const SnapshotReport& r, const Config& cfg) {
  using nlohmann::json;
  auto cvec = [](const VectorXcd& v) {
    json a = json::array();
    for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back({v[i].real(), v[i].imag()});
    return a;
  };
  json j;
  j["method"] = r.method;
  j["spectrum"] = r.spectrum;
  j["units"] = {{"position", "m"}, {"rate", "bit/s/Hz"}, {"power", "W"}, {"complex", "[re, im]"}};
  j["settings"] = {{"antennas", cfg.channel.antennas},       {"altitude_m", cfg.scenario.altitude_m},
                   {"p_max_dbm", cfg.channel.p_max_dbm},     {"noise_dbm", cfg.channel.noise_dbm},
                   {"coverage_radius_m", cfg.channel.coverage_radius_m},
                   {"power_scaling", name_of(cfg.beamforming.power_scaling)}, {"spectrum", name_of(cfg.channel.spectrum)},
                   {"pathloss", cfg.channel.pathloss}, {"fading", cfg.channel.fading}, {"fast_slots", cfg.channel.fast_slots}};
  j["users"] = json::array();
  for (const auto& u : r.users) {
    json ju = {{"index", u.index}, {"x", u.x}, {"y", u.y}, {"distance_m", u.distance_m}, {"path_loss_db", u.path_loss_db}};
    ju["serving_uav"] = u.serving_uav >= 0 ? json(u.serving_uav) : json(nullptr);
    ju["channel"] = cvec(u.channel);
    ju["beamformer"] = cvec(u.beamformer);
    ju["sinr"] = u.sinr;
    ju["sinr_db"] = u.serving_uav >= 0 && u.sinr > 0 ? json(linear_to_db(u.sinr)) : json(nullptr);
    ju["rate"] = u.rate;
    ju["signal_w"] = u.powers.signal;
    ju["intra_interference_w"] = u.powers.intra;
    ju["inter_interference_w"] = u.powers.inter;
    ju["noise_w"] = u.powers.noise;
    json cross = json::array();
    for (const auto& h : u.cross) cross.push_back(cvec(h));
    ju["cross_channels"] = cross;  // h_{m,k} from every UAV m, in UAV order
    json links = json::array();
    for (std::size_t m = 0; m < u.links.size(); ++m) {
      json jl = {{"uav", m}};
      for (const auto& [name, value] : link_fields(u.links[m])) {
        if (name == "los") jl[name] = value != 0.0;
        else if (std::isinf(value)) jl[name] = value > 0 ? "inf" : "-inf";  // K without fading / of a Rayleigh link
        else jl[name] = value;
      }
      jl["channel"] = cvec(u.cross[m]);
      links.push_back(std::move(jl));
    }
    ju["links"] = links;  // the large-scale state of the link from every UAV, beside its channel
    j["users"].push_back(ju);
  }
  j["clusters"] = json::array();
  for (const auto& c : r.uavs)
    j["clusters"].push_back({{"uav", c.uav}, {"x", c.x}, {"y", c.y}, {"users", c.users}, {"power_w", c.power_w},
                             {"sum_rate", c.sum_rate}});
  j["total_sum_rate"] = r.total_sum_rate;
  return j.dump(2) + "\n";
}

std::string snapshot_text(const SnapshotReport& r) {
  const auto db = [](double w) { return w > 0 ? fmt::format("{:.2f}", linear_to_db(w) + 30.0) : std::string("-"); };
  std::string out = fmt::format("method: {}\nspectrum: {}\n\n{:>4} {:>8} {:>8} {:>6} {:>10} {:>10} {:>10} {:>11} {:>11} {:>8}\n",
                                r.method, r.spectrum, "user", "x", "y", "uav", "dist (m)", "PL (dB)", "SINR (dB)",
                                "intra (dBm)", "inter (dBm)", "rate");
  for (const auto& u : r.users)
    out += fmt::format("{:>4} {:>8.2f} {:>8.2f} {:>6} {:>10.2f} {:>10.2f} {:>10} {:>11} {:>11} {:>8.4f}\n", u.index, u.x,
                       u.y, u.serving_uav >= 0 ? std::to_string(u.serving_uav) : "-", u.distance_m, u.path_loss_db,
                       u.serving_uav < 0 ? "-" : u.sinr > 0 ? fmt::format("{:.2f}", linear_to_db(u.sinr)) : "off",
                       u.serving_uav < 0 ? "-" : db(u.powers.intra), u.serving_uav < 0 ? "-" : db(u.powers.inter), u.rate);
  // The vectors themselves: h_k (the user's channel from its serving UAV) and w_k (its beam).
  const auto vec = [](const VectorXcd& v) {
    std::string s = "[";
    for (Eigen::Index i = 0; i < v.size(); ++i)
      s += fmt::format("{}{:.4e}{:+.4e}j", i ? ", " : "", v[i].real(), v[i].imag());
    return s + "]";
  };
  out += "\nper-user vectors (complex, a+bj; h_k from the serving UAV, w_k its beamformer):\n";
  for (const auto& u : r.users) {
    if (u.serving_uav < 0) {
      out += fmt::format("{:>4}  unserved\n", u.index);
      continue;
    }
    out += fmt::format("{:>4}  h = {}\n      w = {}\n", u.index, vec(u.channel), vec(u.beamformer));
  }
  out += fmt::format("\n{:>4} {:>8} {:>8} {:>10} {:>12} {:>10}\n", "uav", "x", "y", "users", "power (W)", "sum rate");
  for (const auto& c : r.uavs)
    out += fmt::format("{:>4} {:>8.2f} {:>8.2f} {:>10} {:>12.6g} {:>10.4f}\n", c.uav, c.x, c.y, c.users.size(),
                       c.power_w, c.sum_rate);
  out += fmt::format("\ntotal sum rate: {:.4f} bit/s/Hz\n", r.total_sum_rate);
  return out;
}

}  // namespace skyloop
