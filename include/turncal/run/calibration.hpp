// A calibration file from a run's report (turncalctl export): the terms the
// run determined as corrections to the INS's existing calibration, in its
// instrument axes, each with its standard deviation, and the covariance of
// that block. A term the run did not determine is absent, with the reason
// (left as the INS has it), never written as zero; a combination the run
// determines but cannot split is exported as what it is, for the mounting
// it holds for. Pure: JSON in, JSON or TOML text out.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "turncal/result.hpp"

namespace turncal::run {

/// The convention the file states once: how its terms correct the raw
/// outputs (derived from model.md's error model, section 2).
extern const char* const kCalibrationConvention;

/// The same in two sentences, for `turncalctl show` and the HTML report.
extern const char* const kHowToApply;

/// The calibration of a finished run's report (status "done", with
/// estimates and their covariance); an error says why there is none.
Result<nlohmann::json> calibration_json(const nlohmann::json& report);

/// The calibration as TOML: the same tables and keys as the JSON.
std::string calibration_toml(const nlohmann::json& calibration);

}  // namespace turncal::run
