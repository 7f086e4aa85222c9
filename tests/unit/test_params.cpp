// The parameter table (turncal/estimation/params.hpp): each parameter's
// name, block, place, units and prior key, and what is derived from it,
// against model.md's layout (section 3) written out here independently.
#include <doctest/doctest.h>

#include <cmath>
#include <set>
#include <string>

#include "turncal/config.hpp"
#include "turncal/estimation/nominal.hpp"
#include "turncal/estimation/params.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/report.hpp"

using namespace turncal;

namespace {
/// a and b agree to 1e-12 of b (a relative check that fails on 0 for b != 0)
bool same(double a, double b) {
  return std::abs(a - b) <= 1e-12 * std::abs(b);
}
}  // namespace

TEST_SUITE("parameter table") {
  TEST_CASE("the 18 parameters sit where model.md, section 3, puts them") {
    // model.md: x = (dv1 dv2 a1 a2 b1 b2 b3 | nu0 (3) Theta (9, row-major)
    // df0 (2) G13 G23 r1 r2)
    const char* names[] = {"nu0_1",    "nu0_2",    "nu0_3",    "theta_11", "theta_12", "theta_13",
                           "theta_21", "theta_22", "theta_23", "theta_31", "theta_32", "theta_33",
                           "df0_1",    "df0_2",    "g13",      "g23",      "r1",       "r2"};
    REQUIRE(est::kParamNames.size() == std::size(names));
    for (std::size_t i = 0; i < std::size(names); ++i) {
      CAPTURE(names[i]);
      CHECK(est::kParamNames[i] == names[i]);
      CHECK(est::param_index(names[i]) == static_cast<int>(i));
    }
    CHECK(est::sx::kNu0 == 7);
    CHECK(est::sx::theta(2, 3) == 7 + 3 + 5);
    CHECK(est::sx::kR + 1 == 7 + 17);
    CHECK(est::param_index("nu0_4") == -1);
    CHECK(est::param_index("df_eff_1") == -1);  // a combination, not a state
  }

  TEST_CASE("units, display units and their factors, per parameter and combination") {
    const double dph = 3.14159265358979323846 / 180 / 3600;  // deg/h in rad/s
    struct Want {
      const char* name;
      const char* si;
      const char* shown;
      double per_si;
    };
    const Want want[] = {{"nu0_3", "rad/s", "deg/h", 1 / dph},
                         {"theta_31", "1", "ppm", 1e6},
                         {"df0_2", "m/s^2", "ug", 1 / 9.80665e-6},
                         {"g13", "1", "ppm", 1e6},
                         {"r2", "m", "mm", 1e3}};
    for (const Want& w : want) {
      CAPTURE(w.name);
      const auto i = static_cast<std::size_t>(est::param_index(w.name));
      CHECK(est::kParamUnits[i] == w.si);
      CHECK(display_unit(w.name).first == w.shown);
      CHECK(display_unit(w.name).second == w.per_si);  // the same double as before
    }
    for (const char* c : {"df_eff_1", "df_eff_2", "df_obs_1", "df_obs_2"}) {
      CAPTURE(c);
      CHECK(display_unit(c).first == "ug");
    }
    CHECK(display_unit("theta_34").first.empty());
    CHECK(display_unit("r").first.empty());
    // every name a report can give has a unit
    for (std::string_view n : est::kParamNames) CHECK_FALSE(display_unit(n).first.empty());
  }

  TEST_CASE("a plan's prior keys fill each block's own parameters") {
    auto p = parse_plan(
        "[priors]\ngyro_bias_dph = [1, 2, 3]\n"
        "gyro_scale_misalignment = [11e-6, 12e-6, 13e-6, 21e-6, 22e-6, 23e-6, 31e-6, 32e-6, "
        "33e-6]\naccel_bias_ug = [100, 200]\naccel_misalignment = [7e-5, 8e-5]\n"
        "proof_mass_offset_m = [0.01, 0.02]\n",
        "a.toml");
    REQUIRE_MESSAGE(p.ok(), (p.ok() ? "" : p.error().describe()));
    const auto at = [&](const char* n) {
      return p->priors.params[static_cast<std::size_t>(est::param_index(n))];
    };
    const double dph = 3.14159265358979323846 / 180 / 3600;
    CHECK(at("nu0_1") == 1 * dph);
    CHECK(at("nu0_3") == 3 * dph);
    CHECK(same(at("theta_11"), 11e-6));
    CHECK(same(at("theta_23"), 23e-6));
    CHECK(same(at("theta_33"), 33e-6));
    CHECK(at("df0_2") == 200 * (1e-6 * 9.80665));  // the plan's ug: 1e-6 g0, not 9.80665e-6
    CHECK(same(at("g13"), 7e-5));
    CHECK(same(at("g23"), 8e-5));
    CHECK(same(at("r1"), 0.01));
    CHECK(same(at("r2"), 0.02));
    // a key left out keeps the tactical default, in SI
    auto d = parse_plan("", "d.toml");
    REQUIRE(d.ok());
    CHECK(d->priors.params[0] == 1 * dph);
    CHECK(d->priors.params[13] == 1000 * (1e-6 * 9.80665));
    CHECK(same(d->priors.params[17], 0.03));
    // a block's bound is its own
    auto big = parse_plan("[priors]\nproof_mass_offset_m = 11\n", "b.toml");
    REQUIRE_FALSE(big.ok());
    CHECK(big.error().message.find("priors.proof_mass_offset_m") != std::string::npos);
  }

  TEST_CASE("the strapdown's errors of each parameter, and back") {
    est::ParamArray p{};
    for (std::size_t k = 0; k < p.size(); ++k) p[k] = static_cast<double>(k + 1) * 1e-3;
    const sim::SensorErrors e = est::sensor_errors(p);
    const auto v = [&](const char* n) { return p[static_cast<std::size_t>(est::param_index(n))]; };
    CHECK(e.nu0(2) == v("nu0_3"));
    CHECK(e.theta(0, 1) == v("theta_12"));  // row-major: Theta_12 is row 1, column 2
    CHECK(e.theta(1, 0) == v("theta_21"));
    CHECK(e.theta(1, 2) == v("theta_23"));
    CHECK(e.theta(2, 2) == v("theta_33"));
    CHECK(e.df0(1) == v("df0_2"));
    CHECK(e.g(0) == v("g13"));
    CHECK(e.g(1) == v("g23"));
    CHECK(e.r(0) == v("r1"));
    CHECK(e.r(1) == v("r2"));
    CHECK(est::params_of(e) == p);
  }

  TEST_CASE("a report's reasons and the calibration file's tables follow the blocks") {
    // the reason of each undetermined parameter names its own axis
    CHECK(run::determination("theta_23", 1, 1).why.find("df0_2 + g G23 - g Theta_23") !=
          std::string::npos);
    CHECK(run::determination("g13", 1, 1).why.find("df0_1 and g G13") != std::string::npos);
    CHECK(run::determination("df_eff_2", 1, 1).why.find("df0_2 and g G23") != std::string::npos);
    CHECK(run::determination("theta_33", 1, 1).why.find("whole revolutions") != std::string::npos);
    CHECK(run::determination("theta_12", 1, 1).why.find("horizontal axis") != std::string::npos);
    CHECK(run::determination("r2", 1, 1).why.find("faster turn") != std::string::npos);
    CHECK(run::determination("r2", 0.1, 1).label == "determined");
    CHECK(run::determination("r2", 0.7, 1).label == "partly");
    // each block's calibration table and sensor, none twice
    std::set<std::pair<std::string_view, std::string_view>> tables;
    for (const est::BlockInfo& b : est::kBlocks) tables.insert({b.sensor, b.calibration});
    CHECK(tables.size() == est::kBlocks.size());
    CHECK(est::block_info(est::Block::kAccelMisalignment).sensor == "accelerometer");
  }
}
