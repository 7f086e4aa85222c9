#include "report_writer.hpp"

#include <cstring>
#include <exception>

#include "turncal/run/html.hpp"
#include "turncal/run/report.hpp"
#include "turncal/run/sha256.hpp"

namespace turncal::daemon {

std::string fsync_fault(int error, std::uint64_t synced) {
  return std::string("log fsync failed: ") + std::strerror(error) + ": lines after " +
         std::to_string(synced) + " may be lost";
}

std::string retire_log(std::string what, std::optional<can::LogWriter>& log,
                       std::optional<can::LogWriter>& retired) {
  if (log) {
    what += ": log kept up to line " + std::to_string(log->records_written());
    retired = std::move(log);
    log.reset();
  }
  return what;
}

namespace {

void write(ReportJob& job, Syncer& syncer, const StateDir& state) {
  // the last phase-end fsync done (and heard of) before the file closes
  syncer.wait_idle();
  if (const int e = syncer.take_error(); e != 0 && job.log_error.empty()) {
    // as the loop's own log fault: the log is kept where it stands
    job.log_error = retire_log(fsync_fault(e, syncer.synced()), job.log, job.retired_log);
  }
  if (job.retired_log) {
    (void)job.retired_log->close();  // its fault is the run's reason already
    job.retired_log.reset();
  }
  if (job.log) {
    auto st = job.log->sync();
    auto cl = job.log->close();
    job.log.reset();
    if (!st || !cl) job.log_error = (!st ? st : cl).error().describe();
  }
  std::string sha;
  if (auto dg = run::sha256_file(job.log_path, run::CountLines::No, run::Links::Refuse)) {
    sha = dg->sha256;
  } else {  // a log that cannot be read back is not a log the report can stand on
    job.errors.push_back(dg.error().describe());
    if (job.log_error.empty()) job.log_error = dg.error().describe();
  }
  // the report with the estimates, if the loop gave one and the log is whole
  const bool est = job.with_estimates && job.with.has_value() && job.log_error.empty();
  nlohmann::json j = est ? std::move(*job.with) : std::move(job.without);
  job.with.reset();
  j["log"]["sha256"] = sha;
  j["host_clock"] = job.host_clock;
  if (!job.log_error.empty() && job.with_estimates) {
    // the run was to be done, but its log is not whole: it is not done
    j["status"] = "failed";
    j["reason"] = "log not written whole: " + job.log_error;
  }
  const std::string text = run::report_text(j);
  const bool drawn = est && job.input && job.result;
  const std::string html =
      run::report_html(j, drawn ? &*job.input : nullptr, drawn ? &*job.result : nullptr);
  auto w = state.write_report_files(job.run_id, j, text, html);
  if (!w)
    job.report_error = w.error().describe();
  else
    job.written = std::move(*w);
}

}  // namespace

void write_report_job(ReportJob& job, Syncer& syncer, const StateDir& state) noexcept {
  try {
    write(job, syncer, state);
  } catch (const std::exception& e) {  // memory, mostly: said, and the report is not written
    job.report_error = std::string("internal error: ") + e.what();
  } catch (...) {
    job.report_error = "internal error";
  }
  if (!job.report_error.empty() && job.log_error.empty())
    job.log_error = "report not written: " + job.report_error;
}

}  // namespace turncal::daemon
