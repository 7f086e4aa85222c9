// Monte Carlo of the single-loop estimator over the nonlinear simulation
// (model.md, 9.2): errors drawn from the prior, sensor noise on, start
// orientation uniform; per parameter the RMS of (estimate - truth)/sigma.
// Shared by the scenario test and turncal-montecarlo.
#pragma once

#include <algorithm>
#include <cstdlib>
#include <thread>
#include <vector>

#include "scenarios.hpp"
#include "turncal/estimation/nominal.hpp"

namespace scenario {

struct MonteCarlo {
  int runs = 0;
  std::array<double, est::sx::kParams> rms_z{};
  std::array<double, est::sx::kParams> mean_z{};
  std::array<double, 2> rms_z_df_eff{};
  /// df_obs_i = df0_i + g G_i3 - g Theta_i3: what a turn about the vertical
  /// determines of the accelerometer
  std::array<double, 2> rms_z_df_obs{};
  std::array<double, 2> mean_z_df_obs{};
  /// the RMS of estimate - truth and the mean reported sigma, SI: what the
  /// runs achieved beside what they said
  std::array<double, est::sx::kParams> rms_error{};
  std::array<double, est::sx::kParams> mean_sigma{};
  std::array<double, 2> rms_error_df_obs{};
  std::array<double, 2> mean_sigma_df_obs{};
  /// posterior / prior sigma of each parameter, the mean over the runs
  std::array<double, est::sx::kParams> ratio{};
  double nis_mean = 0;  ///< over every innovation of every run
  double nis_lo = 0, nis_hi = 0;
  int not_white = 0;     ///< runs failing the Ljung-Box test at 5% on either axis
  int inconsistent = 0;  ///< runs outside their own NIS interval
  std::size_t degraded = 0;
  std::vector<std::string> errors;
  /// the second pass: runs where it ran, of those the ones that converged,
  /// and the most iterations one took
  int second_pass_ran = 0;
  int second_pass_converged = 0;
  int second_pass_max_iterations = 0;
};

struct RunZ {
  std::array<double, est::sx::kParams> z{};
  std::array<double, est::sx::kParams> err{}, sig{};  ///< estimate - truth, sigma; SI
  std::array<double, 2> err_df_obs{}, sig_df_obs{};
  std::array<double, 2> z_df_eff{};
  std::array<double, 2> z_df_obs{};
  std::array<double, est::sx::kParams> ratio{};
  double nis_sum = 0;
  std::size_t nis_count = 0;
  bool white = true, consistent = true;
  std::size_t degraded = 0;
  std::string error;
  est::SecondPass second_pass;
};

/// One run of seed `seed`; the estimator's second pass as `mode` says (the
/// daemon's default: Auto, with the strapdown nominal).
inline RunZ one_run(const Scenario& s, std::uint64_t seed,
                    est::SecondPassSettings::Mode mode = est::SecondPassSettings::Mode::Auto) {
  std::mt19937_64 rng(seed);
  const est::XiVec xi = draw(s, rng);
  const double psi_s = std::uniform_real_distribution<double>(0, 2 * earth::kPi)(rng);
  const sim::Config cfg = sim_config(s, xi, psi_s, rng());
  const sim::Run run = sim::simulate(cfg);
  const TableTrajectory table(cfg.profile);
  est::EstimationInput in;
  in.timeline = timeline(s, psi_s, table, run.encoder);
  in.priors = s.priors;
  in.sigma_z = s.sigma_z;
  in.velocity.reserve(run.velocity.size());
  for (const auto& v : run.velocity) in.velocity.push_back({v.t_s, v.ve, v.vn});
  in.second_pass.mode = mode;
  in.second_pass.nominal = &est::strapdown_nominal;
  in.second_pass.threads = 1;  // the runs are the Monte Carlo's threads
  RunZ out;
  const auto r = est::estimate(in);
  if (!r) {
    out.error = r.error().describe();
    return out;
  }
  const double g = est::EarthAt::at(in.timeline.site).g;
  for (std::size_t j = 0; j < out.z.size(); ++j) {
    const double truth = xi(est::sxi::kParams + static_cast<int>(j));
    out.err[j] = r->parameters[j].value - truth;
    out.sig[j] = r->parameters[j].sigma;
    out.z[j] = out.err[j] / out.sig[j];
  }
  for (std::size_t i = 0; i < 2; ++i) {
    const int a = static_cast<int>(i);
    const double truth = xi(est::sxi::kParams + (est::sx::kDf0 - est::sx::kNu0) + a) +
                         g * xi(est::sxi::kParams + (est::sx::kG - est::sx::kNu0) + a);
    out.z_df_eff[i] = (r->df_eff[i].value - truth) / r->df_eff[i].sigma;
    const double obs =
        truth - g * xi(est::sxi::kParams + (est::sx::theta(a + 1, 3) - est::sx::kNu0));
    out.err_df_obs[i] = r->df_obs[i].value - obs;
    out.sig_df_obs[i] = r->df_obs[i].sigma;
    out.z_df_obs[i] = out.err_df_obs[i] / out.sig_df_obs[i];
  }
  for (std::size_t j = 0; j < out.ratio.size(); ++j)
    out.ratio[j] = r->parameters[j].sigma / r->parameters[j].prior_sigma;
  const est::InnovationStats& st = r->innovation_stats;
  out.nis_sum = st.nis_mean * static_cast<double>(st.count);
  out.nis_count = st.count;
  // the Ljung-Box test's calibration at 5% on each axis (a white sequence
  // fails 9.75% of runs), not the report's rare alarm
  out.white = st.ljung_box_p[0] >= 0.05 && st.ljung_box_p[1] >= 0.05;
  out.consistent = st.consistent();
  out.degraded = r->degraded_updates;
  out.second_pass = r->second_pass;
  return out;
}

/// The Monte Carlo's threads: TURNCAL_THREADS when set (to leave cores to
/// something run beside it), else one per hardware thread.
inline unsigned default_threads() {
  if (const char* e = std::getenv("TURNCAL_THREADS"); e != nullptr && std::atoi(e) > 0)
    return static_cast<unsigned>(std::atoi(e));
  return std::max(1u, std::thread::hardware_concurrency());
}

/// Runs seeds first_seed .. first_seed + runs - 1 on `threads` threads.
inline MonteCarlo monte_carlo(
    const Scenario& s, int runs, std::uint64_t first_seed, unsigned threads = default_threads(),
    est::SecondPassSettings::Mode mode = est::SecondPassSettings::Mode::Auto) {
  std::vector<RunZ> z(static_cast<std::size_t>(runs));
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      for (std::size_t k = t; k < z.size(); k += threads) z[k] = one_run(s, first_seed + k, mode);
    });
  for (auto& th : pool) th.join();
  MonteCarlo mc;
  mc.runs = runs;
  double nis = 0;
  std::size_t count = 0;
  for (const RunZ& r : z) {
    if (!r.error.empty()) {
      mc.errors.push_back(r.error);
      continue;
    }
    for (std::size_t j = 0; j < r.z.size(); ++j) {
      mc.rms_z[j] += r.z[j] * r.z[j];
      mc.mean_z[j] += r.z[j];
      mc.rms_error[j] += r.err[j] * r.err[j];
      mc.mean_sigma[j] += r.sig[j];
    }
    for (std::size_t i = 0; i < 2; ++i) {
      mc.rms_z_df_eff[i] += r.z_df_eff[i] * r.z_df_eff[i];
      mc.rms_z_df_obs[i] += r.z_df_obs[i] * r.z_df_obs[i];
      mc.mean_z_df_obs[i] += r.z_df_obs[i];
      mc.rms_error_df_obs[i] += r.err_df_obs[i] * r.err_df_obs[i];
      mc.mean_sigma_df_obs[i] += r.sig_df_obs[i];
    }
    for (std::size_t j = 0; j < r.ratio.size(); ++j) mc.ratio[j] += r.ratio[j];
    nis += r.nis_sum;
    count += r.nis_count;
    mc.not_white += r.white ? 0 : 1;
    mc.inconsistent += r.consistent ? 0 : 1;
    mc.degraded += r.degraded;
    mc.second_pass_ran += r.second_pass.ran ? 1 : 0;
    mc.second_pass_converged += r.second_pass.ran && r.second_pass.converged ? 1 : 0;
    mc.second_pass_max_iterations =
        std::max(mc.second_pass_max_iterations, r.second_pass.iterations);
  }
  const double n = static_cast<double>(z.size() - mc.errors.size());
  for (std::size_t j = 0; j < mc.rms_z.size(); ++j) {
    mc.rms_z[j] = std::sqrt(mc.rms_z[j] / n);
    mc.mean_z[j] /= n;
    mc.rms_error[j] = std::sqrt(mc.rms_error[j] / n);
    mc.mean_sigma[j] /= n;
  }
  for (double& v : mc.rms_error_df_obs) v = std::sqrt(v / n);
  for (double& v : mc.mean_sigma_df_obs) v /= n;
  for (double& v : mc.rms_z_df_eff) v = std::sqrt(v / n);
  for (double& v : mc.rms_z_df_obs) v = std::sqrt(v / n);
  for (double& v : mc.mean_z_df_obs) v /= n;
  for (double& v : mc.ratio) v /= n;
  const double c = static_cast<double>(count);
  mc.nis_mean = nis / c;
  // 95% interval of the mean of chi^2(2) over `count` epochs (Wilson-Hilferty)
  auto q = [&](double zq) {
    const double k = 2 * c, a = 2.0 / (9.0 * k), b = 1.0 - a + zq * std::sqrt(a);
    return k * b * b * b / c;
  };
  mc.nis_lo = q(-1.959963984540054);
  mc.nis_hi = q(1.959963984540054);
  return mc;
}

}  // namespace scenario
