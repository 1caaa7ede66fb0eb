// The environment's spec is the one layout: every writer fills exactly the row its spec describes
// (no value left unwritten, nothing written past it), each field's own writer exactly its slice, for every state kind and encoder and for
// agent counts on both sides of the compact context's kNeighbours.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/spec.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/env/vec_env.hpp"

using namespace skyloop;

namespace {

Config scenario(int uavs, const std::string& state, const std::string& encoder, bool lookahead = false) {
  const std::string side = uavs <= 3 ? "200" : uavs <= 16 ? "1000" : "2000";
  return resolve_config(std::nullopt, {"scenario.uavs=" + std::to_string(uavs), "scenario.users=15", "scenario.area_x_m=" + side,
                                       "scenario.area_y_m=" + side, "trajectory.layout=\"generated\"", "trajectory.t_max=30",
                                       "env.state=\"" + state + "\"", "marl.encoder=\"" + encoder + "\"", "env.oracle=\"zf\"",
                                       std::string("marl.lookahead=") + (lookahead ? "true" : "false")});
}

/// Calls `write` on a buffer of `size` values and `size + 8` sentinels: every value written is
/// finite and within [low, high] of its field, and nothing past `size` changed.
template <class Write>
void expect_fills_exactly(const ArraySpec& spec, const Write& write, const std::string& what) {
  constexpr float kSentinel = -12345.0f;
  std::vector<float> buf(static_cast<std::size_t>(spec.size + 8), std::numeric_limits<float>::quiet_NaN());
  std::fill(buf.begin() + spec.size, buf.end(), kSentinel);
  write(buf.data());
  for (const auto& f : spec.fields)
    for (int i = f.offset; i < f.offset + f.size; ++i) {
      ASSERT_TRUE(std::isfinite(buf[static_cast<std::size_t>(i)])) << what << ": " << f.name << "[" << i - f.offset << "] unwritten";
      EXPECT_GE(buf[static_cast<std::size_t>(i)], f.low - 1e-5f) << what << ": " << f.name;
      EXPECT_LE(buf[static_cast<std::size_t>(i)], f.high + 1e-5f) << what << ": " << f.name;
    }
  for (std::size_t i = static_cast<std::size_t>(spec.size); i < buf.size(); ++i)
    ASSERT_EQ(buf[i], kSentinel) << what << ": wrote past its " << spec.size << " values";
}

/// The set observation's size without the look-ahead: own (6 + the previous action), users and UAVs.
int scenario_spec_size(const EnvSpec& s) {
  return 6 + s.action.count() + 2 * kWideGrid * kWideGrid + kNearGrid * kNearGrid;
}

}  // namespace

TEST(Spec, EveryWriterFillsExactlyItsRow) {
  BeamformerRegistry reg;
  register_classical_beamformers(reg);
  for (const char* state : {"paper", "compact"})
    for (const char* encoder : {"mlp", "set", "set+lookahead"})
      for (int N : {1, 2, 5, 9, 16}) {
        const bool lookahead = std::string(encoder) == "set+lookahead";
        const Config cfg = scenario(N, state, lookahead ? "set" : encoder, lookahead);
        auto bf = std::shared_ptr<const Beamformer>(reg.create("zf", cfg));
        VecEnv vec(cfg, bf, 2, 7);
        UavEnv& env = vec.env(1);
        const EnvSpec& s = env.spec();
        const std::string what = std::string(state) + "/" + encoder + "/N=" + std::to_string(N);
        ASSERT_EQ(s.agents, N);
        EXPECT_EQ(s.state.size, std::string(state) == "paper" ? 4 * N + 2 * 15 : 3 * kStateGrid * kStateGrid + 2) << what;
        EXPECT_EQ(s.agent_state.size, s.state.size + s.agent_context.size + s.paper_obs.size) << what;
        EXPECT_EQ(s.obs.size, std::string(encoder) != "mlp" ? s.set_obs.size : 11) << what;
        EXPECT_EQ(s.set_obs.size, scenario_spec_size(s) + (lookahead ? kGridActions : 0)) << what;
        EXPECT_EQ(s.action.count(), kGridActions);
        EXPECT_EQ(env.state_size(), s.state.size);
        Rng rng(static_cast<std::uint64_t>(N));
        for (int t = 0; t < 3 && !env.done(); ++t) {
          expect_fills_exactly(s.state, [&](float* o) { env.write_state(o); }, what + " state");
          expect_fills_exactly(s.compact_state, [&](float* o) { env.write_compact_state(o); }, what + " compact state");
          for (int n = 0; n < N; ++n) {
            expect_fills_exactly(s.obs, [&](float* o) { env.write_obs(n, o); }, what + " obs");
            expect_fills_exactly(s.paper_obs, [&](float* o) { env.write_observation(n, o); }, what + " paper obs");
            expect_fills_exactly(s.set_obs, [&](float* o) { env.write_set_observation(n, o); }, what + " set obs");
            expect_fills_exactly(s.agent_context, [&](float* o) { env.write_agent_context(n, o); }, what + " context");
            expect_fills_exactly(s.agent_state, [&](float* o) { env.write_agent_state(n, o); }, what + " agent state");
            EXPECT_EQ(env.agent_state(n).size(), static_cast<std::size_t>(s.agent_state.size));
            // Each field's own writer (its row of observation_fields() or state_fields()) fills
            // exactly its slice: an array is its fields' writers, each at its offset.
            for (const ArraySpec* a : {&s.paper_obs, &s.set_obs, &s.state, &s.compact_state, &s.agent_context})
              for (const SpecField& f : a->fields) {
                ASSERT_NE(f.write, nullptr) << what << ": " << a->name << "." << f.name << " has no writer";
                ArraySpec one;
                one.add(f.name, f.size, f.low, f.high);
                expect_fills_exactly(one, [&](float* o) { f.write(env, n, o); }, what + " " + a->kind + " " + f.name);
              }
          }
          std::vector<int> a(static_cast<std::size_t>(N));
          for (auto& x : a) x = static_cast<int>(rng.below(kGridActions));
          env.step(a);
        }
      }
}

TEST(Spec, FieldsAreContiguousAndNamedOnce) {
  const Config cfg = scenario(3, "paper", "mlp");
  const EnvSpec s = make_env_spec(cfg, 3, 12);
  for (const ArraySpec* a : {&s.obs, &s.state, &s.agent_context, &s.agent_state, &s.action_mask, &s.set_obs}) {
    int offset = 0;
    for (std::size_t i = 0; i < a->fields.size(); ++i) {
      EXPECT_EQ(a->fields[i].offset, offset) << a->name << "." << a->fields[i].name;
      offset += a->fields[i].size;
      for (std::size_t j = 0; j < i; ++j) EXPECT_NE(a->fields[i].name, a->fields[j].name) << a->name;
    }
    EXPECT_EQ(offset, a->size) << a->name;
  }
  EXPECT_EQ(s.agent_state.field("obs.previous_action").offset, s.state.size + s.agent_context.size + 6);
  EXPECT_THROW(s.obs.field("nope"), InputError);
  EXPECT_EQ(s.action_mask.size, kGridActions);
  for (int a = 0; a < kGridActions; ++a) EXPECT_EQ(s.action.names[static_cast<std::size_t>(a)], grid_actions().name(a));
}

// Environments share a spec exactly when their parameters make the same one: the cache is keyed by
// what the spec says, so a parameter that changes the layout (here the altitude field, the action
// space, the rate map) can never be handed another configuration's spec.
TEST(Spec, SharedSpecsAreKeyedByTheirContents) {
  SpecParams p = spec_params(Config{}, 3, 12);
  const auto a = shared_env_spec(p);
  EXPECT_EQ(shared_env_spec(p).get(), a.get());
  SpecParams q = p;
  q.altitude = true;
  const auto b = shared_env_spec(q);
  EXPECT_NE(b.get(), a.get());
  EXPECT_EQ(b->paper_obs.size, a->paper_obs.size + 1);
  EXPECT_EQ(b->paper_obs.fields.back().name, "altitude");
  q = p;
  q.rate_map = 1;
  EXPECT_NE(shared_env_spec(q)->set_obs.size, a->set_obs.size);
  q = p;
  Config grid3d;
  grid3d.trajectory.mobility = "grid-3d";
  q.action = make_dynamics(grid3d)->actions();
  EXPECT_EQ(shared_env_spec(q)->action_mask.size, 15);
  // Every field the same: the same spec object, whichever parameter set made it.
  q = p;
  EXPECT_EQ(make_env_spec(q).obs.size, a->obs.size);
  EXPECT_EQ(shared_env_spec(q).get(), a.get());
}
