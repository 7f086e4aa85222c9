// The bias report of a run: JSON (what other tools read; SI, every estimate
// with its standard deviation and prior) and a plain-text summary of the
// same in display units (deg/h, ppm, ug, mm). Pure: the daemon and the
// replay write what this returns.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "turncal/config.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/run/engine.hpp"

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
};

/// The report of a finished run. `input` and `result` are null when the
/// run ended before estimation (aborted, failed): the report then says why
/// and keeps the health, timings and log.
nlohmann::json report_json(const ReportContext& ctx, const Engine& engine, const BuiltInput* input,
                           const est::EstimationResult* result);

/// The plain-text summary of a report (from its JSON, so any report file
/// can be shown again).
std::string report_text(const nlohmann::json& report);

/// Pass/fail of the estimates against the tolerances: {"pass": bool,
/// "checks": [...]}; every run passes when there are none.
nlohmann::json judge(const nlohmann::json& estimates, const std::vector<Tolerance>& tolerances);

/// SHA-256 of a byte string, lower-case hex (FIPS 180-4).
std::string sha256_hex(std::string_view data);

}  // namespace turncal::run
