#include "checkpoint.hpp"

#include "archive.hpp"

#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::nn {

std::int64_t count_parameters(const torch::nn::Module& m) {
  std::int64_t n = 0;
  for (const auto& p : m.parameters()) n += p.numel();
  return n;
}

const ArchiveKind& checkpoint_kind() {
  static const ArchiveKind k{"checkpoint", "a model.pt written by `skyloop beamform train`", kCheckpointFormat,
                             kCheckpointVersion};
  return k;
}

void save_checkpoint(const std::string& path, const ModelInfo& info, const TrainingState& state, BeamNetImpl& model,
                     torch::optim::Optimizer* optimizer) {
  nlohmann::json meta = {{"model", info.model},             {"antennas", info.antennas},
                         {"hidden", info.hidden},           {"layers", info.layers}, {"readout", name_of(info.readout)},
                         {"feature_scale", info.feature_scale}, {"parameters", info.parameters},
                         {"epoch", state.epoch},            {"step", state.step},
                         {"best_epoch", state.best_epoch},  {"best_val_sum_rate", state.best_val},
                         {"config", info.config_toml}};
  if (info.features != Features::Linear) meta["features"] = name_of(info.features);  // absent: linear (files before it)
  torch::serialize::OutputArchive archive;
  torch::serialize::OutputArchive params;
  model.save(params);
  archive.write("model", params);
  if (optimizer) {
    torch::serialize::OutputArchive opt;
    optimizer->save(opt);
    archive.write("optimizer", opt);
  }
  write_archive(path, checkpoint_kind(), meta, archive);
}

LoadedCheckpoint load_checkpoint(const std::string& path, const torch::Device& device,
                                 torch::optim::Optimizer* optimizer_to_fill) {
  auto opened = open_archive(path, checkpoint_kind());
  auto& archive = opened.archive;
  const nlohmann::json& meta = opened.meta;
  LoadedCheckpoint out;
  try {
    out.info.model = meta.at("model").get<std::string>();
    out.info.antennas = meta.at("antennas").get<int>();
    out.info.hidden = meta.at("hidden").get<int>();
    out.info.layers = meta.at("layers").get<int>();
    out.info.readout = parse_choice<Readout>("the checkpoint's readout", meta.value("readout", std::string("direct")));
    out.info.features = parse_choice<Features>("the checkpoint's features", meta.value("features", std::string("linear")));
    out.info.feature_scale = meta.at("feature_scale").get<double>();
    out.info.parameters = meta.at("parameters").get<std::int64_t>();
    out.info.config_toml = meta.at("config").get<std::string>();
    out.state.epoch = meta.at("epoch").get<int>();
    out.state.step = meta.at("step").get<std::int64_t>();
    out.state.best_epoch = meta.at("best_epoch").get<int>();
    out.state.best_val = meta.at("best_val_sum_rate").get<double>();
  } catch (const std::exception& e) {
    throw InputError("checkpoint '" + path + "' has an incomplete header: " + e.what());
  }
  out.info.epoch = out.state.epoch;
  out.info.best_val_sum_rate = out.state.best_val;
  try {
    out.model = make_model(out.info.model, out.info.antennas, out.info.hidden, out.info.layers,
                           out.info.readout);
    out.model->set_features(out.info.features);
    torch::serialize::InputArchive params;
    archive.read("model", params);
    out.model->load(params);
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    std::string what = e.what();
    what = what.substr(0, what.find('\n'));
    throw InputError("checkpoint '" + path + "' does not match its header (" + out.info.model + "): " + what);
  }
  out.model->to(device);
  torch::serialize::InputArchive opt;
  out.has_optimizer = archive.try_read("optimizer", opt);
  if (optimizer_to_fill && out.has_optimizer) optimizer_to_fill->load(opt);
  return out;
}

void load_optimizer(const std::string& path, torch::optim::Optimizer& optimizer) {
  auto archive = open_archive(path, checkpoint_kind()).archive;
  torch::serialize::InputArchive opt;
  if (!archive.try_read("optimizer", opt)) throw InputError("checkpoint '" + path + "' holds no optimiser state: cannot resume from it");
  optimizer.load(opt);
}

}  // namespace skyloop::nn
