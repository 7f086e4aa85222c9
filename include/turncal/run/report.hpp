// The bias report of a run: JSON (what other tools read; SI, every estimate
// with its standard deviation and prior) and a plain-text summary of the
// same in display units (deg/h, ppm, ug, mm). Pure: the daemon and the
// replay write what this returns.
#pragma once

#include <array>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "turncal/config.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/result.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/sha256.hpp"

namespace turncal::run {

struct ReportContext {
  std::string run_id;
  double start_unix_s = 0;
  double end_unix_s = 0;
  std::string software_version;
  std::string config_file;
  std::string config_sha256;
  std::string log_file;
  std::string log_sha256;
  std::vector<Tolerance> tolerances;
  std::string mode;  ///< "command" or "observe"
  std::string unit;  ///< the INS under test; empty: not named
  /// What the CAN sockets did during the run, per interface (the daemon's
  /// frames sent, echoed, queued, dropped); null: not known (a replay).
  nlohmann::json can;
};

/// The report format this turncal writes. A report without the field is of
/// the first version, which the checks below read as well; one of a later
/// version than this is refused as unreadable, not misread.
inline constexpr int kReportSchemaVersion = 2;

/// Every field a reader of reports (report_text, history, the daemon's
/// index, the replay) takes, type-checked, and the settings a replay takes
/// (time base, plausibility bounds) within what a run can have had: empty
/// when the report is readable, else the first field that is not
/// ("estimates.nu0_1.sigma: expected a number"). A report file is read
/// only after this passes.
std::string check_report(const nlohmann::json& report);

/// The report of a finished run. `input` and `result` are null when the
/// run ended before estimation (aborted, failed): the report then says why
/// and keeps the health, timings and log.
nlohmann::json report_json(const ReportContext& ctx, const Engine& engine, const BuiltInput* input,
                           const est::EstimationResult* result);

/// One combination as the report and the plan give it: the lead parameter
/// and its unit, the non-zero coefficients by name, sigma and prior sigma,
/// and the value when `with_value` (a plan has none).
nlohmann::json combination_json(const est::Combination& c, bool with_value);

/// The plain-text summary of a report (from its JSON, so any report file
/// can be shown again).
/// With `truth` (a turncal-sim truth file: "errors" keyed by model.md's
/// names, SI), each estimate and combination also shows the injected value
/// and its error in sigmas.
std::string report_text(const nlohmann::json& report, const nlohmann::json* truth = nullptr);
/// A combination of the report in physical form: its formula when it is
/// one of the model's named combinations, else its lead and the terms that
/// matter, each with its display unit.
std::string combination_terms(const nlohmann::json& combination, const nlohmann::json& report);
/// The innovations' whiteness in words: the Ljung-Box statistics, their
/// p-values, and "NOT white" only under the alarm's p-value.
std::string whiteness_text(const nlohmann::json& innovations);
/// A report's log in words: its file, and what was cut off its end (the
/// part of a line a kill left) when anything was.
std::string log_text(const nlohmann::json& log);

/// Pass/fail of the estimates against the tolerances: {"pass": bool,
/// "checks": [...]}; every run passes when there are none.
nlohmann::json judge(const nlohmann::json& estimates, const std::vector<Tolerance>& tolerances);

/// How much of a parameter a run determined, by its posterior over its
/// prior standard deviation: "determined" (under 0.5), "partly" (0.5 to
/// 0.9) or "not determined" (over 0.9), and for the last two why, from
/// what a turn about the vertical can and cannot tell (model.md, 8).
struct Determination {
  std::string label;
  std::string why;  ///< empty when determined
};
Determination determination(std::string_view name, double sigma, double prior_sigma);

}  // namespace turncal::run
