// turncal-montecarlo: the full Monte Carlo of model.md 9.2 for the
// reference scenarios, printed as a table (scripts/montecarlo runs it).
//   turncal-montecarlo [RUNS] [FIRST_SEED] [tactical|navigation|recommended|all] [PRIOR_SCALE]
//                      [auto|off|always] [THREADS]
// PRIOR_SCALE scales the prior sigmas of the 18 parameters (the errors
// drawn and the filter's prior alike): 0.1 shows what the linearisation
// costs at the full prior. The fifth argument is the nonlinear second
// pass (model.md, 8): auto (the daemon's default: where the first pass
// predicts a linearisation error), off (the linear model alone), always.
// THREADS defaults to the machine's cores.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "monte_carlo.hpp"

int main(int argc, char** argv) {
  using namespace scenario;
  const int runs = argc > 1 ? std::atoi(argv[1]) : 50;
  const std::uint64_t seed = argc > 2 ? std::strtoull(argv[2], nullptr, 10) : 1000;
  std::string which = argc > 3 ? argv[3] : "all";
  if (which == "both") which = "all";
  const double scale = argc > 4 ? std::atof(argv[4]) : 1.0;
  const std::string pass = argc > 5 ? argv[5] : "auto";
  const int threads = argc > 6 ? std::atoi(argv[6]) : 0;
  using Mode = est::SecondPassSettings::Mode;
  const Mode mode = pass == "off" ? Mode::Off : pass == "always" ? Mode::Always : Mode::Auto;
  if (runs < 2 || (pass != "auto" && pass != "off" && pass != "always") || threads < 0) {
    std::fprintf(stderr,
                 "usage: turncal-montecarlo [RUNS>=2] [FIRST_SEED] "
                 "[tactical|navigation|recommended|all] [PRIOR_SCALE] [auto|off|always] "
                 "[THREADS]\n");
    return 2;
  }
  int bad = 0;
  for (const auto& [name, given] :
       {std::pair{"tactical", tactical()}, std::pair{"navigation", navigation_grade()},
        std::pair{"recommended", from_plan("tactical-recommended.toml")}}) {
    if (which != "all" && which != name) continue;
    Scenario s = given;
    for (double& p : s.priors.params) p *= scale;
    const MonteCarlo mc = threads > 0
                              ? monte_carlo(s, runs, seed, static_cast<unsigned>(threads), mode)
                              : monte_carlo(s, runs, seed, default_threads(), mode);
    std::printf("%s (prior x %g, second pass %s): %d runs, seeds %llu..%llu\n", name, scale,
                pass.c_str(), runs, static_cast<unsigned long long>(seed),
                static_cast<unsigned long long>(seed + static_cast<std::uint64_t>(runs) - 1));
    // the bands of a determined quantity: 3 standard errors of the mean
    // and of the RMS of N(0,1) over N runs
    const double n = static_cast<double>(runs);
    const double mean_band = 3 / std::sqrt(n), rms_band = 3 / std::sqrt(2 * n);
    std::printf("  determined (sigma/prior < 0.5): |mean z| <= %.3f, rms z in [%.3f, %.3f]\n",
                mean_band, 1 - rms_band, 1 + rms_band);
    std::printf("  %-9s %8s %8s   (then: mean sigma and RMS error, SI)\n", "parameter", "rms z",
                "mean z");
    for (std::size_t j = 0; j < mc.rms_z.size(); ++j) {
      const bool ok = mc.rms_z[j] >= 0.8 && mc.rms_z[j] <= 1.2;
      bad += ok ? 0 : 1;
      const bool determined = mc.ratio[j] < 0.5;
      const bool in_band =
          std::abs(mc.mean_z[j]) <= mean_band && std::abs(mc.rms_z[j] - 1) <= rms_band;
      std::printf("  %-9s %8.3f %8.3f  sigma %.3e  error %.3e  sigma/prior %.3f%s%s\n",
                  std::string(est::kParamNames[j]).c_str(), mc.rms_z[j], mc.mean_z[j],
                  mc.mean_sigma[j], mc.rms_error[j], mc.ratio[j], ok ? "" : "  outside [0.8, 1.2]",
                  !determined ? ""
                  : in_band   ? "  determined, in band"
                              : "  determined, OUT of band");
    }
    std::printf("  %-9s %8.3f\n  %-9s %8.3f\n", "df_eff_1", mc.rms_z_df_eff[0], "df_eff_2",
                mc.rms_z_df_eff[1]);
    for (std::size_t i = 0; i < 2; ++i) {
      const bool in_band = std::abs(mc.mean_z_df_obs[i]) <= mean_band &&
                           std::abs(mc.rms_z_df_obs[i] - 1) <= rms_band;
      std::printf("  df_obs_%zu  %8.3f %8.3f  sigma %.3e  error %.3e  %s\n", i + 1,
                  mc.rms_z_df_obs[i], mc.mean_z_df_obs[i], mc.mean_sigma_df_obs[i],
                  mc.rms_error_df_obs[i], in_band ? "in band" : "OUT of band");
    }
    std::printf("  second pass: ran in %d of %d runs, converged in %d, at most %d iterations\n",
                mc.second_pass_ran, runs, mc.second_pass_converged, mc.second_pass_max_iterations);
    std::printf(
        "  NIS mean %.4f (95%% interval [%.4f, %.4f]); runs not white %d, inconsistent %d "
        "(by chance 9.75%% and 5%% of %d); degraded updates %zu; errors %zu\n",
        mc.nis_mean, mc.nis_lo, mc.nis_hi, mc.not_white, mc.inconsistent, runs, mc.degraded,
        mc.errors.size());
    for (const auto& e : mc.errors) std::printf("  error: %s\n", e.c_str());
  }
  return bad == 0 ? 0 : 1;
}
