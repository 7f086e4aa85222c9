// A run's report, written off the event loop: the log's last fsync and
// close, its digest, the text and HTML, and the three files with their
// fsyncs can each wait for a disk, and the loop that sends the heartbeat
// and a quick stop must never wait for one. The loop builds what needs
// the run (the report's JSON, from the engine) and hands it over in a
// ReportJob; write_report_job does the rest on its own thread, touching
// nothing of the loop's; the loop takes the job back when it is done
// (the index of reports is the loop's, and so is the run's end).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "state_dir.hpp"
#include "syncer.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/run/record.hpp"

namespace turncal::daemon {

struct ReportJob {
  // given by the loop
  std::string run_id;
  std::string log_path;  ///< the run's log, digested once closed
  /// The run's log (closed here, after the last fsync the syncer has of
  /// it), and the one a fault retired; either may be empty.
  std::optional<can::LogWriter> log;
  std::optional<can::LogWriter> retired_log;
  /// The run was to end with its estimates (the report phase); false: it
  /// ended failed or aborted, and its report says so.
  bool with_estimates = false;
  /// The run's log fault so far ("" none): a report with estimates needs a
  /// whole log.
  std::string log_error;
  /// The report with the estimates (when the run has them and its log was
  /// whole when the job began) and without; the job takes the first only
  /// if the log is still whole once closed and digested.
  std::optional<nlohmann::json> with;
  nlohmann::json without;
  /// What the HTML report draws of the estimate (with `with` only; its
  /// plots are left out without them).
  std::optional<run::BuiltInput> input;
  std::optional<est::EstimationResult> result;
  nlohmann::json host_clock;  ///< the report's "host_clock"

  // given back
  std::string report_error;         ///< the report not written: why ("" written)
  nlohmann::json written;           ///< the report as a reader will find it
  std::vector<std::string> errors;  ///< for the journal
};

/// A failed fsync of the run's log as the run's reason: which lines are
/// sure to be on disk.
std::string fsync_fault(int error, std::uint64_t synced);
/// A log fault: `log`, if open, is retired where it stands (no more of the
/// run goes into it) and `what` gets up to which line it is kept.
std::string retire_log(std::string what, std::optional<can::LogWriter>& log,
                       std::optional<can::LogWriter>& retired);

/// Does the job (see the file's comment): every step's failure is in
/// log_error, report_error or errors, none thrown.
void write_report_job(ReportJob& job, Syncer& syncer, const StateDir& state) noexcept;

}  // namespace turncal::daemon
