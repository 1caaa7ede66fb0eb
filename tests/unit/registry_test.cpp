#include <gtest/gtest.h>

#include <set>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/fading.hpp"
#include "skyloop/channel/path_loss.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/registry.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/experiments/builtin.hpp"

using namespace skyloop;

namespace {
class HalfMrt final : public Beamformer {
 public:
  explicit HalfMrt(double f) : f_(f) {}
  std::string name() const override { return "half"; }
  MatrixXcd design(const Cluster& c) const override { return mrt(c) * f_; }

 private:
  double f_;
};
}  // namespace

TEST(Registry, UnknownMethodListsKnownOnes) {
  try {
    builtin_beamformers().create("nosuch", Config{});
    FAIL();
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("nosuch"), std::string::npos);
    EXPECT_NE(m.find("wmmse"), std::string::npos);
  }
}

TEST(Registry, UserBeamformerWithArgument) {
  BeamformerRegistry reg;
  reg.add("half", "MRT at a fraction of the budget",
          [](const Config&, const std::string& arg) { return std::make_unique<HalfMrt>(std::stod(arg)); });
  const auto bf = reg.create("half=0.5", Config{});
  Cluster c;
  c.G = MatrixXcd::Ones(1, 4);
  c.p_max = 4.0;
  EXPECT_NEAR(bf->design(c).squaredNorm(), 1.0, 1e-12);
}

TEST(Registry, ClassicalMethodsRejectArguments) {
  EXPECT_THROW(builtin_beamformers().create("zf=3", Config{}), InputError);
}

TEST(Registry, SplitMethods) {
  EXPECT_EQ(split_methods("mrt,zf,gnn=a/b.pt"), (std::vector<std::string>{"mrt", "zf", "gnn=a/b.pt"}));
  EXPECT_THROW(split_methods("mrt,,zf"), InputError);
  EXPECT_THROW(split_methods(""), InputError);
}

// The one registry template every open set is built on (skyloop/core/registry.hpp): rows keep the
// order of their first registration (or sort by name), a name registered again replaces its row
// in place, and a name it lacks is one error line quoting it as the registry says and listing
// every name.
TEST(Registry, TemplateKeepsOrderReplacesInPlaceAndNamesTheUnknown) {
  Registry<int> r("trajectory.mobility = \"{}\"", {{"grid", "five moves", 1}, {"headings", "eight", 2}});
  r.add("continuous", "a velocity", 3);
  r.add("grid", "five moves, again", 10);
  EXPECT_EQ(r.names(), (std::vector<std::string>{"grid", "headings", "continuous"}));
  EXPECT_EQ(r.at("grid"), 10);
  EXPECT_EQ(r.find("grid")->help, "five moves, again");
  EXPECT_EQ(r.help_text(), "grid: five moves, again; headings: eight; continuous: a velocity");
  EXPECT_FALSE(r.contains("grid3"));
  try {
    r.at("grid3");
    FAIL() << "an unknown name was found";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "trajectory.mobility = \"grid3\" is unknown: allowed grid, headings, continuous");
  }
  Registry<int> sorted("method '{}'", {{"zf", "", 1}, {"mrt", "", 2}}, Registry<int>::Order::Name);
  sorted.add("gnn", "", 3);
  EXPECT_EQ(sorted.names_text(), "gnn, mrt, zf");
  // Every registry the program holds is one of these: its names are the configuration's allowed values.
  EXPECT_EQ(find_field("trajectory.mobility")->choices, dynamics_models().names());
  EXPECT_EQ(find_field("channel.fading")->choices, fading_models().names());
  EXPECT_EQ(find_field("channel.pathloss")->choices, path_loss_models().names());
  EXPECT_EQ(find_field("marl.algo")->choices, learners().names());
}

// Every closed choice's table (skyloop/core/choices.hpp) names each value once, and its field's
// allowed values are the table's names, read back to the same value through TOML's text.
TEST(Registry, EveryChoiceTableRoundTripsThroughItsField) {
  auto check = [](const char* key, auto value_of) {
    const Field* f = find_field(key);
    ASSERT_NE(f, nullptr) << key;
    for (const auto& name : f->choices) {
      Config c;
      set_field(c, *f, FieldValue(name));
      EXPECT_EQ(std::get<std::string>(f->get(c)), name) << key;
      EXPECT_STREQ(name_of(value_of(c)), name.c_str()) << key;
    }
  };
  check("channel.spectrum", [](const Config& c) { return c.channel.spectrum; });
  check("marl.encoder", [](const Config& c) { return c.marl.encoder; });
  check("marl.mask_clearance", [](const Config& c) { return c.marl.mask_clearance; });
  check("env.objective", [](const Config& c) { return c.env.objective; });
  check("nn.selection", [](const Config& c) { return c.nn.selection; });
  check("ga.algorithm", [](const Config& c) { return c.ga.algorithm; });
  EXPECT_EQ(find_field("marl.encoder")->choices, choice_names<ObservationKind>());
  EXPECT_THROW(parse_choice<Spectrum>("channel.spectrum", "reuse"), InputError);
}

// Every choice table: its names and its values each once, every row's value named by that row.
template <class... E>
void expect_tables_one_to_one() {
  auto one = [](auto tag) {
    using T = decltype(tag);
    std::set<std::string> names;
    std::set<int> values;
    for (const auto& c : choices<T>()) {
      EXPECT_TRUE(names.insert(c.name).second) << c.name << " twice";
      EXPECT_TRUE(values.insert(static_cast<int>(c.value)).second) << c.name << ": its value has another row";
      EXPECT_STREQ(name_of(c.value), c.name);
      EXPECT_TRUE(c.help && *c.help) << c.name << " has no help";
    }
    EXPECT_FALSE(names.empty());
  };
  (one(E{}), ...);
}

TEST(Registry, EveryChoiceTableIsOneToOne) {
  expect_tables_one_to_one<UserLayout, Spectrum, RicianK, PowerScaling, PowerAllocation, WmmseInit, GaAlgorithm, LayoutSource,
                           Command, Propulsion, Acceleration, Reward, Objective, StateKind, ObservationKind, MinibatchLayout,
                           CriticState, Clearance, StepSchedule, PpoBackend, LrSchedule, ComputeDevice, Readout, Features,
                           Precision, Inference, Selection>();
}
