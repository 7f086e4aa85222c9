// Planning: the covariance analysis of an experiment before the table
// moves. The plan's profile gives the table's motion (TableTrajectory), the
// encoder it would record and the turn windows, exactly as a run's record
// gives them to the estimator; the same filter then runs on the model alone
// (est::analyse). What the profile can estimate is what its posterior
// sigma brings below half the prior; a small sweep shows how the bias
// sigmas fall with hold length and turn angle.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/plan.hpp"
#include "turncal/result.hpp"

namespace turncal::run {

struct PlanningSettings {
  double heading_offset_rad = 0;  ///< the INS mounting on the table
  double sample_rate_hz = 100;    ///< INS velocity rate (matters for the mean measurement)
  double encoder_hz = 200;        ///< encoder rate in the turns
  bool sweep = true;              ///< add the hold length and turn angle table
  /// A parameter is called estimable when its posterior sigma is below this
  /// fraction of its prior.
  double estimable_ratio = 0.5;
};

/// The estimation input a run of `plan` would build, without velocity.
est::EstimationInput planned_input(const Plan& plan, const PlanningSettings& s);

/// `plan` with its holds scaled by `hold_factor` (turn lengths kept) and
/// every turn's angle set to `turn_angle_rad` (sign kept); NaN keeps it.
Plan scaled_plan(const Plan& plan, double hold_factor, double turn_angle_rad);

/// `plan` with its turns replaced by `n` turns of 180 deg, back and forth
/// (+180, -180, ...), evenly spread over the run, each as fast as its
/// first turn.
Plan reversals_plan(const Plan& plan, int n);

/// The covariance analysis as JSON: `predicted` keyed by model.md's names
/// (and df_eff_1, df_eff_2), each {sigma, prior_sigma, ratio, estimable,
/// unit} in SI; `combinations`; `sweep`.
Result<nlohmann::json> plan_json(const Plan& plan, const PlanningSettings& s);

/// The same in display units, for people.
std::string plan_text(const nlohmann::json& plan);

/// Several plans' analyses (plan_json each) side by side: the JSON, and
/// the table for people, a row per parameter and a column per plan.
nlohmann::json compare_json(const std::vector<nlohmann::json>& plans);
std::string compare_text(const nlohmann::json& compared);

}  // namespace turncal::run
