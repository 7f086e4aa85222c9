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

/// What a stand's INS output is: the step of its velocity signal and its
/// rate.
struct InsOutput {
  double resolution_mps = 0;  ///< the velocity signal's step (DBC factor, in m/s); 0: none
  std::string signal;         ///< "Message.Signal" of the coarser component
  double rate_hz = 0;         ///< its velocity rate; 0: not known
};

/// Warnings when the INS output is too coarse for the plan (`analysed`,
/// plan_json's at the plan's own noise and 100 Hz): rounding to a step
/// adds step/sqrt(12) RMS to the output noise, and a slow rate measures
/// further from the turns. Each {what, text, costs: {name: {sigma, with}}}
/// gives the plan's sigmas again with the cost, for every parameter the
/// plan determines that loses more than 5%; a coarseness that costs none
/// that much is not warned of. Empty: nothing to say.
Result<nlohmann::json> ins_output_costs(const Plan& plan, const PlanningSettings& s,
                                        const InsOutput& ins, const nlohmann::json& analysed);

/// Several plans' analyses (plan_json each) side by side: the JSON, and
/// the table for people, a row per parameter and a column per plan.
nlohmann::json compare_json(const std::vector<nlohmann::json>& plans);
std::string compare_text(const nlohmann::json& compared);

}  // namespace turncal::run
