#include <gtest/gtest.h>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/error.hpp"
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
