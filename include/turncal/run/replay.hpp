// Replay: a recorded run re-estimated from its log, in-process, through the
// same engine (observe mode: the sequencer follows the recorded stand) and
// the same estimator the daemon runs. Given the live run's report, the
// replay takes its settings (profile text and overrides, heading offset,
// time base, two-stage), so its estimates equal the live ones bit for bit;
// what-if studies set plan keys over them. A log of any stand the
// configuration describes (`candump -l`) replays too.
//
// A damaged log (a line that does not parse, a truncated last line, time
// going backwards) is read up to the damage; the estimates are those of
// the record up to there, and the report says where the damage is.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "turncal/config.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/result.hpp"

namespace turncal::run {

struct ReplayOptions {
  /// The profile to replay with; empty: the live report's (its text), else
  /// the configuration's default profile.
  std::string profile;
  std::vector<std::string> overrides;  ///< plan keys, "section.key=VALUE"
  std::optional<bool> two_stage;       ///< else the live run's (else on)
  /// The nonlinear second pass (est::SecondPassSettings); else Auto.
  std::optional<est::SecondPassSettings::Mode> second_pass;
  std::optional<double> heading_offset_rad;  ///< else the live run's, else the config's
  bool html = false;                         ///< also make the HTML report
};

/// Where a log stops being readable.
struct LogDamage {
  std::uint64_t line = 0;
  std::string what;
};

struct ReplayOutcome {
  nlohmann::json report;             ///< the report, as the daemon writes it
  std::optional<LogDamage> damage;   ///< the log was read up to here
  std::vector<std::string> missing;  ///< roles whose frames the log never carried
  std::uint64_t lines = 0;           ///< lines read
  std::string html;                  ///< the HTML report, when asked for
};

/// The software version in every report.
const char* software_version();

/// Replays `log_path`. `live` is the live run's report (nullptr for a
/// foreign log). An error only when nothing can be replayed (no file, no
/// profile); a damaged log or a run that cannot be estimated still gives a
/// report that says why.
Result<ReplayOutcome> replay_log(const Config& cfg, const can::Database& db, const RoleMap& roles,
                                 const std::string& log_path, const nlohmann::json* live,
                                 const ReplayOptions& options);

}  // namespace turncal::run
