#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/earth.hpp"
#include "turncal/plan.hpp"

using namespace turncal;

namespace {
const std::string kProfiles = std::string(turncal::build::source_dir) + "/config/profiles/";

Error plan_error(const std::string& text) {
  auto r = parse_plan(text, "lab.toml");
  REQUIRE_FALSE(r.ok());
  return r.error();
}
}  // namespace

TEST_SUITE("plan") {
  TEST_CASE("the shipped profiles load; tactical converts to SI as documented") {
    for (const char* name : {"tactical.toml", "navigation-grade.toml", "tactical-two-turns.toml"}) {
      auto p = load_plan(kProfiles + name);
      CAPTURE(name);
      REQUIRE_MESSAGE(p.ok(), (p.ok() ? "" : p.error().describe()));
      CHECK_FALSE(p->name.empty());
      CHECK_FALSE(p->profile.turns.empty());
    }
    auto t = load_plan(kProfiles + "tactical.toml");
    REQUIRE(t.ok());
    const double deg = earth::kDeg;
    CHECK(t->site.latitude_rad == doctest::Approx(55.75 * deg));
    CHECK(t->site.height_m == 200);
    REQUIRE(t->profile.turns.size() == 1);
    CHECK(t->profile.turns[0].start_s == 1800);
    CHECK(t->profile.turns[0].angle_rad == doctest::Approx(M_PI));
    CHECK(t->profile.turns[0].max_rate_rps == doctest::Approx(30 * deg));
    CHECK(t->priors.params[0] == doctest::Approx(deg / 3600));         // 1 deg/h
    CHECK(t->priors.params[12] == doctest::Approx(1e-3 * 9.80665));    // 1 mg
    CHECK(t->priors.params[16] == doctest::Approx(0.03));              // r1, m
    CHECK(t->priors.heading_rad == doctest::Approx(10.0 / 60 * deg));  // 10 arcmin
    CHECK(t->arw == doctest::Approx(0.05 * deg / 60));                 // deg/sqrt(h)
    CHECK(t->vrw == doctest::Approx(50e-6 * 9.80665));                 // ug/sqrt(Hz)
    CHECK(t->sigma_z == doctest::Approx(1e-3));
    CHECK_FALSE(t->mean_measurement);
  }

  TEST_CASE("an empty file is the tactical reference apart from the turns") {
    auto e = parse_plan("", "empty.toml");
    auto t = load_plan(kProfiles + "tactical.toml");
    REQUIRE(e.ok());
    REQUIRE(t.ok());
    CHECK(e->profile.turns.empty());
    for (std::size_t j = 0; j < e->priors.params.size(); ++j)
      CHECK(e->priors.params[j] == doctest::Approx(t->priors.params[j]));
    CHECK(e->arw == doctest::Approx(t->arw));
    CHECK(e->vrw == doctest::Approx(t->vrw));
  }

  TEST_CASE("per-axis priors take an array") {
    auto p =
        parse_plan("[priors]\ngyro_bias_dph = [1, 2, 3]\naccel_bias_ug = [100, 200]\n", "a.toml");
    REQUIRE_MESSAGE(p.ok(), (p.ok() ? "" : p.error().describe()));
    CHECK(p->priors.params[2] == doctest::Approx(3 * earth::kDeg / 3600).scale(0));
    CHECK(p->priors.params[13] == doctest::Approx(200e-6 * 9.80665).scale(0));
  }

  TEST_CASE("errors name file, line and key") {
    Error e = plan_error("[priors]\ngyro_bias_dph = 1\ngyro_bais = 2\n");
    CHECK(e.where.file == "lab.toml");
    CHECK(e.where.line == 3);
    CHECK(e.message.find("priors.gyro_bais") != std::string::npos);

    e = plan_error("[noise]\n\nvrw_ug_rthz = \"fifty\"\n");
    CHECK(e.where.line == 3);
    CHECK(e.message.find("noise.vrw_ug_rthz") != std::string::npos);
    CHECK(e.message.find("expected a number") != std::string::npos);

    e = plan_error("[site]\nlatitude_deg = 95\n");
    CHECK(e.where.line == 2);
    CHECK(e.message.find("site.latitude_deg") != std::string::npos);

    e = plan_error("[priors]\ngyro_bias_dph = [1, 2]\n");
    CHECK(e.message.find("array of 3") != std::string::npos);

    e = plan_error("[estimation]\nmeasurement = \"median\"\n");
    CHECK(e.where.line == 2);
    CHECK(e.message.find("estimation.measurement") != std::string::npos);

    e = plan_error("[profile]\nduration_s = 600\n[[profile.turn]]\nangle_deg = 180\n");
    CHECK(e.message.find("profile.turn[1].start_s") != std::string::npos);

    e = plan_error("[sites]\n");
    CHECK(e.where.line == 1);
    CHECK(e.message.find("sites") != std::string::npos);

    e = plan_error("[profile\n");  // TOML syntax
    CHECK(e.where.line == 1);
  }

  TEST_CASE("turns must fit: in order, not overlapping, over before the run ends") {
    // a 180 deg turn at 30 deg/s and 30 deg/s^2 lasts 7 s
    Error e = plan_error(
        "[profile]\nduration_s = 600\n[[profile.turn]]\nstart_s = 100\nangle_deg = 180\n"
        "[[profile.turn]]\nstart_s = 105\nangle_deg = 90\n");
    CHECK(e.where.line == 4);
    CHECK(e.message.find("next turn") != std::string::npos);
    e = plan_error(
        "[profile]\nduration_s = 600\n[[profile.turn]]\nstart_s = 595\nangle_deg = 180\n");
    CHECK(e.message.find("run ends") != std::string::npos);
    auto ok = parse_plan(
        "[profile]\nduration_s = 600\n[[profile.turn]]\nstart_s = 100\nangle_deg = 180\n"
        "[[profile.turn]]\nstart_s = 108\nangle_deg = -90\n",
        "ok.toml");
    CHECK(ok.ok());
  }

  TEST_CASE("overrides set keys over the file and are validated like it") {
    const std::vector<std::string> o = {"estimation.epoch_s=2", "estimation.measurement=\"mean\"",
                                        "priors.gyro_bias_dph=[1, 1, 0.5]", "noise.arw_dprh=0.01"};
    auto p = load_plan(kProfiles + "tactical.toml", o);
    REQUIRE_MESSAGE(p.ok(), (p.ok() ? "" : p.error().describe()));
    CHECK(p->epoch_s == 2);
    CHECK(p->mean_measurement);
    CHECK(p->priors.params[2] == doctest::Approx(0.5 * earth::kDeg / 3600));
    CHECK(p->priors.params[1] == doctest::Approx(earth::kDeg / 3600));
    CHECK(p->arw == doctest::Approx(0.01 * earth::kDeg / 60));
    CHECK(p->overrides == o);
    CHECK(p->profile.turns.size() == 1);  // the rest of the file stays
    // the text is kept as read: parsed again with the overrides it is the same plan
    auto q = parse_plan(p->text, "again.toml", p->overrides);
    REQUIRE(q.ok());
    CHECK(q->epoch_s == 2);
    CHECK(q->priors.params == p->priors.params);
    // a new section is made
    auto n = parse_plan("", "empty.toml", std::vector<std::string>{"site.latitude_deg=10"});
    REQUIRE(n.ok());
    CHECK(n->site.latitude_rad == doctest::Approx(10 * earth::kDeg));
  }

  TEST_CASE("a bad override names itself, its key and what is wrong") {
    auto err = [](std::string o) {
      auto r = load_plan(kProfiles + "tactical.toml", std::vector<std::string>{o});
      REQUIRE_FALSE(r.ok());
      return r.error().describe();
    };
    CHECK(err("estimation.epoch_s=0") ==
          "--set estimation.epoch_s=0: key 'estimation.epoch_s': must be between 0.001 and 600");
    CHECK(err("estimation.epoch=1").find("unknown key 'estimation.epoch'") != std::string::npos);
    CHECK(err("estimation.epoch_s").find("expected section.key=VALUE") != std::string::npos);
    CHECK(err("estimation.measurement=mean").starts_with("--set estimation.measurement=mean: "));
    CHECK(err("site.latitude_deg.x=1").find("'latitude_deg' is not a table") != std::string::npos);
  }
}
