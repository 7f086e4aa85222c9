// model.md 9.2: Monte Carlo over the nonlinear simulation, 50 runs per
// reference scenario with fixed seeds (scripts/montecarlo runs more).
#include <doctest/doctest.h>

#include <cmath>
#include <map>
#include <string>

#include "monte_carlo.hpp"

using namespace scenario;

namespace {

/// What a run determines must be unbiased as well as calibrated: for each
/// determined parameter (posterior below half the prior: a sigma that is
/// its prior would pass any z test) and for the sharp combinations df_obs,
/// |mean z| <= 3 / sqrt(N) (3 standard errors of the mean of N(0,1) over
/// N runs: 0.42 for 50) besides the RMS band.
void check_determined(const std::string& name, const MonteCarlo& mc) {
  const double bound = 3 / std::sqrt(static_cast<double>(mc.runs));
  for (std::size_t j = 0; j < mc.mean_z.size(); ++j) {
    if (!(mc.ratio[j] < 0.5)) continue;
    CAPTURE(est::kParamNames[j]);
    CHECK(std::abs(mc.mean_z[j]) <= bound);
  }
  for (std::size_t i = 0; i < 2; ++i) {
    CAPTURE(i);
    MESSAGE(name << " df_obs_" << i + 1 << ": rms z " << mc.rms_z_df_obs[i] << ", mean z "
                 << mc.mean_z_df_obs[i]);
    CHECK(mc.rms_z_df_obs[i] >= 0.8);
    CHECK(mc.rms_z_df_obs[i] <= 1.2);
    CHECK(std::abs(mc.mean_z_df_obs[i]) <= bound);
  }
}

/// The Monte Carlo of the recommended tactical plan with its priors scaled
/// by `scale`, seeds 2000..2049, run once per scale for the tests below.
const MonteCarlo& recommended(double scale) {
  static std::map<double, MonteCarlo> done;
  auto it = done.find(scale);
  if (it == done.end()) {
    Scenario s = from_plan("tactical-recommended.toml");
    for (double& p : s.priors.params) p *= scale;
    it = done.emplace(scale, monte_carlo(s, 50, 2000)).first;
  }
  return it->second;
}

}  // namespace

TEST_SUITE("monte carlo") {
  TEST_CASE("the recommended tactical plan at its full prior: Theta_33, r, the gyro biases") {
    // four reversals and 10 revolutions (config/profiles/
    // tactical-recommended.toml), 50 runs, seeds 2000..2049: Theta_33,
    // which only the revolutions determine, r1, r2 and the horizontal gyro
    // biases, each determined, in the RMS band and unbiased
    const MonteCarlo& mc = recommended(1.0);
    REQUIRE(mc.errors.empty());
    CHECK(mc.degraded == 0);
    const double bound = 3 / std::sqrt(static_cast<double>(mc.runs));
    for (const int p :
         {est::sx::theta(3, 3), est::sx::kR, est::sx::kR + 1, est::sx::kNu0, est::sx::kNu0 + 1}) {
      const auto j = static_cast<std::size_t>(p - est::sx::kNu0);
      CAPTURE(est::kParamNames[j]);
      MESSAGE("recommended " << est::kParamNames[j] << ": rms z " << mc.rms_z[j] << ", mean z "
                             << mc.mean_z[j] << ", sigma/prior " << mc.ratio[j]);
      CHECK(mc.ratio[j] < 0.5);  // determined: the z test means something
      CHECK(mc.rms_z[j] >= 0.8);
      CHECK(mc.rms_z[j] <= 1.2);
      CHECK(std::abs(mc.mean_z[j]) <= bound);
    }
  }

  TEST_CASE(
      "the recommended plan's df_obs at the full tactical prior: the second pass calibrates") {
    // At the full tactical prior the velocities reach 100 m/s and the
    // linear model's misses (up to 3%) enter df_obs, whose sigma after four
    // reversals is small (14 ug): on these seeds the linear model alone
    // gives RMS z 1.49 and 1.57. The nonlinear second pass (model.md, 8)
    // runs on each of these runs by its criterion and brings df_obs to RMS
    // z within 3 standard errors of 1 (1 +- 3/sqrt(2N): [0.70, 1.30] for
    // N = 50; 1.00 and 1.04 here) and mean z within 3/sqrt(N) = 0.42 of 0.
    // With the model about the nominal's own navigation state, the
    // nominal's derivative there, it reaches its 0.01 sigma in all 50 runs
    // (measured: in 3 iterations at most; the model that turned only the
    // parameters' terms by the nominal's azimuth converged in 40 within 5).
    const MonteCarlo& mc = recommended(1.0);
    REQUIRE(mc.errors.empty());
    CHECK(mc.second_pass_ran == mc.runs);
    MESSAGE("second pass converged in " << mc.second_pass_converged << " of " << mc.runs
                                        << " runs, at most " << mc.second_pass_max_iterations
                                        << " iterations");
    CHECK(mc.second_pass_converged == mc.runs);
    const double n = static_cast<double>(mc.runs);
    for (std::size_t i = 0; i < 2; ++i) {
      MESSAGE("recommended, full prior, second pass: df_obs_"
              << i + 1 << " rms z " << mc.rms_z_df_obs[i] << ", mean z " << mc.mean_z_df_obs[i]);
      CHECK(std::abs(mc.rms_z_df_obs[i] - 1) <= 3 / std::sqrt(2 * n));
      CHECK(std::abs(mc.mean_z_df_obs[i]) <= 3 / std::sqrt(n));
    }
  }

  TEST_CASE("the recommended plan at a tenth of the tactical prior: df_obs calibrated") {
    // the errors drawn from, and the filter's prior, a tenth of the tactical
    // one: the linear regime, where the sharp combinations must be right
    const MonteCarlo& mc = recommended(0.1);
    REQUIRE(mc.errors.empty());
    check_determined("recommended, prior x 0.1", mc);
  }

  TEST_CASE("RMS of (estimate - truth)/sigma in [0.8, 1.2] over 50 runs; innovations white") {
    // Given errors drawn from the prior, sensor noise on and a random start
    // orientation, 50 runs (seeds 1000..1049) per scenario: for each
    // parameter the RMS z must lie in [0.8, 1.2] (model.md 9.2; with 50
    // runs the RMS of a true N(0,1) spreads by about 1/sqrt(100) = 0.1, so
    // the band is 2 sigma of the sampling). The tactical scenario drives
    // the INS velocity to 60-120 m/s, where the linear model misses the
    // simulation by up to 3%; the test shows that the free navigation
    // states absorb it. Innovations: the pooled NIS mean lies in its 95%
    // interval, and at most 11 of 50 runs fail the Ljung-Box test (a run
    // fails if either axis does, each at 5%, so 9.75% of runs fail by
    // chance: binomial mean 4.9, sd 2.1, and 11 is 3 sd out).
    for (const auto& [name, s] : {std::pair{std::string("tactical"), tactical()},
                                  std::pair{std::string("navigation grade"), navigation_grade()}}) {
      const MonteCarlo mc = monte_carlo(s, 50, 1000);
      CAPTURE(name);
      REQUIRE(mc.errors.empty());
      CHECK(mc.degraded == 0);
      for (std::size_t j = 0; j < mc.rms_z.size(); ++j) {
        CAPTURE(est::kParamNames[j]);
        MESSAGE(name << " " << est::kParamNames[j] << ": rms z " << mc.rms_z[j] << ", mean z "
                     << mc.mean_z[j]);
        CHECK(mc.rms_z[j] >= 0.8);
        CHECK(mc.rms_z[j] <= 1.2);
      }
      for (const double v : mc.rms_z_df_eff) {
        CHECK(v >= 0.8);
        CHECK(v <= 1.2);
      }
      check_determined(name, mc);
      MESSAGE(name << ": NIS mean " << mc.nis_mean << " in [" << mc.nis_lo << ", " << mc.nis_hi
                   << "]; not white " << mc.not_white << " of 50");
      CHECK(mc.nis_mean >= mc.nis_lo);
      CHECK(mc.nis_mean <= mc.nis_hi);
      CHECK(mc.not_white <= 11);
    }
  }
}
