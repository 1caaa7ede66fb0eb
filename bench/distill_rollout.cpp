// Rollout distillation, an experiment (BENCHMARKS, "Distilling the rollout"): one step of
// approximate policy iteration on a trained discrete PPO policy. The policy flies as the base of
// the multiagent rollout (RolloutPlanner) on training layouts; each slot records every flying
// UAV's actor input, its allowed moves and the rollout's move; the actor is then fine-tuned on
// those moves by cross-entropy over the allowed moves, and the epoch that scores best on
// validation layouts (more missions complete, then a higher mean objective) is written as
// OUT/policy.pt, which `skyloop eval --policy OUT` flies like any trained policy.
//
//   skyloop_distill POLICY_DIR OUT_DIR LAYOUTS EPOCHS LEARNING_RATE [VAL_LAYOUTS=100] [THREADS=2] [FIRST=0]
//
// Training layouts are the train split's indices FIRST .. FIRST + LAYOUTS - 1 (layouts.hpp), never
// a validation or test layout. Seeded: the same arguments give the same policy.pt on one machine.
#include <torch/torch.h>

#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <iostream>
#include <string>
#include <vector>

#include "../src/marl/common.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"

using namespace skyloop;

namespace {

struct Sample {
  std::vector<float> input;
  ActionSet allowed = 0;
  int action = 0;
};

struct Score {
  double complete = 0, objective = 0;
  bool better_than(const Score& o) const { return complete != o.complete ? complete > o.complete : objective > o.objective; }
};

/// The deterministic policy at `path` on validation layouts 0 .. count - 1.
Score validate(const Config& cfg, std::shared_ptr<const Beamformer> bf, const std::string& path, int count, int threads) {
  std::vector<double> objective(static_cast<std::size_t>(count)), complete(static_cast<std::size_t>(count));
  parallel_for(static_cast<std::size_t>(count), threads, [&](std::size_t i) {
    UavEnv env(cfg, std::make_shared<RateOracle>(cfg, bf, layout_users(cfg, layout_seed(LayoutSplit::Validation, i))));
    auto policy = MarlPolicy::load(path);
    const auto rec = run_episode(env, *policy);
    objective[i] = rec.objective;
    complete[i] = rec.success && rec.collisions == 0 && rec.boundary == 0 ? 1.0 : 0.0;
  });
  Score s;
  for (int i = 0; i < count; ++i) s.objective += objective[static_cast<std::size_t>(i)] / count, s.complete += complete[static_cast<std::size_t>(i)] / count;
  return s;
}

/// Fine-tunes the actor (or a fresh student: DISTILL_HIDDEN) on the rollout's moves; writes the
/// epoch best on validation as OUT/policy.pt.
int finetune(const Config& cfg, std::shared_ptr<const Beamformer> bf, nlohmann::json meta, const std::string& in, const std::string& out_dir,
             int layouts, std::uint64_t first, int epochs, double lr, int val, int threads, const torch::Tensor& X, const torch::Tensor& allowed,
             const torch::Tensor& Y) {
  const auto S = X.size(0);
  const int D = static_cast<int>(X.size(1)), A = static_cast<int>(allowed.size(1));
    marl::Nets nets;
    const char* wide = std::getenv("DISTILL_HIDDEN");  // a fresh student of this width instead of the base's actor
    if (wide) {
      meta["hidden"] = std::stoi(wide);
      nets.actor = marl::MlpNet(D, meta.at("hidden").get<int>(), A);
    } else {
      nets.actor = marl::MlpNet(D, meta.at("hidden").get<int>(), A);
      marl::load(in, nets, nullptr);
    }
    {
      torch::NoGradGuard ng;
      const auto logits = nets.actor->forward(X).masked_fill(allowed.logical_not(), -1e9);
      std::cout << fmt::format("before: the actor's best allowed move is the rollout's in {:.2f}%\n",
                               100.0 * logits.argmax(1).eq(Y).sum().item<double>() / static_cast<double>(S));
    }
    torch::optim::Adam adam(nets.actor->parameters(), torch::optim::AdamOptions(lr));
    const std::string trial = (std::filesystem::path(out_dir) / "epoch.pt").string();
    const std::string best_path = (std::filesystem::path(out_dir) / "policy.pt").string();
    meta["distilled"] = {{"from", in}, {"layouts", layouts}, {"first", first}, {"epochs", epochs}, {"learning_rate", lr}};
    Score best = validate(cfg, bf, in, val, threads);
    marl::save(best_path, meta, nets, nullptr);
    std::cout << fmt::format("epoch 0 (the base policy): validation complete {:.2f}, objective {:.4f}\n", best.complete, best.objective);
    torch::manual_seed(static_cast<std::uint64_t>(cfg.run.seed));
    constexpr std::int64_t kBatch = 256;
    for (int epoch = 1; epoch <= epochs; ++epoch) {
      const auto order = torch::randperm(S, torch::kLong);
      double loss_sum = 0, hits = 0;
      int batches = 0;
      for (std::int64_t b = 0; b < S; b += kBatch) {
        const auto idx = order.slice(0, b, std::min(S, b + kBatch));
        const auto logits = nets.actor->forward(X.index_select(0, idx)).masked_fill(allowed.index_select(0, idx).logical_not(), -1e9);
        const auto y = Y.index_select(0, idx);
        const auto loss = torch::nn::functional::cross_entropy(logits, y);
        adam.zero_grad();
        loss.backward();
        adam.step();
        loss_sum += loss.item<double>();
        hits += logits.argmax(1).eq(y).sum().item<double>();
        ++batches;
      }
      marl::save(trial, meta, nets, nullptr);
      const Score s = validate(cfg, bf, trial, val, threads);
      const bool kept = s.better_than(best);
      if (kept) {
        best = s;
        std::filesystem::copy_file(trial, best_path, std::filesystem::copy_options::overwrite_existing);
      }
      std::cout << fmt::format("epoch {}: loss {:.4f}, the rollout's move {:.2f}%, validation complete {:.2f}, objective {:.4f}{}\n", epoch,
                               loss_sum / batches, 100.0 * hits / static_cast<double>(S), s.complete, s.objective, kept ? " (best)" : "")
              << std::flush;
    }
    std::filesystem::remove(trial);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    if (argc < 6) {
      std::cerr << "usage: skyloop_distill POLICY_DIR OUT_DIR LAYOUTS EPOCHS LEARNING_RATE [VAL_LAYOUTS] [THREADS] [FIRST]\n";
      return 2;
    }
    const std::string in = (std::filesystem::path(argv[1]) / "policy.pt").string(), out_dir = argv[2];
    const int layouts = std::stoi(argv[3]), epochs = std::stoi(argv[4]);
    const double lr = std::stod(argv[5]);
    const int val = argc > 6 ? std::stoi(argv[6]) : 100, threads = resolve_threads(argc > 7 ? std::stoi(argv[7]) : 2);
    const std::uint64_t first = argc > 8 ? std::stoull(argv[8]) : 0;
    std::filesystem::create_directories(out_dir);
    auto meta = marl::read_meta(in);
    Config cfg;
    apply_toml(cfg, meta.at("config").get<std::string>(), in);
    if (meta.value("dims", 0) != 0 || meta.value("algo", "") == "vdn" || meta.value("algo", "") == "qmix")
      throw InputError("skyloop_distill: allowed a discrete PPO policy (mappo, ippo)");
    auto bf = marl::make_oracle_beamformer(cfg, builtin_beamformers());
    const marl::Encoder enc = marl::encoder_of(cfg, false);
    const SafetyOptions safety = safety_options(cfg);
    set_torch_threads(1);

    // 1. The rollout's moves on the training layouts (or those kept by an earlier run: DISTILL_LOAD).
    if (const char* load = std::getenv("DISTILL_LOAD")) {
      std::vector<torch::Tensor> t;
      torch::load(t, load);
      return finetune(cfg, bf, meta, in, out_dir, layouts, first, epochs, lr, val, threads, t[0], t[1], t[2]);
    }
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<std::vector<Sample>> per(static_cast<std::size_t>(layouts));
    std::vector<int> agree(static_cast<std::size_t>(layouts), 0);
    parallel_for(static_cast<std::size_t>(layouts), threads, [&](std::size_t i) {
      UavEnv env(cfg, std::make_shared<RateOracle>(cfg, bf, layout_users(cfg, layout_seed(LayoutSplit::Train, first + i))));
      RolloutPlanner rollout(MarlPolicy::load(in));
      auto plain = MarlPolicy::load(in);
      env.reset();
      rollout.reset(env);
      plain->reset(env);
      const int D = enc.width(env);
      while (!env.done()) {
        const auto base = plain->act(env);
        const auto a = rollout.act(env);
        if (enc.sequential) {
          // Each UAV's turn as the sequential policy sees it: its observation written with the
          // rollout's moves of the UAVs before it shown, its allowed moves those of its turn.
          SafeTurns turns(env, safety);
          while (!turns.done()) {
            const int n = turns.uav();
            Sample s;
            s.input.resize(static_cast<std::size_t>(D));
            enc.write(env, n, s.input.data());
            s.allowed = turns.allowed() | action_bit(a[static_cast<std::size_t>(n)]);
            s.action = a[static_cast<std::size_t>(n)];
            agree[i] += base[static_cast<std::size_t>(n)] == s.action;
            per[i].push_back(std::move(s));
            turns.choose(a[static_cast<std::size_t>(n)]);
            const UavEnv::Landing l = env.landing(n, a[static_cast<std::size_t>(n)]);
            env.show_decided(n, l.x, l.y);
          }
          env.clear_decided();
        } else {
          for (int n = 0; n < env.uavs(); ++n) {
            if (env.arrived(n)) continue;
            Sample s;
            s.input.resize(static_cast<std::size_t>(D));
            enc.write(env, n, s.input.data());
            s.allowed = allowed_moves(env, n, safety) | action_bit(a[static_cast<std::size_t>(n)]);
            s.action = a[static_cast<std::size_t>(n)];
            agree[i] += base[static_cast<std::size_t>(n)] == s.action;
            per[i].push_back(std::move(s));
          }
        }
        env.step(a);
      }
    });
    std::vector<Sample> data;
    int agreed = 0;
    for (std::size_t i = 0; i < per.size(); ++i) {
      agreed += agree[i];
      for (auto& s : per[i]) data.push_back(std::move(s));
    }
    const double label_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::cout << fmt::format("labels: {} samples from {} training layouts in {:.1f} s; the base policy's move is the rollout's in {:.2f}%\n",
                             data.size(), layouts, label_s, 100.0 * agreed / static_cast<double>(data.size()));

    // 2. Fine-tune the actor.
    const int D = static_cast<int>(data.front().input.size());
    const int A = static_cast<int>(meta.at("actions").size());
    const auto S = static_cast<std::int64_t>(data.size());
    torch::Tensor X = torch::empty({S, D}), allowed = torch::zeros({S, A}, torch::kBool), Y = torch::empty({S}, torch::kLong);
    {
      auto x = X.accessor<float, 2>();
      auto m = allowed.accessor<bool, 2>();
      auto y = Y.accessor<std::int64_t, 1>();
      for (std::int64_t i = 0; i < S; ++i) {
        const auto& s = data[static_cast<std::size_t>(i)];
        for (int d = 0; d < D; ++d) x[i][d] = s.input[static_cast<std::size_t>(d)];
        for (int a = 0; a < A; ++a) m[i][a] = (s.allowed >> a & 1u) != 0;
        y[i] = s.action;
      }
    }
    if (const char* keep = std::getenv("DISTILL_DATA")) torch::save(std::vector<torch::Tensor>{X, allowed, Y}, keep);
    return finetune(cfg, bf, meta, in, out_dir, layouts, first, epochs, lr, val, threads, X, allowed, Y);
  } catch (const std::exception& e) {
    std::cerr << "skyloop_distill: error: " << e.what() << "\n";
    return 1;
  }
}
