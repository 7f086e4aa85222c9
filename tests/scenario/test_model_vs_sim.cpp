// model.md 9.1: the linear model against the nonlinear strapdown
// simulation, noise off, each parameter alone and all together.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>

#include <unsupported/Eigen/MatrixFunctions>
#include "scenarios.hpp"
#include "turncal/earth.hpp"

#include "turncal/estimation/model.hpp"
#include "turncal/estimation/nominal.hpp"
#include "turncal/estimation/timeline.hpp"
#include "turncal/physics/strapdown.hpp"

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

namespace {

/// One equation of the model changed: the sign of F's entry (row, col)
/// (every orientation), of a Theta_.3 turn-jump term (row b_i, column
/// Theta_j3), or of a proof-mass jump term (row dv_i, column r_j).
struct Mutation {
  enum Kind { None, F, ThetaJump, LeverJump } kind = None;
  int row = 0, col = 0;
  [[nodiscard]] std::string name() const {
    const auto n = [](int i) {
      static const char* names[est::sx::kNav] = {"dv1", "dv2", "a1", "a2", "b1", "b2", "b3"};
      return i < est::sx::kNav
                 ? std::string(names[i])
                 : std::string(est::kParamNames[static_cast<std::size_t>(i - est::sx::kNu0)]);
    };
    const char* k = kind == F ? "F" : kind == ThetaJump ? "Theta jump" : "lever-arm jump";
    return std::string(k) + " (" + n(row) + ", " + n(col) + ")";
  }
};

/// The model's mean propagation written out again, on the timeline of
/// compare() (epochs of 1 s, the turn by the encoder), with `m` applied:
/// the velocity error (dv1, dv2) at each epoch.
std::vector<Eigen::Vector2d> propagate(const est::TimelineInput& in, const est::XiVec& xi,
                                       const Mutation& m) {
  using namespace est;
  const EarthAt e = EarthAt::at(in.site);
  auto f_of = [&](double psi) {
    StateMat f = hold_dynamics(e, psi);
    if (m.kind == Mutation::F) f(m.row, m.col) = -f(m.row, m.col);
    return f;
  };
  auto hold = [&](double psi, double dt) { return StateMat((f_of(psi) * dt).exp()); };
  auto turn = [&](const TurnWindow& w, StateVec& x) {
    std::vector<AngleSample> s = {{w.t_start_s, psi_at(in.encoder, w.t_start_s)}};
    for (const AngleSample& a : in.encoder)
      if (a.t_s > w.t_start_s && a.t_s < w.t_end_s) s.push_back(a);
    s.push_back({w.t_end_s, psi_at(in.encoder, w.t_end_s)});
    for (std::size_t k = 0; k + 1 < s.size(); ++k) {
      const double dt = s[k + 1].t_s - s[k].t_s, p1 = s[k].psi_rad, p2 = s[k + 1].psi_rad;
      const StateMat fdt = f_of(0.5 * (p1 + p2)) * dt;
      StateMat step = StateMat::Identity() + fdt + 0.5 * fdt * fdt;
      const double sd = std::sin(p2) - std::sin(p1), cd = std::cos(p2) - std::cos(p1);
      const double ia[3][3] = {{sd, cd, 0}, {-cd, sd, 0}, {0, 0, p2 - p1}};
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const bool flip =
              m.kind == Mutation::ThetaJump && m.row == sx::kB + i && m.col == sx::theta(j + 1, 3);
          step(sx::kB + i, sx::theta(j + 1, 3)) -= (flip ? -1 : 1) * ia[i][j];
        }
      const double omega = (p2 - p1) / dt, mid = 0.5 * (p1 + p2);
      const double jc = omega * std::cos(mid) * (p2 - p1), js = omega * std::sin(mid) * (p2 - p1);
      const double jump[2][2] = {{jc, js}, {js, -jc}};
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) {
          const bool flip =
              m.kind == Mutation::LeverJump && m.row == sx::kDv + i && m.col == sx::kR + j;
          step(sx::kDv + i, sx::kR + j) += (flip ? -1 : 1) * jump[i][j];
        }
      x = step * x;
    }
    return s.back().psi_rad;
  };
  StateVec x = initial_map(e, in.psi_start_rad) * xi;
  double psi = in.psi_start_rad, t = 0;
  StateMat epoch = hold(psi, in.epoch_s);
  std::vector<Eigen::Vector2d> v;
  std::size_t next = 0;
  for (long k = 1; k <= static_cast<long>(in.duration_s / in.epoch_s); ++k) {
    const double to = static_cast<double>(k) * in.epoch_s;
    if (next < in.turns.size() && in.turns[next].t_start_s <= to) {
      if (to <= in.turns[next].t_end_s) continue;  // within the turn: no epoch
      const TurnWindow& w = in.turns[next++];
      x = hold(psi, w.t_start_s - t) * x;
      psi = turn(w, x);
      x = hold(psi, to - w.t_end_s) * x;
      epoch = hold(psi, in.epoch_s);
    } else {
      x = epoch * x;
    }
    t = to;
    v.emplace_back(x(sx::kDv), x(sx::kDv + 1));
  }
  return v;
}

}  // namespace

TEST_SUITE("model vs simulation") {
  TEST_CASE("mutation: each equation changed alone, the comparison misses") {
    // model.md 9.1's check has teeth only if no equation could be wrong and
    // still pass it. The model's propagation is written out again here (and
    // must match turncal's to 1e-9 of the signal); then each non-zero term
    // of F's navigation rows, each Theta_.3 turn-jump term and each
    // proof-mass jump term has its sign flipped alone, for each injection
    // of the check (each parameter alone at a tenth of the tactical prior,
    // the heading error, all together). Wherever a flip moves the velocity
    // by more than the check's tolerance, the check against the simulation
    // must fail; and every flip but one (below) must be seen so by at least
    // one injection.
    const scenario::Scenario s = scenario::tactical();
    const double psi_s = 37 * kDeg;
    const est::EarthAt earth = est::EarthAt::at(s.site);
    std::vector<Mutation> mutations;
    for (int i = 0; i < est::sx::kNav; ++i)
      for (int j = 0; j < est::sx::kN; ++j)
        if (est::hold_dynamics(earth, 0.3)(i, j) != 0 || est::hold_dynamics(earth, 1.9)(i, j) != 0)
          mutations.push_back({Mutation::F, i, j});
    for (int i = 0; i < 3; ++i)
      for (int j = 1; j <= 3; ++j)
        if ((i < 2 && j < 3) ||
            (i == 2 && j == 3))  // int A dpsi: [[S, C, 0], [-C, S, 0], [0, 0, dpsi]]
          mutations.push_back({Mutation::ThetaJump, est::sx::kB + i, est::sx::theta(j, 3)});
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j)
        mutations.push_back({Mutation::LeverJump, est::sx::kDv + i, est::sx::kR + j});
    std::vector<int> seen(mutations.size(), 0);
    int judged = 0;
    for (const Injection& inj : injections_of(s)) {
      CAPTURE(inj.name);
      const sim::Config cfg = scenario::sim_config(inj.xi, psi_s, s);
      const sim::Run run = sim::simulate(cfg);
      const TableTrajectory table(cfg.profile);
      est::TimelineInput in;
      in.site = s.site;
      in.epoch_s = 1.0;
      in.duration_s = cfg.profile.duration_s;
      in.psi_start_rad = psi_s;
      in.turns.push_back({table.turn_start(0), table.turn_end(0)});
      for (const auto& e : run.encoder) in.encoder.push_back({e.t_s, psi_s + e.angle_rad});
      std::vector<Eigen::Vector2d> truth, turncal;
      est::StateVec x = est::initial_map(earth, psi_s) * inj.xi;
      const auto per_epoch = static_cast<std::size_t>(std::llround(cfg.output_rate_hz));
      REQUIRE(est::for_each_step(in, [&](const est::TimelineStep& st) {
                x = st.d->phi * x;
                turncal.emplace_back(x(est::sx::kDv), x(est::sx::kDv + 1));
                const auto k = static_cast<std::size_t>(std::llround(st.t_to)) * per_epoch;
                truth.emplace_back(run.velocity[k].ve, run.velocity[k].vn);
              }).ok());
      double signal = 0;
      for (const auto& v : truth) signal = std::max(signal, v.norm());
      const double tol = std::max(0.01 * signal, 1e-4);
      auto worst = [](const std::vector<Eigen::Vector2d>& a,
                      const std::vector<Eigen::Vector2d>& b) {
        REQUIRE(a.size() == b.size());
        double w = 0;
        for (std::size_t k = 0; k < a.size(); ++k) w = std::max(w, (a[k] - b[k]).norm());
        return w;
      };
      const auto same = propagate(in, inj.xi, Mutation{});
      CHECK(worst(same, turncal) <= 1e-9 * signal);  // the replica is turncal's model
      CHECK(worst(same, truth) <= tol);              // and it passes
      for (std::size_t m = 0; m < mutations.size(); ++m) {
        const auto v = propagate(in, inj.xi, mutations[m]);
        if (worst(v, same) <= tol) continue;
        ++judged;
        ++seen[m];
        CAPTURE(mutations[m].name());
        CHECK(worst(v, truth) > tol);
      }
    }
    std::string never;
    for (std::size_t m = 0; m < mutations.size(); ++m)
      if (seen[m] == 0) never += " " + mutations[m].name();
    MESSAGE(mutations.size() << " single flips, judged " << judged
                             << " times over the injections; never above the tolerance:"
                             << (never.empty() ? " none" : never));
    // one term is below the tolerance for every injection: b3's rate from
    // b1 (u2 b1, the azimuth drift of a tilt; u2 = 4.1e-5 rad/s at 55.75
    // deg), whose velocity effect over the hour is second order in errors
    // at a tenth of the prior. Every other flip is caught.
    CHECK(never == " F (b3, b1)");
  }
}

namespace {

/// The second pass's model (model.md, 8) against the simulation: the
/// velocity of the nonlinear nominal at `nominal_xi`'s parameters (the
/// estimator's own, strapdown_nominal: the strapdown driven by the
/// encoder samples, start errors zero) plus the linear model carrying
/// x0 = T (xi - nominal_xi) on (linearised about the nominal, or with
/// `linearised_there` false about zero), against the simulation of `xi`,
/// at every epoch. With nominal_xi zero and not linearised there it is
/// compare(): the linear model alone.
Comparison compare_about(const est::XiVec& xi, const est::XiVec& nominal_xi, double psi_s,
                         const scenario::Scenario& where, bool linearised_there = true) {
  const sim::Config cfg = scenario::sim_config(xi, psi_s, where);
  const sim::Run run = sim::simulate(cfg);
  const TableTrajectory table(cfg.profile);
  est::EstimationInput ein;
  est::TimelineInput& in = ein.timeline;
  in.site = where.site;
  in.epoch_s = 1.0;
  in.duration_s = cfg.profile.duration_s;
  in.psi_start_rad = psi_s;
  for (std::size_t i = 0; i < table.turns(); ++i)
    in.turns.push_back({table.turn_start(i), table.turn_end(i)});
  for (const auto& e : run.encoder) in.encoder.push_back({e.t_s, psi_s + e.angle_rad});
  ein.priors.align_s = cfg.profile.align_s;
  std::array<double, est::sx::kParams> p{};
  for (int j = 0; j < est::sx::kParams; ++j)
    p[static_cast<std::size_t>(j)] = nominal_xi(est::sxi::kParams + j);
  auto nominal_run = est::strapdown_nominal(ein, p);
  REQUIRE(nominal_run.ok());
  const std::vector<est::VelocityObs>* nominal = &nominal_run->velocity;
  if (linearised_there)
    in.nominal = est::Nominal{
        p, std::make_shared<const std::vector<est::NominalState>>(std::move(nominal_run->track))};
  REQUIRE(nominal->size() == run.velocity.size());
  const est::EarthAt earth = est::EarthAt::at(in.site);
  est::StateVec x = est::initial_map(earth, psi_s) * (xi - nominal_xi);
  Comparison c;
  const auto per_epoch = static_cast<std::size_t>(std::llround(cfg.output_rate_hz * in.epoch_s));
  const auto steps = est::for_each_step(in, [&](const est::TimelineStep& s) {
    x = s.d->phi * x;
    const auto k = static_cast<std::size_t>(std::llround(s.t_to / in.epoch_s)) * per_epoch;
    REQUIRE(k < run.velocity.size());
    const sim::VelocitySample& v = run.velocity[k];
    const est::VelocityObs& h = (*nominal)[k];
    REQUIRE(std::fabs(v.t_s - s.t_to) < 1e-9);
    REQUIRE(std::fabs(h.t_s - s.t_to) < 1e-9);
    const double d = std::hypot(h.ve + x(est::sx::kDv) - v.ve, h.vn + x(est::sx::kDv + 1) - v.vn);
    c.max_signal = std::max(c.max_signal, std::hypot(v.ve, v.vn));
    if (d > c.max_diff) {
      c.max_diff = d;
      c.t_worst = s.t_to;
    }
  });
  REQUIRE(steps.ok());
  return c;
}

}  // namespace

TEST_SUITE("model vs simulation") {
  TEST_CASE("full prior, 10 revolutions: the second pass's model within 1%, the linear one not") {
    // model.md 9.1 at the full tactical prior, where the linear model alone
    // misses by more: 10 revolutions (0 to 3600 deg at 1800 s) at one
    // sigma of Theta_33 are an azimuth jump of -(psi2 - psi1) Theta_33 =
    // 3.6 deg. Given the truth at one prior sigma (Theta_33 alone, and
    // every parameter with signs mixed and the start errors), when the
    // second pass linearises about a first estimate off the truth by a
    // tenth of the prior in every parameter (the size of the linear
    // regime, and far more than the first pass's error in what it
    // determines), then its model (the nonlinear nominal there plus the
    // linear model for the rest) predicts the simulated INS velocity
    // within 1% of the signal, where the linear model about zero misses
    // by more than 1%.
    scenario::Scenario s = scenario::tactical();
    s.profile.turns[0].angle_rad = 3600 * kDeg;
    using namespace est;
    XiVec theta33 = XiVec::Zero();
    const int t33 = sx::theta(3, 3) - sx::kNu0;
    theta33(sxi::kParams + t33) = s.priors.params[static_cast<std::size_t>(t33)];
    XiVec all = XiVec::Zero();
    for (int p = 0; p < sx::kParams; ++p)
      all(sxi::kParams + p) =
          (p % 3 == 1 ? -1.0 : 1.0) * s.priors.params[static_cast<std::size_t>(p)];
    all(sxi::kDpsi0) = s.priors.heading_rad;
    all(sxi::kDrE) = s.priors.position_m;
    all(sxi::kDrN) = -s.priors.position_m;
    all(sxi::kV0) = s.priors.v0_mps;
    for (const auto& [name, xi] : {std::pair{std::string("theta_33"), theta33},
                                   std::pair{std::string("all together"), all}}) {
      CAPTURE(name);
      // the first estimate: each parameter off by a tenth of its prior
      XiVec first = XiVec::Zero();
      for (int p = 0; p < sx::kParams; ++p)
        first(sxi::kParams + p) =
            xi(sxi::kParams + p) +
            (p % 2 == 0 ? 0.1 : -0.1) * s.priors.params[static_cast<std::size_t>(p)];
      const Comparison linear = compare_about(xi, XiVec::Zero(), 37 * kDeg, s, false);
      const Comparison second = compare_about(xi, first, 37 * kDeg, s);
      const Comparison about_zero = compare_about(xi, first, 37 * kDeg, s, false);
      MESSAGE("full prior, 10 revolutions, "
              << name << ": signal " << linear.max_signal << " m/s; linear model misses by "
              << 100 * linear.max_diff / linear.max_signal << "%, the second pass's by "
              << 100 * second.max_diff / second.max_signal << "% (" << second.max_diff << " m/s at "
              << second.t_worst << " s); the nominal with the model about zero "
              << 100 * about_zero.max_diff / about_zero.max_signal << "%");
      CHECK(linear.max_diff > 0.01 * linear.max_signal);
      CHECK(second.max_diff <= std::max(0.01 * second.max_signal, 1e-4));
    }
  }
}

namespace {

/// The largest difference of two matrices over the largest entry of the
/// first, each row scaled to its own largest entry (F's rows span 1e-7
/// to 10 in SI).
template <class M>
double row_relative(const M& a, const M& b) {
  double worst = 0;
  for (Eigen::Index i = 0; i < a.rows(); ++i) {
    const double scale = a.row(i).cwiseAbs().maxCoeff();
    const double diff = (a.row(i) - b.row(i)).cwiseAbs().maxCoeff();
    if (scale > 0)
      worst = std::max(worst, diff / scale);
    else if (diff > 0)
      worst = INFINITY;
  }
  return worst;
}

/// A nominal at zero errors: its state at rest at the site, its attitude
/// the true one, over an hour.
est::Nominal zero_nominal() {
  auto track = std::make_shared<std::vector<est::NominalState>>(2);
  (*track)[1].t_s = 3600;
  return est::Nominal{{}, std::move(track)};
}

}  // namespace

TEST_SUITE("model about a nominal") {
  TEST_CASE("about a nominal at zero errors it is the model about zero, rows to 1e-12") {
    // The error equations about the nominal's state, in the perturbation's
    // coordinates and carried back to the model's, at zero: model.md's F,
    // its transition and noise, each row to 1e-12 of its largest entry
    // (rounding of the coordinates' change). The hold's transition about a
    // nominal comes from the navigation block alone; about zero from the
    // whole matrix exponential: the two agree as well, the noise to 1e-8
    // (Van Loan's Q_d = Phi E12 loses digits to cancellation in the
    // scaling and squaring, whose count differs between the two sizes:
    // measured 1.3e-9).
    const scenario::Scenario s = scenario::tactical();
    const est::EarthAt e = est::EarthAt::at(s.site);
    const est::ProcessNoise noise{1e-8, 1e-12};
    for (const double psi : {0.0, 0.7, 2.5, -2.0}) {
      CAPTURE(psi);
      const est::Nominal nom = zero_nominal();
      const est::StateMat f0 = est::hold_dynamics(e, psi);
      const est::StateMat fn = est::hold_dynamics(e, psi, &nom, 100);
      CHECK(row_relative(f0, fn) < 1e-12);
      const est::Discrete d0 = est::discretize_hold(e, psi, 1.0, noise);
      const est::Discrete dn = est::discretize_hold(e, psi, 1.0, noise, &nom, 100);
      CHECK(row_relative(d0.phi, dn.phi) < 1e-12);
      CHECK(row_relative(d0.q, dn.q) < 1e-8);
      CHECK(row_relative(est::StateMat(d0.sqrt_q * d0.sqrt_q.transpose()),
                         est::StateMat(dn.sqrt_q * dn.sqrt_q.transpose())) < 1e-8);
      std::vector<est::AngleSample> turn;
      for (int k = 0; k <= 100; ++k)
        turn.push_back(
            {10 + 0.05 * k, psi + earth::kPi * (1 - std::cos(earth::kPi * k / 100)) / 2});
      const est::Discrete t0 = est::turn_transition(e, turn, noise);
      const est::Discrete tn = est::turn_transition(e, turn, noise, nullptr, &nom);
      CHECK(row_relative(t0.phi, tn.phi) < 1e-12);
      CHECK(row_relative(t0.q, tn.q) < 1e-9);
    }
  }

  TEST_CASE("a nominal without a navigation state from t0 is refused; alone it is zero") {
    est::TimelineInput in;
    in.site = scenario::tactical().site;
    in.duration_s = 10;
    const est::Nominal none{{}, nullptr};
    CHECK(none.at(3).e == Eigen::Matrix3d::Identity());
    CHECK(none.at(3).ve == 0);
    auto late = std::make_shared<std::vector<est::NominalState>>(1);
    (*late)[0].t_s = 0.5;
    for (const est::Nominal& n :
         {none, est::Nominal{{}, std::make_shared<std::vector<est::NominalState>>()},
          est::Nominal{{}, late}}) {
      if (n.track != late) {  // no state at all: the state at zero errors, at the time asked
        const est::NominalState z = n.at(3);
        CHECK(z.t_s == 3);
        CHECK(z.ve == 0);
        CHECK(z.vn == 0);
        CHECK(z.dlat_rad == 0);
        CHECK(z.e == Eigen::Matrix3d::Identity());
      }
      in.nominal = n;
      int steps = 0;
      const auto r = est::for_each_step(in, [&](const est::TimelineStep&) { ++steps; });
      REQUIRE_FALSE(r.ok());
      CHECK(r.error().describe().find("no navigation state from t0") != std::string::npos);
      CHECK(steps == 0);
    }
    in.nominal = zero_nominal();
    int steps = 0;
    CHECK(est::for_each_step(in, [&](const est::TimelineStep&) { ++steps; }).ok());
    CHECK(steps == 10);
  }

  TEST_CASE("the nominal's state is linear between its samples, held beyond them, any order") {
    auto track = std::make_shared<std::vector<est::NominalState>>(3);
    for (int k = 0; k < 3; ++k) {
      est::NominalState& n = (*track)[static_cast<std::size_t>(k)];
      n.t_s = 10.0 * k;
      n.ve = 1.0 + k;
      n.vn = -2.0 * k * k;
      n.dlat_rad = 1e-3 * k;
      n.e(0, 1) = 0.01 * k;
    }
    const est::Nominal nom{{}, track};
    std::size_t hint = 0;
    // ascending, then back: the hint is only where the search starts
    for (const double t : {-5.0, 0.0, 5.0, 15.0, 20.0, 25.0, 12.5, 2.5}) {
      CAPTURE(t);
      const est::NominalState n = nom.at(t, hint);
      CHECK(n.t_s == t);  // the time asked, held beyond the ends too
      const double c = std::clamp(t, 0.0, 20.0);
      const double vn = c <= 10 ? -0.2 * c : -2.0 - 0.6 * (c - 10);
      CHECK(n.ve == doctest::Approx(1.0 + c / 10).epsilon(1e-12));
      CHECK(n.vn == doctest::Approx(vn).epsilon(1e-12));
      CHECK(n.dlat_rad == doctest::Approx(1e-4 * c).epsilon(1e-12).scale(1e-3));
      CHECK(n.e(0, 1) == doctest::Approx(1e-3 * c).epsilon(1e-12).scale(1e-2));
      CHECK(n.e(0, 0) == 1.0);
    }
  }
}
