// turncal-montecarlo: the full Monte Carlo of model.md 9.2 for the
// reference scenarios, printed as a table (scripts/montecarlo runs it).
//   turncal-montecarlo [RUNS] [FIRST_SEED] [tactical|navigation|recommended|all] [PRIOR_SCALE]
// PRIOR_SCALE scales the prior sigmas of the 18 parameters (the errors
// drawn and the filter's prior alike): 0.1 shows what the linearisation
// costs at the full prior.
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
  if (runs < 2) {
    std::fprintf(stderr,
                 "usage: turncal-montecarlo [RUNS>=2] [FIRST_SEED] "
                 "[tactical|navigation|recommended|all] [PRIOR_SCALE]\n");
    return 2;
  }
  int bad = 0;
  for (const auto& [name, given] :
       {std::pair{"tactical", tactical()}, std::pair{"navigation", navigation_grade()},
        std::pair{"recommended", from_plan("tactical-recommended.toml")}}) {
    if (which != "all" && which != name) continue;
    Scenario s = given;
    for (double& p : s.priors.params) p *= scale;
    const MonteCarlo mc = monte_carlo(s, runs, seed);
    std::printf("%s (prior x %g): %d runs, seeds %llu..%llu\n", name, scale, runs,
                static_cast<unsigned long long>(seed),
                static_cast<unsigned long long>(seed + static_cast<std::uint64_t>(runs) - 1));
    std::printf("  %-9s %8s %8s\n", "parameter", "rms z", "mean z");
    for (std::size_t j = 0; j < mc.rms_z.size(); ++j) {
      const bool ok = mc.rms_z[j] >= 0.8 && mc.rms_z[j] <= 1.2;
      bad += ok ? 0 : 1;
      std::printf("  %-9s %8.3f %8.3f  sigma/prior %.3f%s\n",
                  std::string(est::kParamNames[j]).c_str(), mc.rms_z[j], mc.mean_z[j], mc.ratio[j],
                  ok ? "" : "  outside [0.8, 1.2]");
    }
    std::printf("  %-9s %8.3f\n  %-9s %8.3f\n", "df_eff_1", mc.rms_z_df_eff[0], "df_eff_2",
                mc.rms_z_df_eff[1]);
    for (std::size_t i = 0; i < 2; ++i)
      std::printf("  df_obs_%zu  %8.3f %8.3f\n", i + 1, mc.rms_z_df_obs[i], mc.mean_z_df_obs[i]);
    std::printf(
        "  NIS mean %.4f (95%% interval [%.4f, %.4f]); runs not white %d, inconsistent %d "
        "(by chance 9.75%% and 5%% of %d); degraded updates %zu; errors %zu\n",
        mc.nis_mean, mc.nis_lo, mc.nis_hi, mc.not_white, mc.inconsistent, runs, mc.degraded,
        mc.errors.size());
    for (const auto& e : mc.errors) std::printf("  error: %s\n", e.c_str());
  }
  return bad == 0 ? 0 : 1;
}
