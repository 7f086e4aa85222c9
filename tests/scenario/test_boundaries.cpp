// model.md 5: the measurements at the turn boundaries (the last INS sample
// before a turn, the first after it), the mean measurement's window, and
// turns closer together than one epoch; against an independent filter and
// the nonlinear simulation.
#include <doctest/doctest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>

#include "scenarios.hpp"
#include "turncal/estimation/estimator.hpp"

using namespace turncal;
using namespace scenario;

namespace {

constexpr std::size_t kIdx(int state_index) {
  return static_cast<std::size_t>(state_index - est::sx::kNu0);
}

/// The reference profile with its turn moved off the epoch grid.
Profile off_grid(double start_s) {
  Profile p = reference_profile();
  p.turns[0].start_s = start_s;
  return p;
}

est::EstimationInput plan_of(const Scenario& s, double psi_s, const Profile& profile) {
  const TableTrajectory table(profile);
  est::EstimationInput in;
  in.timeline = timeline(s, psi_s, table, encoder_of(table, profile.duration_s));
  in.priors = s.priors;
  in.sigma_z = s.sigma_z;
  return in;
}

/// An independent covariance filter (the plain Kalman form with Joseph's
/// update, not turncal's square-root one) that measures on the epoch grid
/// and at exactly the turn's start and end: the parameters' sigmas.
std::array<double, est::sx::kParams> reference_sigmas(const est::EstimationInput& in) {
  const est::TimelineInput& tl = in.timeline;
  REQUIRE(tl.turns.size() == 1);
  const double t1 = tl.turns[0].t_start_s, t2 = tl.turns[0].t_end_s;
  const est::EarthAt e = est::EarthAt::at(tl.site);
  const est::XiMat map = est::initial_map(e, tl.psi_start_rad);
  const est::XiVec s0 = est::prior_sigmas(in.priors, tl.noise);
  est::StateMat p = map * s0.cwiseAbs2().asDiagonal() * map.transpose();
  const est::MeasMat h = est::velocity_measurement();
  const Eigen::Matrix2d r = Eigen::Matrix2d::Identity() * in.sigma_z * in.sigma_z;
  auto update = [&] {
    const Eigen::Matrix2d s = h * p * h.transpose() + r;
    const Eigen::Matrix<double, est::sx::kN, 2> k = p * h.transpose() * s.inverse();
    const est::StateMat a = est::StateMat::Identity() - k * h;
    p = a * p * a.transpose() + k * r * k.transpose();
  };
  auto propagate = [&](const est::Discrete& d) { p = d.phi * p * d.phi.transpose() + d.q; };
  std::vector<est::AngleSample> turn = {{t1, est::psi_at(tl.encoder, t1)}};
  for (const est::AngleSample& a : tl.encoder)
    if (a.t_s > t1 && a.t_s < t2) turn.push_back(a);
  turn.push_back({t2, est::psi_at(tl.encoder, t2)});
  double t = 0, psi = tl.psi_start_rad;
  for (long k = 1; k <= static_cast<long>(tl.duration_s / tl.epoch_s); ++k) {
    const double at = static_cast<double>(k) * tl.epoch_s;
    if (at >= t1 && at <= t2) continue;
    if (t < t1 && at > t2) {
      propagate(est::discretize_hold(e, psi, t1 - t, tl.noise));
      update();
      propagate(est::turn_transition(e, turn, tl.noise));
      psi = turn.back().psi_rad;
      update();
      t = t2;
    }
    propagate(est::discretize_hold(e, psi, at - t, tl.noise));
    update();
    t = at;
  }
  std::array<double, est::sx::kParams> out{};
  for (int j = 0; j < est::sx::kParams; ++j)
    out[static_cast<std::size_t>(j)] = std::sqrt(p(est::sx::kNu0 + j, est::sx::kNu0 + j));
  return out;
}

/// The largest normalized innovation of a run, and when.
std::pair<double, double> worst_innovation(const est::EstimationResult& r) {
  double worst = 0, at = NAN;
  for (const est::Innovation& i : r.innovations) {
    const Eigen::LLT<Eigen::Matrix2d> llt(i.cov);
    const double n = llt.matrixL().solve(i.value).cwiseAbs().maxCoeff();
    if (n > worst) {
      worst = n;
      at = i.t_s;
    }
  }
  return {worst, at};
}

/// A noise-free tactical run with the errors at a tenth of the prior and
/// the proof-mass offset at its full prior (a turn transient of 50 to 70
/// sigma of a mean measurement, were it let into one).
struct SimulatedRun {
  Scenario s = tactical();
  double psi_s = 37 * kDeg;
  sim::Config cfg;
  sim::Run run;
  explicit SimulatedRun(const Profile& profile) {
    std::mt19937_64 rng(5);
    est::XiVec xi = 0.1 * draw(s, rng);
    xi(est::sxi::kParams + kIdx(est::sx::kR)) = 0.03;
    xi(est::sxi::kParams + kIdx(est::sx::kR) + 1) = -0.02;
    s.profile = profile;
    cfg = sim_config(xi, psi_s, s);
    run = sim::simulate(cfg);
  }
  [[nodiscard]] est::EstimationInput input(bool mean) const {
    const TableTrajectory table(cfg.profile);
    est::EstimationInput in;
    in.timeline = timeline(s, psi_s, table, run.encoder);
    in.priors = s.priors;
    in.sigma_z = s.sigma_z;
    in.mean_measurement = mean;
    in.sample_rate_hz = cfg.output_rate_hz;
    for (const auto& v : run.velocity) in.velocity.push_back({v.t_s, v.ve, v.vn});
    return in;
  }
};

}  // namespace

TEST_SUITE("turn boundaries") {
  TEST_CASE(
      "measured at the turn's last and first still samples: the independent filter's "
      "sigmas to 2%") {
    // The turn starts 0.373 s after an epoch: on the grid alone the
    // samples nearest it are not measured. turncal measures the last 100 Hz
    // sample before the turn (3 ms before it) and the first after; the
    // reference filter measures at exactly the turn's start and end.
    for (const Scenario& s : {tactical(), navigation_grade()}) {
      const est::EstimationInput in = plan_of(s, 37 * kDeg, off_grid(1800.373));
      const auto with = est::analyse(in);
      REQUIRE(with.ok());
      est::EstimationInput grid = in;
      grid.boundary_measurements = false;
      const auto without = est::analyse(grid);
      REQUIRE(without.ok());
      const auto ref = reference_sigmas(in);
      for (const int j : {est::sx::kR, est::sx::kR + 1, est::sx::kDf0, est::sx::kDf0 + 1}) {
        const std::size_t u = kIdx(j);
        CAPTURE(est::kParamNames[u]);
        MESSAGE(est::kParamNames[u] << ": sigma " << with->parameters[u].sigma << ", reference "
                                    << ref[u] << ", the grid alone "
                                    << without->parameters[u].sigma);
        CHECK(with->parameters[u].sigma == doctest::Approx(ref[u]).epsilon(0.02).scale(0));
      }
      // the proof-mass offset is seen in the turn's jump: the grid alone,
      // a hold of 0.37 s and 0.63 s of free drift around it, loses on it
      for (const int j : {est::sx::kR, est::sx::kR + 1})
        CHECK(without->parameters[kIdx(j)].sigma > 1.03 * with->parameters[kIdx(j)].sigma);
    }
  }

  TEST_CASE("the covariance analysis has the schedule of the data: boundaries off the grid") {
    // the data at 100 Hz from t0, the turn off the epoch grid: the analysis
    // and the filter on data reach the same covariance, in both modes
    for (const bool mean : {false, true}) {
      CAPTURE(mean);
      est::EstimationInput in = plan_of(tactical(), 37 * kDeg, off_grid(1800.373));
      in.mean_measurement = mean;
      in.sample_rate_hz = 100;
      std::mt19937_64 rng(3);
      std::normal_distribution<double> n(0, in.sigma_z);
      for (long k = 1; k <= 360000; ++k)
        in.velocity.push_back({static_cast<double>(k) / 100, n(rng), n(rng)});
      const auto a = est::analyse(in);
      const auto e = est::estimate(in);
      REQUIRE(a.ok());
      REQUIRE(e.ok());
      double worst = 0;
      for (int i = 0; i < est::sx::kN; ++i)
        for (int j = 0; j < est::sx::kN; ++j)
          worst = std::max(worst,
                           std::fabs(a->p(i, j) - e->p(i, j)) / std::sqrt(e->p(i, i) * e->p(j, j)));
      CHECK(worst < 1e-9);
      CHECK(a->epoch_t == e->epoch_t);
      // the boundary measurements are there: 1800.37 and 1807.38 s
      const auto has = [&](double t) {
        return std::any_of(e->epoch_t.begin(), e->epoch_t.end(),
                           [&](double x) { return std::abs(x - t) < 1e-6; });
      };
      CHECK(has(1800.37));
      CHECK(has(1807.38));
      CHECK_FALSE(has(1801.0));  // inside the turn
    }
  }

  TEST_CASE("a mean is centred on its epoch: a velocity growing linearly is measured at it") {
    // v_E = c t sampled at 100 Hz: the mean around epoch 1 s, of the
    // samples in (0.5 s, 1.5 s], is c * 1.005 s: centred to half a sample
    // (as the nearest sample is). A mean over the epoch before it, stamped
    // at its end, would be c * 0.505 s. The first innovation is the
    // measurement itself (the state starts at zero).
    est::EstimationInput in = plan_of(tactical(), 0, reference_profile());
    in.mean_measurement = true;
    const double c = 1e-4;  // m/s^2
    for (long k = 1; k <= 360000; ++k) {
      const double t = static_cast<double>(k) / 100;
      in.velocity.push_back({t, c * t, 0});
    }
    const auto e = est::estimate(in);
    REQUIRE(e.ok());
    REQUIRE(!e->innovations.empty());
    CHECK(e->innovations[0].t_s == 1.0);
    CHECK(e->innovations[0].value(0) == doctest::Approx(c * 1.005).epsilon(1e-9).scale(0));
  }

  TEST_CASE("no sample of a turn enters any measurement: turn samples of 1 m/s change nothing") {
    // zero velocity everywhere but inside the turn window, where it is
    // 1 m/s (1000 sigma): the estimate is the one of all zeros, in both
    // modes, with the turn off the grid and the samples 3 ms off it
    for (const bool mean : {false, true}) {
      CAPTURE(mean);
      est::EstimationInput in = plan_of(tactical(), 37 * kDeg, off_grid(1800.373));
      in.mean_measurement = mean;
      const est::TurnWindow w = in.timeline.turns[0];
      for (long k = 0; k < 360000; ++k) {
        const double t = (static_cast<double>(k) + 0.3) / 100;
        in.velocity.push_back({t, 0, 0});
      }
      const auto zero = est::estimate(in);
      REQUIRE(zero.ok());
      std::size_t in_turn = 0;
      for (est::VelocityObs& v : in.velocity)
        if (v.t_s > w.t_start_s && v.t_s < w.t_end_s) {
          v.ve = v.vn = 1.0;
          ++in_turn;
        }
      CHECK(in_turn == 700);
      const auto turned = est::estimate(in);
      REQUIRE(turned.ok());
      CHECK(turned->x == zero->x);
      CHECK(turned->innovations.size() == zero->innovations.size());
      // and the samples just outside it are measured: 1 m/s there shows
      for (est::VelocityObs& v : in.velocity)
        if (v.t_s > w.t_start_s - 0.01 && v.t_s < w.t_end_s + 0.01) v.ve = 1.0;
      const auto edges = est::estimate(in);
      REQUIRE(edges.ok());
      CHECK(edges->x != zero->x);
    }
  }

  TEST_CASE("mean measurements of a simulated run follow the simulation through the turn") {
    // Noise off; every injected error is within one prior sigma (a tenth of
    // it, the proof-mass offset at 1 and 0.67 sigma), so a model that
    // follows the simulation keeps each normalized innovation near 1 at
    // most; 2 leaves room for the filter's own transients, where a turn
    // sample in a mean would be tens.
    const SimulatedRun sim(off_grid(1800.373));
    const auto r = est::estimate(sim.input(true));
    REQUIRE(r.ok());
    const auto [worst, at] = worst_innovation(*r);
    MESSAGE("mean mode: largest normalized innovation " << worst << " at " << at << " s");
    CHECK(worst < 2.0);
  }

  TEST_CASE(
      "two turns closer together than one epoch: one step through both, against the "
      "simulation") {
    // +180 deg, then back -90 deg 0.4 s after the first ends; in between,
    // the hold has 40 samples: the boundary measurements are there, and no
    // epoch falls inside either turn
    Profile p = off_grid(1800.373);
    TurnSpec back = p.turns[0];
    back.angle_rad = -90 * kDeg;
    back.start_s = 1807.773;
    p.turns.push_back(back);
    const SimulatedRun sim(p);
    for (const bool mean : {false, true}) {
      CAPTURE(mean);
      const est::EstimationInput in = sim.input(mean);
      REQUIRE(in.timeline.turns.size() == 2);
      const auto r = est::estimate(in);
      REQUIRE(r.ok());
      CHECK(r->timeline.turns.size() == 2);
      const auto [worst, at] = worst_innovation(*r);
      MESSAGE("largest normalized innovation " << worst << " at " << at << " s");
      CHECK(worst < 2.0);  // as for one turn above
      // no measurement inside a turn
      for (const double t : r->epoch_t)
        for (const est::TurnWindow& w : in.timeline.turns)
          CHECK_FALSE((t > w.t_start_s && t < w.t_end_s));
    }
    // the second turn right at the first one's end: no sample between
    // them, one step takes both turns
    est::EstimationInput tight = sim.input(false);
    tight.timeline.turns[1].t_start_s = tight.timeline.turns[0].t_end_s;
    const auto r = est::analyse(tight);
    REQUIRE(r.ok());
    CHECK(r->timeline.turns.size() == 2);
  }
}
