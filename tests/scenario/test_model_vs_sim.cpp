// model.md 9.1: the linear model against the nonlinear strapdown
// simulation, noise off, each parameter alone and all together.
#include <doctest/doctest.h>

#include <cmath>
#include <string>

#include "scenarios.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/timeline.hpp"
#include "turncal/sim/strapdown.hpp"

using namespace turncal;
using turncal::earth::kDeg;

namespace {

constexpr double kLat = scenario::kDeg * 55.75;
constexpr double kHeight = 200;
constexpr double kDegPerHour = kDeg / 3600.0;
constexpr double kMg = 1e-3 * 9.80665;

struct Injection {
  std::string name;
  est::XiVec xi;  // the same errors in the model's variables
};

struct Comparison {
  double max_signal = 0;
  double max_diff = 0;
  double t_worst = 0;
};

/// Runs the simulation with `xi` and the linear model with `model_xi`
/// (the same unless a test flips a sign on purpose), on the scenario's
/// profile (the reference one by default).
Comparison compare(const est::XiVec& xi, double psi_s, const est::XiVec* model_xi = nullptr,
                   const scenario::Scenario& where = scenario::tactical()) {
  const sim::Config cfg = scenario::sim_config(xi, psi_s, where);
  const sim::Run run = sim::simulate(cfg);
  const TableTrajectory table(cfg.profile);
  est::TimelineInput in;
  in.site = where.site;
  in.epoch_s = 1.0;
  in.duration_s = cfg.profile.duration_s;
  in.psi_start_rad = psi_s;
  for (std::size_t i = 0; i < table.turns(); ++i)
    in.turns.push_back({table.turn_start(i), table.turn_end(i)});
  for (const auto& e : run.encoder) in.encoder.push_back({e.t_s, psi_s + e.angle_rad});
  const est::EarthAt earth = est::EarthAt::at(in.site);
  est::StateVec x = est::initial_map(earth, psi_s) * (model_xi != nullptr ? *model_xi : xi);
  Comparison c;
  const auto per_epoch = static_cast<std::size_t>(std::llround(cfg.output_rate_hz * in.epoch_s));
  const auto steps = est::for_each_step(in, [&](const est::TimelineStep& s) {
    x = s.d->phi * x;
    const auto k = static_cast<std::size_t>(std::llround(s.t_to / in.epoch_s)) * per_epoch;
    REQUIRE(k < run.velocity.size());
    const sim::VelocitySample& v = run.velocity[k];
    REQUIRE(std::fabs(v.t_s - s.t_to) < 1e-9);
    const double d = std::hypot(x(est::sx::kDv) - v.ve, x(est::sx::kDv + 1) - v.vn);
    c.max_signal = std::max(c.max_signal, std::hypot(v.ve, v.vn));
    if (d > c.max_diff) {
      c.max_diff = d;
      c.t_worst = s.t_to;
    }
  });
  REQUIRE(steps.ok());
  return c;
}

/// Each parameter alone at a tenth of the scenario's prior sigma, the
/// start errors, and all together (signs mixed).
std::vector<Injection> injections_of(const scenario::Scenario& s) {
  using namespace est;
  std::vector<Injection> out;
  XiVec all = XiVec::Zero();
  for (int p = 0; p < sx::kParams; ++p) {
    const double tenth = 0.1 * s.priors.params[static_cast<std::size_t>(p)];
    XiVec xi = XiVec::Zero();
    xi(sxi::kParams + p) = tenth;
    out.push_back({std::string(kParamNames[static_cast<std::size_t>(p)]), xi});
    all(sxi::kParams + p) = (p % 3 == 1 ? -1.0 : 1.0) * tenth;
  }
  XiVec start = XiVec::Zero();
  start(sxi::kDpsi0) = 1.0 / 60.0 * kDeg;
  out.push_back({"heading error", start});
  all(sxi::kDpsi0) = 1.0 / 60.0 * kDeg;
  all(sxi::kDrE) = 1.0;
  all(sxi::kDrN) = -1.0;
  all(sxi::kV0) = 1e-4;
  out.push_back({"all together", all});
  return out;
}

std::vector<Injection> injections() {
  using namespace est;
  // one tenth of the tactical prior sigma (issue: second-order terms stay
  // near 0.2% there)
  const double tenth[sx::kParams] = {0.1 * kDegPerHour,
                                     0.1 * kDegPerHour,
                                     0.1 * kDegPerHour,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     1e-4,
                                     0.1 * kMg,
                                     0.1 * kMg,
                                     1e-4,
                                     1e-4,
                                     0.003,
                                     0.003};
  std::vector<Injection> out;
  XiVec all = XiVec::Zero();
  for (int p = 0; p < sx::kParams; ++p) {
    XiVec xi = XiVec::Zero();
    xi(sxi::kParams + p) = tenth[p];
    out.push_back({std::string(kParamNames[static_cast<std::size_t>(p)]), xi});
    all(sxi::kParams + p) = (p % 3 == 1 ? -1.0 : 1.0) * tenth[p];
  }
  XiVec start = XiVec::Zero();
  start(sxi::kDpsi0) = 1.0 / 60.0 * kDeg;
  out.push_back({"heading error", start});
  start = XiVec::Zero();
  start(sxi::kDrE) = 1.0;
  start(sxi::kDrN) = -1.0;
  out.push_back({"position error", start});
  start = XiVec::Zero();
  start(sxi::kV0) = 1e-4;
  start(sxi::kV0 + 1) = -1e-4;
  out.push_back({"initial velocity", start});
  all(sxi::kDpsi0) = 1.0 / 60.0 * kDeg;
  all(sxi::kDrE) = 1.0;
  all(sxi::kDrN) = -1.0;
  all(sxi::kV0) = 1e-4;
  out.push_back({"all together", all});
  return out;
}

}  // namespace

TEST_SUITE("model vs simulation") {
  TEST_CASE("the linear model predicts the simulated INS velocity within 1% or 1e-4 m/s") {
    for (double psi_deg : {0.0, 37.0}) {
      for (const Injection& inj : injections()) {
        CAPTURE(psi_deg);
        CAPTURE(inj.name);
        const Comparison c = compare(inj.xi, psi_deg * kDeg);
        const double tol = std::max(0.01 * c.max_signal, 1e-4);
        MESSAGE(inj.name << " at " << psi_deg << " deg: signal " << c.max_signal
                         << " m/s, max diff " << c.max_diff << " m/s at " << c.t_worst << " s ("
                         << 100 * c.max_diff / c.max_signal << "%)");
        CHECK(c.max_diff <= tol);
      }
    }
  }
}

TEST_SUITE("model vs simulation") {
  TEST_CASE("several turns and whole revolutions: the linear model within 1% or 1e-4 m/s") {
    // model.md 9.1 on the profiles beyond the single turn: four reversals
    // (0-180-0-180-0 deg in the hour), one turn of 10 revolutions (0 to
    // 3600 deg, 121 s), and the recommended mix of both; each parameter
    // alone at a tenth of the prior and all together, in the tactical and
    // the navigation-grade scenario. Theta_33 on the revolutions is the
    // azimuth jump -(psi2 - psi1) Theta_33 (0.36 deg at a tenth of the
    // tactical prior).
    auto reversals = [] {
      Profile p = scenario::reference_profile();
      const TurnSpec t = p.turns[0];
      p.turns.clear();
      for (int k = 0; k < 4; ++k) {
        TurnSpec r = t;
        r.angle_rad = (k % 2 == 0 ? 180 : -180) * kDeg;
        r.start_s = 720.0 * (k + 1);
        p.turns.push_back(r);
      }
      return p;
    };
    auto revolutions = [] {
      Profile p = scenario::reference_profile();
      p.turns[0].angle_rad = 3600 * kDeg;
      return p;
    };
    const std::vector<std::pair<std::string, Profile>> profiles = {
        {"four reversals", reversals()},
        {"10 revolutions", revolutions()},
        {"recommended", scenario::from_plan("tactical-recommended.toml").profile}};
    for (const scenario::Scenario& grade : {scenario::tactical(), scenario::navigation_grade()})
      for (const auto& [name, profile] : profiles) {
        scenario::Scenario s = grade;
        s.profile = profile;
        const bool tactical = grade.priors.params[0] > 0.5 * kDegPerHour;
        for (const Injection& inj : injections_of(s)) {
          // the navigation grade: all together (each alone is smaller still)
          if (!tactical && inj.name != "all together") continue;
          CAPTURE(tactical);
          CAPTURE(name);
          CAPTURE(inj.name);
          const Comparison c = compare(inj.xi, 37 * kDeg, nullptr, s);
          const double tol = std::max(0.01 * c.max_signal, 1e-4);
          if (inj.name == "all together" || inj.name == "theta_33" || inj.name == "r1")
            MESSAGE(std::string(tactical ? "tactical, " : "navigation grade, ")
                    << name << ", " << inj.name << ": signal " << c.max_signal << " m/s, max diff "
                    << c.max_diff << " m/s at " << c.t_worst << " s ("
                    << 100 * c.max_diff / c.max_signal << "%)");
          CHECK(c.max_diff <= tol);
        }
      }
  }

  TEST_CASE("the comparison has teeth: a flipped sign misses by far more than 1%") {
    // model.md 9.1: a flipped sign anywhere misses by 50-200%. Flip the
    // model's reading of a parameter and the comparison must fail loudly.
    for (const Injection& inj : injections()) {
      if (inj.name != "theta_13" && inj.name != "heading error" && inj.name != "r1") continue;
      CAPTURE(inj.name);
      const est::XiVec flipped = -inj.xi;
      const Comparison c = compare(inj.xi, 37 * kDeg, &flipped);
      CHECK(c.max_diff > 0.5 * c.max_signal);
    }
  }
}
