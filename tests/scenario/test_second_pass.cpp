// The nonlinear second pass (model.md, 8): its criterion on both sides and
// what it does on a run where it runs. The Monte Carlo of its calibration
// is in test_monte_carlo.cpp, the model it linearises in
// test_model_vs_sim.cpp.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "monte_carlo.hpp"
#include "turncal/estimation/nominal.hpp"

using namespace scenario;

namespace {

struct Simulated {
  est::EstimationInput in;
  est::XiVec truth;
};

/// The recommended tactical plan with its priors scaled by `scale`, the
/// errors of seed `seed` drawn as the Monte Carlo draws them, noise on.
Simulated recommended_run(double scale, std::uint64_t seed) {
  Scenario s = from_plan("tactical-recommended.toml");
  for (double& p : s.priors.params) p *= scale;
  std::mt19937_64 rng(seed);
  Simulated out;
  out.truth = draw(s, rng);
  const double psi_s = std::uniform_real_distribution<double>(0, 2 * earth::kPi)(rng);
  const sim::Config cfg = sim_config(s, out.truth, psi_s, rng());
  const sim::Run run = sim::simulate(cfg);
  const TableTrajectory table(cfg.profile);
  out.in.timeline = timeline(s, psi_s, table, run.encoder);
  out.in.priors = s.priors;
  out.in.sigma_z = s.sigma_z;
  for (const auto& v : run.velocity) out.in.velocity.push_back({v.t_s, v.ve, v.vn});
  out.in.second_pass.nominal = &est::strapdown_nominal;
  out.in.second_pass.threads = default_threads();
  return out;
}

/// A nominal that is the strapdown's plus an East ramp that flips sign
/// and grows tenfold at each call: an iteration about it must diverge.
int g_diverging_calls = 0;
Result<std::vector<est::VelocityObs>> diverging_nominal(
    const est::EstimationInput& in, const std::array<double, est::sx::kParams>& p) {
  auto v = est::strapdown_nominal(in, p);
  if (!v) return v;
  const double slope =
      (g_diverging_calls % 2 == 0 ? 1.0 : -1.0) * 1e-5 * std::pow(10.0, g_diverging_calls);
  ++g_diverging_calls;
  for (est::VelocityObs& o : *v) o.ve += slope * o.t_s;
  return v;
}

/// The strapdown's nominal, counting its calls, that fails at call
/// g_fail_at (none: count only).
int g_nominal_calls = 0;
int g_fail_at = 0;
Result<std::vector<est::VelocityObs>> failing_nominal(
    const est::EstimationInput& in, const std::array<double, est::sx::kParams>& p) {
  if (++g_nominal_calls == g_fail_at) return turncal::make_error("an injected failure");
  return est::strapdown_nominal(in, p);
}

/// The square of df_obs_i's sigma, m^2/s^4.
double var_obs(const est::EstimationResult& r, std::size_t i) {
  return r.df_obs[i].sigma * r.df_obs[i].sigma;
}

}  // namespace

TEST_SUITE("second pass") {
  TEST_CASE("an iteration that diverges is no estimate: the first pass stands, and says so") {
    // Given the recommended plan at the full prior, seed 2000, where the
    // second pass runs, and a nominal whose error grows at each call: the
    // change grows from one iteration to the next, the iteration stops,
    // and the result is the first pass's, bit for bit, its reason saying
    // why.
    Simulated run = recommended_run(1.0, 2000);
    est::EstimationInput off = run.in;
    off.second_pass.mode = est::SecondPassSettings::Mode::Off;
    const auto linear = est::estimate(off);
    g_diverging_calls = 0;
    run.in.second_pass.nominal = &diverging_nominal;
    const auto r = est::estimate(run.in);
    REQUIRE(linear.ok());
    REQUIRE(r.ok());
    MESSAGE(r->second_pass.reason);
    CHECK(g_diverging_calls >= 2);
    CHECK_FALSE(r->second_pass.ran);
    CHECK_FALSE(r->second_pass.converged);
    CHECK(r->second_pass.reason.find("diverged") != std::string::npos);
    CHECK(r->second_pass.reason.find("the first pass's estimates stand") != std::string::npos);
    CHECK(r->x == linear->x);
    CHECK(r->p == linear->p);
  }

  TEST_CASE("the criterion's speed is the run's largest, a NaN sample's left out") {
    // rho = b3 + v_max / sqrt(g sqrt(Rm Rn)) is linear in v_max: the
    // criterion with a fastest sample of 300 m/s is as far above that with
    // none as twice that with 150 m/s, wherever in the run it lies; slower
    // samples before and after it, one with the larger component (0.9 of
    // the speed East, the fastest's largest 0.8), one with the larger sum
    // of components (1.41 against 1.4), and a NaN one change nothing
    Simulated run = recommended_run(1.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Off;
    const auto first = est::estimate(run.in);
    REQUIRE(first.ok());
    const auto criterion = [&](double speed, std::size_t at, bool others) {
      est::EstimationInput in = run.in;
      for (est::VelocityObs& v : in.velocity) v.ve = v.vn = 0;
      if (speed > 0) {
        in.velocity[at].ve = -0.6 * speed;
        in.velocity[at].vn = 0.8 * speed;
      }
      if (others) {
        in.velocity[at / 2].ve = 0.9 * speed;  // slower, its larger component larger
        const std::size_t after = (at + in.velocity.size()) / 2;
        in.velocity[after].ve = in.velocity[after].vn = 0.705 * speed;  // slower, |ve|+|vn| larger
        in.velocity[at + 1].ve = std::nan("");
      }
      return est::linearisation_error_sigma(in, *first);
    };
    const std::size_t n = run.in.velocity.size();
    const double none = criterion(0, n / 3, false);
    const double step = criterion(150, n / 3, false) - none;
    CHECK(step > 0.1 * none);  // the speed matters here
    for (const std::size_t at : {n / 3, n / 2}) {
      CAPTURE(at);
      const double twice = criterion(300, at, true) - none;
      CHECK(std::abs(twice - 2 * step) <= 1e-9 * twice);
      CHECK(criterion(300, at, true) == criterion(300, at, false));
    }
  }

  TEST_CASE("it runs where the first pass predicts a linearisation error, and converges") {
    // Given the recommended plan at the full tactical prior (velocities of
    // 100 m/s, a 10-revolution azimuth jump of degrees), seed 2000: the
    // criterion predicts an error of sigmas (over the 0.3 threshold), the
    // second pass runs and converges to 0.01 sigma within its 5
    // iterations, and what it determines lies within 4 of its sigmas of
    // the truth (a determined quantity misses by that one run in 16,000).
    Simulated run = recommended_run(1.0, 2000);
    const auto linear = [&] {
      est::EstimationInput in = run.in;
      in.second_pass.mode = est::SecondPassSettings::Mode::Off;
      return est::estimate(in);
    }();
    const auto r = est::estimate(run.in);
    REQUIRE(linear.ok());
    REQUIRE(r.ok());
    MESSAGE("full prior: " << r->second_pass.reason << "; iterations " << r->second_pass.iterations
                           << ", last change " << r->second_pass.last_change_sigma << " sigma");
    CHECK_FALSE(linear->second_pass.ran);
    CHECK(linear->second_pass.predicted_sigma == r->second_pass.predicted_sigma);
    CHECK(r->second_pass.predicted_sigma > run.in.second_pass.threshold_sigma);
    CHECK(r->second_pass.ran);
    CHECK(r->second_pass.converged);
    CHECK(r->second_pass.iterations >= 2);  // one to move, one to see it stay
    CHECK(r->second_pass.iterations <= run.in.second_pass.max_iterations);
    CHECK(r->second_pass.last_change_sigma < 0.01);
    double moved = 0;
    for (std::size_t i = 0; i < 2; ++i)
      moved = std::max(moved,
                       std::abs(r->df_obs[i].value - linear->df_obs[i].value) / r->df_obs[i].sigma);
    MESSAGE("df_obs moved by " << moved << " sigma from the linear model's");
    // the pass changed what it was run for, by more than its own tolerance
    // (0.068 sigma measured on this seed, against 0.01): a pass that
    // returned the first pass's estimates would fail here
    CHECK(moved > 2 * run.in.second_pass.tolerance_sigma);
    const double g = est::EarthAt::at(run.in.timeline.site).g;
    const auto truth = [&](int state) {
      return run.truth(est::sxi::kParams + state - est::sx::kNu0);
    };
    for (std::size_t j = 0; j < est::sx::kParams; ++j) {
      const est::ParameterEstimate& q = r->parameters[j];
      if (!(q.sigma < 0.5 * q.prior_sigma)) continue;
      CAPTURE(q.name);
      CHECK(std::abs(q.value - truth(est::sx::kNu0 + static_cast<int>(j))) <= 4 * q.sigma);
    }
    for (int i = 0; i < 2; ++i) {
      const double obs = truth(est::sx::kDf0 + i) + g * truth(est::sx::kG + i) -
                         g * truth(est::sx::theta(i + 1, 3));
      const est::ParameterEstimate& q = r->df_obs[static_cast<std::size_t>(i)];
      CAPTURE(q.name);
      MESSAGE(q.name << ": second pass z " << (q.value - obs) / q.sigma << ", linear model z "
                     << (linear->df_obs[static_cast<std::size_t>(i)].value - obs) /
                            linear->df_obs[static_cast<std::size_t>(i)].sigma);
      CHECK(std::abs(q.value - obs) <= 4 * q.sigma);
    }
  }

  TEST_CASE("its nominal at 100 Hz gives the estimates of one at the simulation's 400 Hz") {
    // Given the recommended plan at the full tactical prior, seed 2000
    // (where the second pass runs), with the nominal's strapdown at its
    // default rate and at the 400 Hz the simulated INS itself runs at:
    // every determined parameter and df_obs differ by under 0.05 of their
    // sigma (an error of 0.05 sigma added in quadrature moves the RMS of
    // error/sigma by 0.1%; the iteration itself stops at 0.01 sigma).
    Simulated run = recommended_run(1.0, 2000);
    REQUIRE(run.in.second_pass.nominal_imu_rate_hz == 100);
    const auto fast = [&] {
      est::EstimationInput in = run.in;
      in.second_pass.nominal_imu_rate_hz = 400;
      return est::estimate(in);
    }();
    const auto r = est::estimate(run.in);
    REQUIRE(fast.ok());
    REQUIRE(r.ok());
    REQUIRE(r->second_pass.ran);
    REQUIRE(fast->second_pass.ran);
    double worst = 0;
    for (std::size_t j = 0; j < est::sx::kParams; ++j) {
      const est::ParameterEstimate& a = r->parameters[j];
      if (!(a.sigma < 0.5 * a.prior_sigma)) continue;
      CAPTURE(a.name);
      const double d = std::abs(a.value - fast->parameters[j].value) / a.sigma;
      worst = std::max(worst, d);
      CHECK(d < 0.05);
    }
    for (std::size_t i = 0; i < 2; ++i) {
      const double d = std::abs(r->df_obs[i].value - fast->df_obs[i].value) / r->df_obs[i].sigma;
      worst = std::max(worst, d);
      CHECK(d < 0.05);
    }
    MESSAGE("100 Hz against 400 Hz: at most " << worst << " sigma");
    CHECK(worst > 0);  // the rate is the nominal's: the two differ at all
    // and a rate under the output's is refused, not rounded
    est::EstimationInput slow = run.in;
    slow.second_pass.nominal_imu_rate_hz = 50;
    slow.second_pass.mode = est::SecondPassSettings::Mode::Always;
    std::array<double, est::sx::kParams> zero{};
    CHECK_FALSE(est::strapdown_nominal(slow, zero).ok());
  }

  TEST_CASE("it does not run where the linear model suffices: the result is the first pass's") {
    // Given the same plan and seed at a tenth of the prior (velocities of
    // 10 m/s, azimuth jumps of tenths of a degree), where the Monte Carlo
    // finds the linear model calibrated: the criterion predicts under the
    // threshold, the second pass does not run, and the estimates are the
    // first pass's, bit for bit.
    Simulated run = recommended_run(0.1, 2000);
    const auto r = est::estimate(run.in);
    est::EstimationInput off = run.in;
    off.second_pass.mode = est::SecondPassSettings::Mode::Off;
    const auto linear = est::estimate(off);
    REQUIRE(r.ok());
    REQUIRE(linear.ok());
    MESSAGE("a tenth of the prior: " << r->second_pass.reason);
    CHECK(r->second_pass.predicted_sigma < run.in.second_pass.threshold_sigma);
    CHECK(r->second_pass.predicted_sigma > 0);
    CHECK_FALSE(r->second_pass.ran);
    CHECK(r->second_pass.iterations == 0);
    CHECK(r->x == linear->x);
    CHECK(r->p == linear->p);
    // asked for anyway, it converges next to the first pass: within a
    // tenth of a sigma in every determined parameter and in df_obs
    est::EstimationInput always = run.in;
    always.second_pass.mode = est::SecondPassSettings::Mode::Always;
    const auto forced = est::estimate(always);
    REQUIRE(forced.ok());
    CHECK(forced->second_pass.ran);
    CHECK(forced->second_pass.converged);
    for (std::size_t j = 0; j < est::sx::kParams; ++j) {
      const est::ParameterEstimate& a = forced->parameters[j];
      if (!(a.sigma < 0.5 * a.prior_sigma)) continue;
      CAPTURE(a.name);
      CHECK(std::abs(a.value - linear->parameters[j].value) < 0.1 * a.sigma);
    }
    for (std::size_t i = 0; i < 2; ++i)
      CHECK(std::abs(forced->df_obs[i].value - linear->df_obs[i].value) <
            0.1 * forced->df_obs[i].sigma);
  }

  TEST_CASE("how df_obs splits, which no vertical turn determines, widens its sigma") {
    // At three times the tactical prior, where the azimuth error reaches
    // degrees: moving the split by its sigma moves the estimates (the
    // nominal turns df_z apart from g Theta_13), which the covariance then
    // holds; the estimates themselves are those of the same iterations.
    Simulated run = recommended_run(3.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
    run.in.with_two_stage = true;
    // the first-order term alone: the product, which would dominate what
    // this measures, has a case of its own below
    run.in.second_pass.consider_split_mixed = false;
    const auto with = est::estimate(run.in);
    est::EstimationInput without_in = run.in;
    without_in.second_pass.consider_split = false;
    const auto without = est::estimate(without_in);
    REQUIRE(with.ok());
    REQUIRE(without.ok());
    MESSAGE(with->second_pass.reason);
    CHECK(with->second_pass.reason.find("(df_obs_1, df_obs_2: 2 of 2 axes)") != std::string::npos);
    CHECK(without->second_pass.reason.find("axes") == std::string::npos);
    CHECK(with->x == without->x);
    // the two-stage baseline compares the filters on the linear covariance:
    // the consider term is not in it
    REQUIRE(with->has_two_stage);
    REQUIRE(without->has_two_stage);
    CHECK(with->two_stage.ratio == without->two_stage.ratio);
    double widest = 0;
    for (std::size_t i = 0; i < 2; ++i) {
      const double ratio = with->df_obs[i].sigma / without->df_obs[i].sigma;
      MESSAGE("df_obs_" << i + 1 << " sigma widened by " << ratio);
      CHECK(ratio < 1.5);  // a term of a fraction of a sigma, not a new error
      widest = std::max(widest, ratio);
    }
    // at this seed df_obs_1 by 7%: wider by more than rounding, as the
    // Monte Carlo says it should be
    CHECK(widest > 1.03);
    // the parameters the run determines well and the split does not
    // reach (the horizontal gyro biases) keep their sigma within 1%
    for (std::size_t j = 0; j < 2; ++j)
      CHECK(with->parameters[j].sigma < 1.01 * without->parameters[j].sigma);
  }

  TEST_CASE(
      "the split times the azimuth error from nu0_3 and Theta_33: considered at three times the "
      "prior, left out at a tenth of it, where it is predicted small") {
    // The nominal turns df_z by its azimuth error, and that error is
    // uncertain by nu0_3's sigma over the run: a product, with no first
    // derivative in either factor about the estimate. Its mixed one, from
    // two more passes, is added where predicted over half a sigma of df_obs.
    // Ten revolutions determine Theta_33, yet its sigma times 3600 deg is
    // an azimuth error too.
    const auto pair = [](double scale) {
      Simulated run = recommended_run(scale, 2000);
      run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
      est::EstimationInput without = run.in;
      without.second_pass.consider_split_mixed = false;
      auto a = est::estimate(run.in);
      auto b = est::estimate(without);
      REQUIRE(a.ok());
      REQUIRE(b.ok());
      MESSAGE("prior x " << scale << ": " << a->second_pass.reason);
      return std::pair{std::move(*a), std::move(*b)};
    };
    {
      const auto [with, without] = pair(3.0);
      for (const char* axis : {"df_obs_1 x nu0_3 (predicted", "df_obs_2 x nu0_3 (predicted",
                               "df_obs_1 x theta_33 (predicted"})
        CHECK(with.second_pass.reason.find(axis) != std::string::npos);
      CHECK(without.second_pass.reason.find(" x nu0_3") == std::string::npos);
      CHECK(with.x == without.x);  // the covariance only
      double widest = 0;
      for (std::size_t i = 0; i < 2; ++i) {
        const double ratio = with.df_obs[i].sigma / without.df_obs[i].sigma;
        MESSAGE("df_obs_" << i + 1 << " sigma widened by " << ratio << " by the product");
        CHECK(ratio >= 1);
        CHECK(ratio < 1.5);
        widest = std::max(widest, ratio);
      }
      // df_obs_1 by 24% at this seed: more than rounding by far
      CHECK(widest > 1.15);
      for (std::size_t j = 0; j < 2; ++j)  // the horizontal gyro biases: within 1%
        CHECK(with.parameters[j].sigma < 1.01 * without.parameters[j].sigma);
    }
    {
      const auto [with, without] = pair(0.1);
      CHECK(with.second_pass.ran);
      CHECK(with.second_pass.reason.find("azimuth error") == std::string::npos);
      CHECK(with.p == without.p);
    }
  }

  TEST_CASE(
      "the product's term is its mixed derivative: the same at half the partners' step and at the "
      "step reversed") {
    // The term found at a step s of the partners is (the split's central
    // sensitivity there - at the estimate) / s: of a product alone, the
    // same at any s and either sign. Mixing in the first-order term (a
    // sign slip: + for -) or not dividing by the step makes it depend on
    // s: tried, they moved these ratios by 70 to 150% and by 74%.
    Simulated run = recommended_run(3.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
    est::EstimationInput off = run.in;
    off.second_pass.consider_split_mixed = false;
    const auto base = est::estimate(off);
    REQUIRE(base.ok());
    const auto added = [&](double step) {
      est::EstimationInput in = run.in;
      in.second_pass.mixed_step_sigmas = step;
      const auto r = est::estimate(in);
      REQUIRE(r.ok());
      REQUIRE(r->x == base->x);
      std::array<double, 2> v{};
      for (std::size_t i = 0; i < 2; ++i) v[i] = var_obs(*r, i) - var_obs(*base, i);
      MESSAGE("step " << step << " sigma: the product adds " << v[0] << " and " << v[1]
                      << " m^2/s^4 to df_obs's variance; " << r->second_pass.reason);
      return v;
    };
    const std::array<double, 2> one = added(1), reversed = added(-1), half = added(0.5);
    {  // the passes on one thread and on three: the same covariance, bit for bit
      est::EstimationInput in = run.in;
      in.second_pass.threads = 1;
      const auto serial = est::estimate(in);
      in.second_pass.threads = 3;
      const auto parallel = est::estimate(in);
      REQUIRE(serial.ok());
      REQUIRE(parallel.ok());
      CHECK(serial->p == parallel->p);
      CHECK(var_obs(*serial, 0) - var_obs(*base, 0) == one[0]);
    }
    {  // a step too small to rise above the passes' own noise: refused, and said
      est::EstimationInput in = run.in;
      in.second_pass.mixed_step_sigmas = 0.01;
      const auto r = est::estimate(in);
      REQUIRE(r.ok());
      CHECK(r->second_pass.reason.find("not considered: a partner step of 0.010 sigma") !=
            std::string::npos);
      CHECK(r->p == base->p);
    }
    for (std::size_t i = 0; i < 2; ++i) {
      CAPTURE(i);
      REQUIRE(one[i] > 0);
      // what is left is of the third order, the curvature in the partners
      // (5 to 7% at this seed): within 20%, far inside what a wrong term
      // shows
      CHECK(std::abs(reversed[i] / one[i] - 1) < 0.2);
      CHECK(std::abs(half[i] / one[i] - 1) < 0.2);
    }
  }

  TEST_CASE("a product's pass that fails leaves that product out and keeps the rest, and says so") {
    // The nominal fails at the first pass of the product df_obs_2 x nu0_3:
    // after the iterations, the two passes of each axis's first-order term
    // and the four of df_obs_1's products, the fifth call after the last
    // of a run without the product. Every term is a covariance added, so
    // the result lies between the run without the product and the run
    // with all of it, in every direction.
    Simulated run = recommended_run(3.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
    run.in.second_pass.nominal = &failing_nominal;
    run.in.second_pass.threads = 1;  // its calls counted in the order they are planned
    const auto counted = [&](const est::EstimationInput& in, int fail_at) {
      g_nominal_calls = 0;
      g_fail_at = fail_at;
      auto r = est::estimate(in);
      REQUIRE(r.ok());
      return std::pair{std::move(*r), g_nominal_calls};
    };
    est::EstimationInput off = run.in;
    off.second_pass.consider_split_mixed = false;
    const auto without = counted(off, 0);
    const auto all = counted(run.in, 0);
    const auto failed = counted(run.in, without.second + 5);
    MESSAGE(failed.first.second_pass.reason);
    CHECK(failed.first.second_pass.reason.find(
              "df_obs_2 x nu0_3 not considered: an injected failure") != std::string::npos);
    CHECK(failed.first.second_pass.reason.find("(df_obs_1, df_obs_2: 2 of 2 axes)") !=
          std::string::npos);
    CHECK(all.first.second_pass.reason.find("df_obs_2 x nu0_3 (predicted") != std::string::npos);
    CHECK(failed.first.x == all.first.x);
    for (std::size_t i = 0; i < 2; ++i) {
      CAPTURE(i);
      CHECK(var_obs(failed.first, i) >= var_obs(without.first, i) * (1 - 1e-12));
      CHECK(var_obs(failed.first, i) <= var_obs(all.first, i) * (1 + 1e-12));
    }
    // The azimuth error turns df_z_2 into the first axis: df_obs_2's split
    // times nu0_3 is most of what the product adds to df_obs_1's variance
    // (97% at this seed), lost with that pair
    CHECK(var_obs(failed.first, 0) - var_obs(without.first, 0) <
          0.5 * (var_obs(all.first, 0) - var_obs(without.first, 0)));
  }

  TEST_CASE(
      "the split's sensitivity is taken about the estimate: a pass stopped early adds what a "
      "converged one does") {
    // One step of the iteration about either side of the estimate (a
    // central difference). A pass stopped after one iteration is no fixed
    // point: a step about it moves the estimates by the change the
    // iteration had left, which a difference from the estimate itself (one
    // side) would add to the covariance as if it were the split's.
    Simulated run = recommended_run(3.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
    run.in.second_pass.consider_split_mixed = false;  // the first-order term alone
    struct Widened {
      std::array<double, 2> by{};  // the consider term's share of df_obs_i's sigma (m/s^2)
      double last_change_sigma = 0;
      bool converged = false;
    };
    const auto widened = [&](int iterations) {
      est::EstimationInput with = run.in;
      with.second_pass.max_iterations = iterations;
      est::EstimationInput without = with;
      without.second_pass.consider_split = false;
      const auto a = est::estimate(with);
      const auto b = est::estimate(without);
      REQUIRE(a.ok());
      REQUIRE(b.ok());
      REQUIRE(a->x == b->x);
      Widened w;
      for (std::size_t i = 0; i < 2; ++i) {
        const double sa = a->df_obs[i].sigma;
        const double sb = b->df_obs[i].sigma;
        REQUIRE(sa >= sb);
        w.by[i] = std::sqrt(sa * sa - sb * sb);
      }
      w.last_change_sigma = a->second_pass.last_change_sigma;
      w.converged = a->second_pass.converged;
      MESSAGE(iterations << " iteration(s), the last change " << a->second_pass.last_change_sigma
                         << " sigma: " << a->second_pass.reason);
      return w;
    };
    const Widened stopped = widened(1);
    const Widened converged = widened(8);
    // the first iteration moves the estimates by some 4 sigma, the
    // second by nearly one: the step a one-sided difference would count
    REQUIRE_FALSE(stopped.converged);
    REQUIRE(stopped.last_change_sigma > 2);
    REQUIRE(converged.converged);
    // About points 4 sigma apart the sensitivity differs (by some 40% at
    // this seed); a one-sided difference, with the second iteration's step
    // in it, gave 2.3 and 4.3 times the converged pass's term here (tried):
    // within a factor of 1.7 either way tells the two apart.
    for (std::size_t i = 0; i < 2; ++i) {
      CAPTURE(i);
      MESSAGE("df_obs_" << i + 1 << ": the split adds " << stopped.by[i] << " m/s^2 after one "
                        << "iteration, " << converged.by[i] << " m/s^2 converged");
      REQUIRE(converged.by[i] > 0);
      CHECK(stopped.by[i] < 1.7 * converged.by[i]);
      CHECK(stopped.by[i] > converged.by[i] / 1.7);
    }
  }

  TEST_CASE("a Theta_i3 the prior fixes fixes the split: that axis is not considered") {
    Simulated run = recommended_run(3.0, 2000);
    run.in.second_pass.mode = est::SecondPassSettings::Mode::Always;
    run.in.priors.params[static_cast<std::size_t>(est::sx::theta(1, 3) - est::sx::kNu0)] = 0;
    const auto r = est::estimate(run.in);
    REQUIRE(r.ok());
    MESSAGE(r->second_pass.reason);
    CHECK(r->second_pass.reason.find("(df_obs_2: 1 of 2 axes)") != std::string::npos);
  }

  TEST_CASE("without a nominal, or turned off, it says so and the first pass stands") {
    Simulated run = recommended_run(1.0, 2001);
    run.in.second_pass.nominal = nullptr;
    const auto r = est::estimate(run.in);
    REQUIRE(r.ok());
    CHECK_FALSE(r->second_pass.ran);
    CHECK(r->second_pass.reason.find("no nonlinear nominal") != std::string::npos);
  }
}

TEST_SUITE("second pass: the model against its nominal") {
  TEST_CASE("the model about zero is the nonlinear nominal's derivative there, every parameter") {
    // The nominal (the strapdown the second pass simulates) moved by a
    // small step of one parameter, central difference, against the model's
    // own transitions from the initial map: on the recommended plan (four
    // reversals, ten revolutions) they agree to 1e-4 of the largest
    // response over the hour (measured: 1e-5 for the gyro and
    // accelerometer terms and r2, 1e-3 for r1, whose jump the model takes
    // from the encoder's samples: 2e-3 for it). A term of F or of a turn's
    // jump left out or of the wrong sign misses by its whole effect.
    // About the nominal at the truth of three times the prior the model
    // misses by more (Theta_33 13%, nu0_3 4%; at the prior 6% and 2%;
    // seed 2000): the linearisation there does not yet hold all of the
    // nominal's own navigation errors.
    Simulated run = recommended_run(1.0, 2000);
    const est::EarthAt e = est::EarthAt::at(run.in.timeline.site);
    const std::array<double, est::sx::kParams> zero{};
    int checked = 0;
    for (int j = 0; j < est::sx::kParams; ++j) {
      const auto u = static_cast<std::size_t>(j);
      CAPTURE(est::kParamNames[u]);
      const double delta = 0.02 * run.in.priors.params[u];
      if (!(delta > 0)) continue;
      auto moved = [&](double s) {
        auto q = zero;
        q[u] = s * delta;
        auto v = est::strapdown_nominal(run.in, q);
        REQUIRE(v.ok());
        return std::move(*v);
      };
      const auto up = moved(1), down = moved(-1);
      REQUIRE(up.size() == down.size());
      est::XiVec xi = est::XiVec::Zero();
      xi(est::sxi::kParams + j) = 1;
      est::StateVec x = est::initial_map(e, run.in.timeline.psi_start_rad) * xi;
      std::size_t k = 0;
      double worst = 0, size = 0;
      int steps = 0, aligned = 0;
      auto rep = est::for_each_step(run.in.timeline, [&](const est::TimelineStep& st) {
        x = st.d->phi * x;
        while (k + 1 < up.size() && up[k + 1].t_s <= st.t_to) ++k;
        aligned += up[k].t_s == st.t_to;  // the nominal's sample at the step, not one before
        const Eigen::Vector2d fd((up[k].ve - down[k].ve) / (2 * delta),
                                 (up[k].vn - down[k].vn) / (2 * delta));
        size = std::max(size, fd.norm());
        worst = std::max(worst, (x.segment<2>(est::sx::kDv) - fd).norm());
        ++steps;
      });
      REQUIRE(rep.ok());
      REQUIRE(steps > 3000);  // an hour of epochs, but in the turns
      CHECK(aligned == steps);
      MESSAGE(est::kParamNames[u] << ": the model misses the nominal's derivative by "
                                  << worst / size << " of its largest, " << size);
      CHECK(size > 0);
      // r1's jump is the table's angular acceleration, which the model
      // takes from the encoder's samples: 1e-3
      CHECK(worst <= (j == est::sx::kR - est::sx::kNu0 ? 2e-3 : 1e-4) * size);  // NaN fails
      ++checked;
    }
    CHECK(checked == est::sx::kParams);
  }
}
