// Benchmarks of the estimation core (not tests): the single-loop filter
// over a 2-hour run (the tactical reference plan, its +180 deg turn at 1 h) at 1 s and at 0.1 s
// epochs, and the covariance analysis of the same plan. The cost does not depend on the velocity
// values, so the record is noise at 100 Hz and the encoder the profile's own angle at 200 Hz.
// Then the one-hour recommended tactical plan (four reversals, ten revolutions) simulated at one
// prior sigma of every error, estimated with the nonlinear second pass (model.md, 8).
// Prints one figure per line; scripts/bench runs it.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

#include "turncal/build_paths.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/estimation/model.hpp"
#include "turncal/estimation/nominal.hpp"
#include "turncal/physics/profile.hpp"
#include "turncal/physics/strapdown.hpp"
#include "turncal/plan.hpp"

using namespace turncal;
using Clock = std::chrono::steady_clock;

namespace {

constexpr double kDuration = 7200;

/// The tactical reference plan stretched to 2 hours, the turn at 1 hour.
est::EstimationInput two_hour_run(const Plan& plan, double epoch_s) {
  Profile profile = plan.profile;
  profile.duration_s = kDuration;
  profile.turns.at(0).start_s = kDuration / 2;
  const TableTrajectory table(profile);
  est::EstimationInput in;
  in.timeline.site = plan.site;
  in.timeline.noise = plan.noise();
  in.timeline.epoch_s = epoch_s;
  in.timeline.duration_s = kDuration;
  in.timeline.turns.push_back({table.turn_start(0), table.turn_end(0)});
  for (long k = 0; k <= static_cast<long>(kDuration * 200); ++k) {
    const double t = static_cast<double>(k) / 200;
    in.timeline.encoder.push_back({t, table.at(t).angle});
  }
  in.priors = plan.priors;
  in.sigma_z = plan.sigma_z;
  std::mt19937_64 rng(1);
  std::normal_distribution<double> n(0, in.sigma_z);
  for (long k = 0; k <= static_cast<long>(kDuration * 100); ++k)
    in.velocity.push_back({static_cast<double>(k) / 100, n(rng), n(rng)});
  return in;
}

template <class F>
double best_of(int reps, F&& f) {
  double best = 1e300;
  for (int r = 0; r < reps; ++r) {
    const auto t0 = Clock::now();
    f();
    best = std::min(best, std::chrono::duration<double>(Clock::now() - t0).count());
  }
  return best;
}

}  // namespace

int main() {
  const auto plan =
      load_plan(std::string(turncal::build::source_dir) + "/config/profiles/tactical.toml");
  if (!plan) {
    std::fprintf(stderr, "%s\n", plan.error().describe().c_str());
    return 1;
  }
  double sink = 0;
  for (const double epoch : {1.0, 0.1}) {
    const est::EstimationInput in = two_hour_run(*plan, epoch);
    std::size_t epochs = 0;
    const double t_est = best_of(3, [&] {
      const auto r = est::estimate(in);
      if (!r) std::abort();
      epochs = r->epoch_t.size();
      sink += r->x(est::sx::kNu0);
    });
    std::printf("estimate_2h_epoch_%.1fs_s %.3f  (%zu epochs, %.2f us/epoch%s; best of 3)\n", epoch,
                t_est, epochs, 1e6 * t_est / static_cast<double>(epochs),
                epoch < 0.5 ? "; target < 0.5 s" : "");
    const double t_cov = best_of(3, [&] {
      const auto r = est::analyse(in);
      if (!r) std::abort();
      sink += r->p(est::sx::kNu0, est::sx::kNu0);
    });
    std::printf("covariance_analysis_2h_epoch_%.1fs_s %.3f  (best of 3)\n", epoch, t_cov);
  }
  // one hold epoch of the filter: predict over a precomputed transition,
  // update with a velocity sample
  {
    const est::EarthAt e = est::EarthAt::at(plan->site);
    const est::Discrete d = est::discretize_hold(e, 0.3, 1.0, plan->noise());
    const est::StateMat s0 = est::StateMat::Identity() * 1e-3;
    const est::MeasMat h = est::velocity_measurement();
    constexpr int kEpochs = 100000;
    const double t = best_of(3, [&] {
      est::SqrtFilter f(est::StateVec::Zero(), s0, s0.rowwise().norm());
      for (int k = 0; k < kEpochs; ++k) {
        f.predict(d.phi, d.sqrt_q);
        (void)f.update(est::Meas(1e-4, -1e-4), h, plan->sigma_z);
      }
      sink += f.state()(0);
    });
    std::printf("filter_hold_epoch_us %.2f  (predict and update; best of 3; target <= 5 us)\n",
                1e6 * t / kEpochs);
  }
  // the turn transition: the reference 180 deg turn (7 s) and 10
  // revolutions (3600 deg at 30 deg/s, 120 s), encoder at 200 Hz
  for (const double deg : {180.0, 3600.0}) {
    Profile p = plan->profile;
    p.turns.at(0).angle_rad = deg * earth::kDeg;
    const TableTrajectory table(p);
    std::vector<est::AngleSample> enc;
    for (double t = table.turn_start(0); t <= table.turn_end(0) + 1e-9; t += 0.005)
      enc.push_back({t, table.at(t).angle});
    const est::EarthAt e = est::EarthAt::at(plan->site);
    const double t = best_of(3, [&] {
      const est::Discrete d = est::turn_transition(e, enc, plan->noise());
      sink += d.phi(0, est::sx::kR);
    });
    std::printf("turn_transition_%.0fdeg_ms %.2f  (%zu encoder samples, %.2f us each; best of 3)\n",
                deg, 1e3 * t, enc.size(), 1e6 * t / static_cast<double>(enc.size()));
  }
  // the second pass: the recommended plan's hour at one prior sigma of
  // every error (signs mixed), noise on, the nominal and the iterations
  {
    const auto rec = load_plan(std::string(turncal::build::source_dir) +
                               "/config/profiles/tactical-recommended.toml");
    if (!rec) {
      std::fprintf(stderr, "%s\n", rec.error().describe().c_str());
      return 1;
    }
    sim::Config cfg;
    cfg.latitude_rad = rec->site.latitude_rad;
    cfg.height_m = rec->site.height_m;
    cfg.psi_start_rad = 0.7;
    cfg.profile = rec->profile;
    const auto& pr = rec->priors.params;
    const auto at = [&](int state, int sign) {
      return sign * pr[static_cast<std::size_t>(state - est::sx::kNu0)];
    };
    cfg.errors.nu0 =
        Eigen::Vector3d(at(est::sx::kNu0, 1), at(est::sx::kNu0 + 1, -1), at(est::sx::kNu0 + 2, 1));
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        cfg.errors.theta(i, j) = at(est::sx::theta(i + 1, j + 1), (i + j) % 2 == 0 ? 1 : -1);
    cfg.errors.df0 = Eigen::Vector2d(at(est::sx::kDf0, 1), at(est::sx::kDf0 + 1, -1));
    cfg.errors.g = Eigen::Vector2d(at(est::sx::kG, -1), at(est::sx::kG + 1, 1));
    cfg.errors.r = Eigen::Vector2d(at(est::sx::kR, 1), at(est::sx::kR + 1, -1));
    cfg.noise.arw = rec->arw;
    cfg.noise.vrw = rec->vrw;
    cfg.noise.velocity_sigma = rec->sigma_z;
    const sim::Run run = sim::simulate(cfg);
    const TableTrajectory table(cfg.profile);
    est::EstimationInput in;
    in.timeline.site = rec->site;
    in.timeline.noise = rec->noise();
    in.timeline.epoch_s = rec->epoch_s;
    in.timeline.duration_s = rec->profile.duration_s;
    in.timeline.psi_start_rad = cfg.psi_start_rad;
    for (std::size_t i = 0; i < table.turns(); ++i)
      in.timeline.turns.push_back({table.turn_start(i), table.turn_end(i)});
    for (const auto& e : run.encoder)
      in.timeline.encoder.push_back({e.t_s, cfg.psi_start_rad + e.angle_rad});
    in.priors = rec->priors;
    in.priors.align_s = rec->profile.align_s;
    in.sigma_z = rec->sigma_z;
    for (const auto& v : run.velocity) in.velocity.push_back({v.t_s, v.ve, v.vn});
    in.second_pass.nominal = &est::strapdown_nominal;
    est::SecondPass pass;
    const double t_pass = best_of(3, [&] {
      const auto r = est::estimate(in);
      if (!r) std::abort();
      pass = r->second_pass;
      sink += r->x(est::sx::kNu0);
    });
    in.second_pass.mode = est::SecondPassSettings::Mode::Off;
    const double t_linear = best_of(3, [&] {
      const auto r = est::estimate(in);
      if (!r) std::abort();
      sink += r->x(est::sx::kNu0);
    });
    const std::array<double, est::sx::kParams> p{};
    const double t_nominal = best_of(3, [&] {
      const auto h = est::strapdown_nominal(in, p);
      if (!h) std::abort();
      sink += h->velocity.back().ve;
    });
    std::printf(
        "second_pass_recommended_1h_s %.3f  (%s, %d iterations, %s; the first pass alone %.3f s, "
        "one nominal %.3f s; best of 3; target < 2 s)\n",
        t_pass, pass.ran ? "ran" : "did not run", pass.iterations,
        pass.converged ? "converged" : "not converged", t_linear, t_nominal);
  }
  std::printf("(checksum %.3e)\n", sink);
  return 0;
}
