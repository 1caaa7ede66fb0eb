#include "checkpoint.hpp"

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

void save_checkpoint(const std::string& path, const ModelInfo& info, const TrainingState& state, BeamNetImpl& model,
                     torch::optim::Optimizer* optimizer) {
  nlohmann::json meta = {{"format", kCheckpointFormat},     {"version", kCheckpointVersion},
                         {"model", info.model},             {"antennas", info.antennas},
                         {"hidden", info.hidden},           {"layers", info.layers}, {"readout", info.readout},
                         {"feature_scale", info.feature_scale}, {"parameters", info.parameters},
                         {"epoch", state.epoch},            {"step", state.step},
                         {"best_epoch", state.best_epoch},  {"best_val_sum_rate", state.best_val},
                         {"config", info.config_toml}};
  torch::serialize::OutputArchive archive;
  archive.write("skyloop_meta", c10::IValue(meta.dump()));
  torch::serialize::OutputArchive params;
  model.save(params);
  archive.write("model", params);
  if (optimizer) {
    torch::serialize::OutputArchive opt;
    optimizer->save(opt);
    archive.write("optimizer", opt);
  }
  std::ostringstream bytes;
  archive.save_to(bytes);
  write_file_atomic(path, bytes.str());
}

namespace {

torch::serialize::InputArchive open_archive(const std::string& path) {
  if (!std::filesystem::is_regular_file(path))
    throw InputError("checkpoint '" + path + "' does not exist: allowed a model.pt written by `skyloop beamform train`");
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(path);
  } catch (const std::exception&) {
    throw InputError("checkpoint '" + path + "' is corrupt or not a torch archive: allowed a model.pt written by `skyloop beamform train`");
  }
  return archive;
}

}  // namespace

LoadedCheckpoint load_checkpoint(const std::string& path, const torch::Device& device,
                                 torch::optim::Optimizer* optimizer_to_fill) {
  auto archive = open_archive(path);
  c10::IValue raw;
  if (!archive.try_read("skyloop_meta", raw) || !raw.isString())
    throw InputError("checkpoint '" + path + "' has no skyloop header: allowed a model.pt written by `skyloop beamform train`");
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(raw.toStringRef());
  } catch (const std::exception&) {
    throw InputError("checkpoint '" + path + "' has a corrupt header");
  }
  if (meta.value("format", "") != kCheckpointFormat)
    throw InputError("checkpoint '" + path + "' has format '" + meta.value("format", "") + "': allowed " + kCheckpointFormat);
  if (meta.value("version", 0) != kCheckpointVersion)
    throw InputError("checkpoint '" + path + "' has version " + std::to_string(meta.value("version", 0)) +
                     ": allowed " + std::to_string(kCheckpointVersion));
  LoadedCheckpoint out;
  try {
    out.info.model = meta.at("model").get<std::string>();
    out.info.antennas = meta.at("antennas").get<int>();
    out.info.hidden = meta.at("hidden").get<int>();
    out.info.layers = meta.at("layers").get<int>();
    out.info.readout = meta.value("readout", std::string("direct"));
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
                           parse_readout(out.info.readout));
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
  auto archive = open_archive(path);
  torch::serialize::InputArchive opt;
  if (!archive.try_read("optimizer", opt)) throw InputError("checkpoint '" + path + "' holds no optimiser state: cannot resume from it");
  optimizer.load(opt);
}

}  // namespace skyloop::nn
