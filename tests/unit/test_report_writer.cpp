// The report written off the loop (src/daemon/report_writer.hpp): the log
// closed after its last fsync, digested, the report chosen by whether the
// log is whole, the three files written; every failure in the job's
// errors, none thrown.
#include <doctest/doctest.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "report_writer.hpp"

using namespace turncal;
using namespace turncal::daemon;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

int eio_fsync(int) {
  errno = EIO;
  return -1;
}
int good_fsync(int) {
  return 0;
}

/// sha256sum's digest of a file (coreutils, not the code under test).
std::string sha256sum(const fs::path& p) {
  const std::string cmd = "sha256sum '" + p.string() + "'";
  FILE* f = ::popen(cmd.c_str(), "r");
  REQUIRE(f != nullptr);
  char buf[65] = {};
  const std::size_t n = std::fread(buf, 1, 64, f);
  ::pclose(f);
  return std::string(buf, n);
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

struct Fixture {
  fs::path dir = fs::temp_directory_path() / ("turncal-report-" + std::to_string(::getpid()));
  StateDir state{dir};
  Fixture() {
    fs::remove_all(dir);
    REQUIRE(state.create().ok());
  }
  ~Fixture() { fs::remove_all(dir); }
  Fixture(const Fixture&) = delete;
  Fixture& operator=(const Fixture&) = delete;

  /// A job of run "r1" whose log holds two frames, its reports marked.
  ReportJob job(bool with_estimates) {
    ReportJob j;
    j.run_id = "r1";
    j.log_path = (dir / "r1.log").string();
    auto w = can::LogWriter::open(j.log_path);
    REQUIRE(w.ok());
    j.log.emplace(std::move(*w));
    for (int k = 0; k < 2; ++k) {
      can::LogRecord r;
      r.time_ns = 1'000'000'000LL * (k + 1);
      r.interface = "vcan0";
      r.frame.id = 0x123;
      r.frame.len = 1;
      REQUIRE(j.log->write(r).ok());
    }
    j.with_estimates = with_estimates;
    j.with = json{{"format", "turncal-report-1"},
                  {"run_id", "r1"},
                  {"status", "done"},
                  {"log", {{"file", "r1.log"}, {"sha256", ""}}},
                  {"marker", "with"}};
    j.without = json{{"format", "turncal-report-1"},
                     {"run_id", "r1"},
                     {"status", "aborted"},
                     {"log", {{"file", "r1.log"}, {"sha256", ""}}},
                     {"marker", "without"}};
    j.host_clock = {{"realtime_steps", 0}};
    return j;
  }
};

}  // namespace

TEST_CASE("a run's report off the loop: the log closed and digested, the files written") {
  Fixture f;
  Syncer syncer(good_fsync);
  ReportJob j = f.job(false);
  write_report_job(j, syncer, f.state);
  CHECK(j.report_error.empty());
  CHECK(j.log_error.empty());
  CHECK(j.errors.empty());
  CHECK_FALSE(j.log.has_value());  // closed
  const std::string sum = sha256sum(f.dir / "r1.log");
  REQUIRE(sum.size() == 64);
  CHECK(j.written["log"]["sha256"] == sum);
  CHECK(j.written["marker"] == "without");  // a run that ended without estimates
  CHECK(j.written["status"] == "aborted");
  CHECK(j.written["host_clock"]["realtime_steps"] == 0);
  // what a reader will find is what is on disk, the text and HTML beside it
  CHECK(json::parse(slurp(f.dir / "r1.report.json")) == j.written);
  CHECK(fs::file_size(f.dir / "r1.report.txt") > 0);
  CHECK(fs::file_size(f.dir / "r1.report.html") > 0);
  CHECK(slurp(f.dir / "r1.log").find("vcan0 123#00") != std::string::npos);
}

TEST_CASE("a run with its estimates and a whole log: the report with them, as it was") {
  Fixture f;
  Syncer syncer(good_fsync);
  ReportJob j = f.job(true);
  write_report_job(j, syncer, f.state);
  CHECK(j.report_error.empty());
  CHECK(j.log_error.empty());
  CHECK(j.written["marker"] == "with");
  CHECK(j.written["status"] == "done");
  CHECK_FALSE(j.written.contains("reason"));
  CHECK(j.written["log"]["sha256"] == sha256sum(f.dir / "r1.log"));
  CHECK(json::parse(slurp(f.dir / "r1.report.json")) == j.written);
}

TEST_CASE("a log whose last fsync failed: the run is not done, its report says why") {
  Fixture f;
  Syncer syncer(eio_fsync);
  ReportJob j = f.job(true);
  // the phase end's fsync, asked for by the loop before the report
  REQUIRE(j.log->flush().ok());
  syncer.request(j.log->fd(), j.log->records_written());
  write_report_job(j, syncer, f.state);
  CHECK(j.report_error.empty());
  CHECK(j.log_error.find("log fsync failed: ") == 0);
  CHECK(j.log_error.find("log kept up to line 2") != std::string::npos);
  // not the report with the estimates, and failed, with the reason
  CHECK(j.written["marker"] == "without");
  CHECK(j.written["status"] == "failed");
  CHECK(j.written["reason"].get<std::string>().find("log not written whole: log fsync failed") ==
        0);
  CHECK(j.written["log"]["sha256"] == sha256sum(f.dir / "r1.log"));
}

TEST_CASE("a fault the loop had already: kept, and the report without estimates") {
  Fixture f;
  Syncer syncer(good_fsync);
  ReportJob j = f.job(true);
  j.log_error = "write failed: No space left on device";
  write_report_job(j, syncer, f.state);
  CHECK(j.log_error == "write failed: No space left on device");
  CHECK(j.written["marker"] == "without");
  CHECK(j.written["reason"] == "log not written whole: write failed: No space left on device");
}

TEST_CASE(
    "the loop's fault first: no report with estimates, and a later fsync failure not its reason") {
  // as the loop hands it over when its log had failed: estimates due, but
  // no report with them
  Fixture f;
  Syncer syncer(eio_fsync);
  ReportJob j = f.job(true);
  j.with.reset();
  j.log_error = "write failed: Input/output error: log kept up to line 1";
  REQUIRE(j.log->flush().ok());
  syncer.request(j.log->fd(), j.log->records_written());
  write_report_job(j, syncer, f.state);
  CHECK(j.log_error == "write failed: Input/output error: log kept up to line 1");
  CHECK(j.written["marker"] == "without");
  CHECK(j.written["status"] == "failed");
  CHECK(j.written["reason"] == "log not written whole: " + j.log_error);
  CHECK_FALSE(j.log.has_value());  // closed all the same
  CHECK(j.written["log"]["sha256"] == sha256sum(f.dir / "r1.log"));
}

TEST_CASE("a report that cannot be written, and a log that cannot be read back: said, not thrown") {
  Fixture f;
  Syncer syncer(good_fsync);
  ReportJob j = f.job(false);
  j.log_path = (f.dir / "gone.log").string();  // not there: no digest
  fs::remove_all(f.dir);                       // nor a directory to write into
  write_report_job(j, syncer, f.state);
  REQUIRE(j.errors.size() == 1);
  CHECK(j.errors[0].find("gone.log") != std::string::npos);
  CHECK_FALSE(j.report_error.empty());
  CHECK(j.log_error == j.errors[0]);  // the first fault is the run's
  CHECK(j.written.is_null());
}
