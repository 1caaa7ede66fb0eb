#include <gtest/gtest.h>

#include <filesystem>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

#include "test_util.hpp"
#include "../scratch.hpp"

using namespace skyloop;
using skyloop::test::error_of;


TEST(Config, DefaultsAreThePaperValues) {
  const Config c;
  EXPECT_EQ(c.scenario.area_x_m, 200);
  EXPECT_EQ(c.scenario.altitude_m, 100);
  EXPECT_EQ(c.channel.antennas, 4);
  EXPECT_EQ(c.channel.antenna_spacing_wavelengths, 0.5);
  EXPECT_EQ(c.channel.p_max_dbm, 30);
  EXPECT_EQ(c.channel.noise_dbm, -90);
  EXPECT_EQ(c.channel.beta0_db, -20);
  EXPECT_EQ(c.channel.coverage_radius_m, 150);
  EXPECT_EQ(c.ga.generations, 2000);
  EXPECT_EQ(c.trajectory.t_max, 24);
  EXPECT_DOUBLE_EQ(c.channel.p_max_w(), 1.0);
  EXPECT_DOUBLE_EQ(c.channel.noise_w(), 1e-12);
}

TEST(Config, PaperTomlEqualsDefaults) {
  const Config file = resolve_config(std::string(SKYLOOP_SOURCE_DIR) + "/configs/paper.toml", {});
  EXPECT_EQ(to_toml(file), to_toml(Config{}));
}

// Every configuration shipped in configs/ (the recipes the README trains with) resolves: a key
// renamed or a value out of range in one of them is a user's first command failing.
TEST(Config, ShippedConfigsResolve) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(SKYLOOP_SOURCE_DIR) + "/configs")) {
    if (e.path().extension() != ".toml") continue;
    EXPECT_NO_THROW(resolve_config(e.path().string(), {})) << e.path();
    ++n;
  }
  EXPECT_GE(n, 4);  // paper, generalise, generalise_fleet, generalise_wmmse
}

TEST(Config, ShowRoundTrips) {
  Config c;
  apply_override(c, "channel.p_max_dbm=42.5");
  apply_override(c, "trajectory.starts=[[1,2],[3,4],[5,6]]");
  apply_override(c, "beamforming.power_scaling=cap");
  apply_override(c, "run.seed=123456789012");
  Config back;
  apply_toml(back, to_toml(c), "shown");
  EXPECT_EQ(to_toml(back), to_toml(c));
  EXPECT_EQ(back.channel.p_max_dbm, 42.5);
  EXPECT_EQ(back.trajectory.starts[2], (Point2{5, 6}));
  EXPECT_EQ(back.beamforming.power_scaling, PowerScaling::Cap);
  EXPECT_EQ(back.run.seed, 123456789012u);
}

TEST(Config, OverrideAcceptsIntegerForReal) {
  Config c;
  apply_override(c, "channel.p_max_dbm=40");
  EXPECT_EQ(c.channel.p_max_dbm, 40.0);
}

TEST(Config, UnknownKeyIsNamed) {
  Config c;
  const auto msg = error_of([&] { apply_toml(c, "[channel]\np_max = 3\n", "x.toml"); });
  EXPECT_NE(msg.find("channel.p_max"), std::string::npos) << msg;
  EXPECT_NE(msg.find("p_max_dbm"), std::string::npos) << msg;  // lists the allowed keys
  const auto msg2 = error_of([&] { apply_override(c, "nosuch.key=1"); });
  EXPECT_NE(msg2.find("nosuch.key"), std::string::npos) << msg2;
  const auto msg3 = error_of([&] { apply_toml(c, "seed = 3\n", "x.toml"); });
  EXPECT_NE(msg3.find("'seed'"), std::string::npos) << msg3;
}

TEST(Config, OutOfRangeNamesKeyValueAndRange) {
  Config c;
  const auto msg = error_of([&] { apply_override(c, "channel.p_max_dbm=400"); });
  EXPECT_NE(msg.find("channel.p_max_dbm"), std::string::npos) << msg;
  EXPECT_NE(msg.find("400"), std::string::npos) << msg;
  EXPECT_NE(msg.find("[-30, 80]"), std::string::npos) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line";
  EXPECT_EQ(c.channel.p_max_dbm, 30.0) << "a rejected value leaves the config unchanged";
}

TEST(Config, WrongTypeIsNamed) {
  Config c;
  auto msg = error_of([&] { apply_override(c, "channel.antennas=4.5"); });
  EXPECT_NE(msg.find("channel.antennas"), std::string::npos) << msg;
  EXPECT_NE(msg.find("wrong type"), std::string::npos) << msg;
  msg = error_of([&] { apply_toml(c, "[channel]\nantennas = \"four\"\n", "x.toml"); });
  EXPECT_NE(msg.find("channel.antennas = \"four\""), std::string::npos) << msg;
  msg = error_of([&] { apply_override(c, "trajectory.starts=[[1,2,3]]"); });
  EXPECT_NE(msg.find("trajectory.starts"), std::string::npos) << msg;
}

TEST(Config, ChoiceIsChecked) {
  Config c;
  const auto msg = error_of([&] { apply_override(c, "beamforming.power_scaling=boost"); });
  EXPECT_NE(msg.find("beamforming.power_scaling"), std::string::npos) << msg;
  EXPECT_NE(msg.find("full, cap"), std::string::npos) << msg;
}

TEST(Config, CrossFieldRules) {
  Config c;
  apply_override(c, "trajectory.starts=[[20,20]]");
  auto msg = error_of([&] { validate(c); });
  EXPECT_NE(msg.find("trajectory.destinations"), std::string::npos) << msg;
  Config d;
  apply_override(d, "trajectory.starts=[[20,20],[20,180],[250,180]]");
  msg = error_of([&] { validate(d); });
  EXPECT_NE(msg.find("trajectory.starts[2]"), std::string::npos) << msg;
  Config e;
  apply_override(e, "channel.coverage_radius_m=50");
  msg = error_of([&] { validate(e); });
  EXPECT_NE(msg.find("channel.coverage_radius_m"), std::string::npos) << msg;
}

TEST(Config, MalformedTomlIsOneLineWithPosition) {
  Config c;
  const auto msg = error_of([&] { apply_toml(c, "[channel\np = 1\n", "bad.toml"); });
  EXPECT_EQ(msg.rfind("bad.toml:1:", 0), 0u) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
}

TEST(Config, MissingFileIsInputError) {
  const auto msg = error_of([&] { resolve_config(std::string("/nonexistent/cfg.toml"), {}); });
  EXPECT_NE(msg.find("/nonexistent/cfg.toml"), std::string::npos) << msg;
}

TEST(Config, EveryFieldHasHelpAndRoundTripsItsDefault) {
  for (const auto& f : config_fields()) {
    EXPECT_FALSE(f.help.empty()) << f.key;
    Config c;
    EXPECT_NO_THROW(set_field(c, f, f.get(Config{}))) << f.key;
  }
}

TEST(Io, AtomicWriteReplacesWholeFile) {
  const std::string path = (test::scratch_path("atomic") / "out.txt").string();
  write_file_atomic(path, "first\n");
  write_file_atomic(path, "second\n");
  EXPECT_EQ(read_file(path), "second\n");
}

TEST(Io, FormatDoubleRoundTrips) {
  for (double x : {0.1, 1.0 / 3.0, 1e-12, 123456.789, -90.0}) EXPECT_EQ(std::stod(format_double(x)), x);
}
