// The daemon's control protocol and state directory, without a loop: every
// request shape gets a reply (never an exception), reports of any shape are
// readable or "unreadable" with the field, writes that fail say so and
// leave nothing half-written.
#include <doctest/doctest.h>

#include <fcntl.h>
#include <grp.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "control.hpp"
#include "state_dir.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/run/html.hpp"
#include "turncal/run/report.hpp"

using namespace turncal;
using namespace turncal::daemon;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

struct FakeDaemon {
  Index index;
  bool running = true;
  int status_calls = 0;
  View view() {
    View v;
    v.status = [this] {
      ++status_calls;
      return json{{"ok", true}, {"phase", "turn"}};
    };
    v.running = running;
    v.index = &index;
    v.read_report = [](const std::string& id) -> Result<json> {
      return make_error("no report " + id);
    };
    return v;
  }
};

std::string error_of(const Outcome& o) {
  REQUIRE(o.reply.is_object());
  REQUIRE(o.reply.contains("ok"));
  CHECK(o.reply["ok"] == false);
  CHECK_FALSE(o.action.has_value());
  return o.reply.value("error", std::string());
}

/// A minimal report as the daemon writes one, with one estimate.
json sample_report() {
  return {
      {"format", "turncal-report-1"},
      {"schema_version", run::kReportSchemaVersion},
      {"run_id", "20261201T000000Z"},
      {"status", "done"},
      {"unit", "SN-1"},
      {"start_time_unix_s", 1.8e9},
      {"profile", {{"name", "tactical"}, {"duration_s", 3600.0}}},
      {"estimates",
       {{"nu0_1", {{"value", 1e-7}, {"sigma", 1e-9}, {"prior_sigma", 1e-6}, {"unit", "rad/s"}}}}},
      {"verdict", {{"pass", true}, {"checks", json::array()}}}};
}

}  // namespace

TEST_CASE("control: wrong types are error replies, never exceptions") {
  FakeDaemon d;
  // the requests that crashed the daemon, and their kin
  CHECK(error_of(dispatch(R"({"cmd":"abort","reason":1})", d.view())) ==
        "abort: reason: expected a string");
  CHECK(error_of(dispatch(R"({"cmd":"start","observe":"x"})", d.view())) ==
        "start: observe: expected true or false");
  CHECK(error_of(dispatch(R"({"cmd":"report","run_id":1})", d.view())) ==
        "report: run_id: expected a string");
  CHECK(error_of(dispatch(R"({"cmd":"history","unit":[1]})", d.view())) ==
        "history: unit: expected a string");
  CHECK(error_of(dispatch(R"({"cmd":"start","heading_offset_deg":"5"})", d.view()))
            .starts_with("start: heading_offset_deg: expected a number"));
  CHECK(error_of(dispatch(R"({"cmd":"start","unit":"a/b"})", d.view()))
            .starts_with("start: unit: expected the INS identity"));
  CHECK(error_of(dispatch(R"({"cmd":"start","plan_text":5})", d.view())) ==
        "start: plan_text: expected a string");
  CHECK(error_of(dispatch(R"({"cmd":"status","x":1})", d.view())) == "status: unknown field 'x'");
  CHECK(error_of(dispatch("[1,2]", d.view())).starts_with("malformed request"));
  CHECK(error_of(dispatch("{\"cmd\":", d.view())).starts_with("malformed request"));
  CHECK(error_of(dispatch(std::string(5000, '['), d.view())).starts_with("malformed request"));
  CHECK(error_of(dispatch(R"({"cmd":"fly"})", d.view())) == "unknown command 'fly'");
  CHECK(d.status_calls == 0);
}

TEST_CASE("control: the daemon opens no path a client names") {
  FakeDaemon d;
  for (const char* bad : {"../../etc/passwd", "/etc/shadow", "a/b", "..", ".", ""}) {
    CAPTURE(bad);
    CHECK(error_of(dispatch(json{{"cmd", "start"}, {"profile", bad}}.dump(), d.view()))
              .starts_with("start: profile: expected the name of a plan"));
  }
  for (const char* bad : {"../x", "a/b", ".."}) {
    CAPTURE(bad);
    CHECK(error_of(dispatch(json{{"cmd", "report"}, {"run_id", bad}}.dump(), d.view())) ==
          "report: expected a run_id");
  }
  // a plan's text, or a bare name, goes to the loop as the start action
  const Outcome o =
      dispatch(R"({"cmd":"start","profile":"tactical.toml","unit":"SN-1"})", d.view());
  REQUIRE(o.action.has_value());
  const auto& s = std::get<StartRequest>(*o.action);
  CHECK(s.plan_name == "tactical.toml");
  CHECK(s.plan_text.empty());
  CHECK(s.unit == std::optional<std::string>("SN-1"));
  const Outcome t =
      dispatch(R"({"cmd":"start","plan_text":"[profile]\n","plan_name":"mine.toml"})", d.view());
  REQUIRE(t.action.has_value());
  CHECK(std::get<StartRequest>(*t.action).plan_text == "[profile]\n");
  CHECK(error_of(dispatch(R"({"cmd":"start","plan_name":"mine.toml"})", d.view()))
            .starts_with("start: plan_name: names the plan_text"));
  CHECK(error_of(dispatch(R"({"cmd":"start","plan_text":"x","profile":"y"})", d.view()))
            .find("not both") != std::string::npos);
}

TEST_CASE("control: abort only while running; status and watch read the daemon") {
  FakeDaemon d;
  const Outcome a = dispatch(R"({"cmd":"abort","reason":"operator"})", d.view());
  REQUIRE(a.action.has_value());
  CHECK(std::get<AbortRequest>(*a.action).reason == "operator");
  d.running = false;
  CHECK(error_of(dispatch(R"({"cmd":"abort"})", d.view())) == "no run in progress");
  const Outcome w = dispatch(R"({"cmd":"watch"})", d.view());
  CHECK(w.watch);
  CHECK(w.reply["phase"] == "turn");
  CHECK(d.status_calls == 1);
}

TEST_CASE("check_report: every field a reader takes is type-checked") {
  CHECK(run::check_report(sample_report()).empty());
  CHECK(run::report_text(sample_report()).find("nu0_1") != std::string::npos);
  struct Case {
    const char* pointer;
    json value;
    const char* error;
  };
  const Case cases[] = {
      {"/status", 5, "status: expected a string"},
      {"/reason", json::array(), "reason: expected a string"},
      {"/profile", "x", "profile: expected an object"},
      {"/profile/name", 1, "profile.name: expected a string"},
      {"/estimates/nu0_1/sigma", "1", "estimates.nu0_1.sigma: expected a number"},
      {"/estimates/nu0_1", 3, "estimates.nu0_1: expected an object"},
      {"/verdict/pass", "yes", "verdict.pass: expected true or false"},
      {"/verdict/checks", json::array({5}), "verdict.checks[0]: expected an object"},
      {"/turns_achieved", json::array({json::object()}), "turns_achieved[0].angle_rad: missing"},
      {"/innovations", json{{"nis_mean", 1.0}, {"white", true}, {"nis_95_interval", {1.0}}},
       "innovations.nis_95_interval: expected two numbers"},
      {"/start_time_unix_s", "now", "start_time_unix_s: expected a number"},
      {"/schema_version", 99, "schema_version 99 is newer than this turncal reads (2)"},
      // null is a wrong type too, but where a reader takes it (unit)
      {"/reason", nullptr, "reason: expected a string"},
      {"/status", nullptr, "status: expected a string"},
      {"/verdict", nullptr, "verdict: expected an object"},
      {"/profile/name", nullptr, "profile.name: expected a string"},
      {"/estimates/nu0_1/unit", nullptr, "estimates.nu0_1.unit: expected a string"},
      // a bound or a time scale no run can have (a replay would read it)
      {"/time_base/scale", 0, "time_base.scale: expected a number in [0.001, 10000], not 0"},
      {"/time_base/scale", std::numeric_limits<double>::infinity(),
       "time_base.scale: expected a number in [0.001, 10000], not inf"},
      {"/time_base/epoch_us", -1,
       "time_base.epoch_us: expected a number in [0, 9.22337e+15], not -1"},
      {"/time_base/epoch_us", 1e16,
       "time_base.epoch_us: expected a number in [0, 9.22337e+15], not 1e+16"},
      {"/settings/stale_floor_s", -0.1,
       "settings.stale_floor_s: expected a number of at least 0, not -0.1"},
      {"/settings/real_time_floor_s", -1,
       "settings.real_time_floor_s: expected a number of at least 0, not -1"},
      {"/plausibility/dbc_ranges", 1, "plausibility.dbc_ranges: expected true or false"},
      {"/plausibility/max_fraction", -0.5,
       "plausibility.max_fraction: expected a number in [0, 1], not -0.5"},
      {"/plausibility/max_fraction", 1.5,
       "plausibility.max_fraction: expected a number in [0, 1], not 1.5"},
      {"/plausibility/max_velocity_mps", 0,
       "plausibility.max_velocity_mps: expected a number above 0, not 0"},
      {"/plausibility/max_table_rate_rps", -1,
       "plausibility.max_table_rate_rps: expected a number above 0, not -1"},
      {"/plausibility/step_slack_s", -0.01,
       "plausibility.step_slack_s: expected a number of at least 0, not -0.01"},
      {"/plausibility/step_slack_s", nullptr, "plausibility.step_slack_s: expected a number"},
      // an interrupted run's log: what was cut off its end
      {"/log/torn_bytes_cut", "12", "log.torn_bytes_cut: expected an integer"},
      {"/log/torn_bytes_cut", 1.5, "log.torn_bytes_cut: expected an integer"},
      {"/log/torn_tail", 12, "log.torn_tail: expected a string"},
      {"/log/lines", nullptr, "log.lines: expected an integer"},
  };
  for (const Case& c : cases) {
    CAPTURE(c.pointer);
    json r = sample_report();
    r[json::json_pointer(c.pointer)] = c.value;
    CHECK(run::check_report(r) == c.error);
  }
  json replayed = sample_report();  // a replay's report: a whole log has damage null
  replayed["replay"] = {{"of_live_report", true}, {"damage", nullptr}};
  CHECK(run::check_report(replayed).empty());
  json bounded = sample_report();  // the ends of each range; null: no bound
  bounded["plausibility"] = {{"max_velocity_mps", nullptr},
                             {"max_table_rate_rps", 1e-9},
                             {"max_fraction", 1},
                             {"step_slack_s", 0}};
  bounded["time_base"]["scale"] = 1e-3;
  bounded["time_base"]["epoch_us"] = 0;
  CHECK(run::check_report(bounded).empty());
  bounded["plausibility"]["max_fraction"] = 0;
  bounded["time_base"]["scale"] = 1e4;
  bounded["time_base"]["epoch_us"] = 9223372035999999.0;  // a log's last microsecond
  CHECK(run::check_report(bounded).empty());
  json unnamed = sample_report();
  unnamed["unit"] = nullptr;
  CHECK(run::check_report(unnamed).empty());
  // an older report, without schema_version, still reads
  json old = sample_report();
  old.erase("schema_version");
  CHECK(run::check_report(old).empty());
  CHECK(run::check_report(json::array()) == "not a JSON object");
}

TEST_CASE("report: a log's cut end is shown in the text and the HTML, quoted as it was kept") {
  json r = sample_report();
  r["log"] = {{"file", "r.log"}, {"sha256", std::string(64, '0')}, {"lines", 3}};
  REQUIRE(run::check_report(r).empty());
  CHECK(run::log_text(r["log"]) == "r.log");  // nothing cut: nothing said of it
  r["log"]["torn_bytes_cut"] = 0;
  CHECK(run::log_text(r["log"]) == "r.log");
  r["log"]["torn_bytes_cut"] = 8;
  r["log"]["torn_tail"] = printable_bytes("(1.0\"<&\x01");
  REQUIRE(run::check_report(r).empty());
  const std::string said =
      "r.log (cut off its end: 8 bytes of a line cut short, \"(1.0\\x22<&\\x01\")";
  CHECK(run::log_text(r["log"]) == said);
  CHECK(run::report_text(r).find("  log: " + said + "\n") != std::string::npos);
  // in the HTML as text, escaped: the < and & are no markup
  const std::string html = run::report_html(r, nullptr, nullptr);
  CHECK(html.find("<dd>r.log (cut off its end: 8 bytes of a line cut short, "
                  "&quot;(1.0\\x22&lt;&amp;\\x01&quot;)</dd>") != std::string::npos);
}

TEST_CASE("state directory: reports indexed or unreadable; reports and history survive bad files") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-state-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  StateDir st(dir);
  REQUIRE(st.create().ok());
  REQUIRE(st.write_atomic("good.report.json", sample_report().dump()).ok());
  json bad = sample_report();
  bad["estimates"]["nu0_1"]["value"] = "oops";
  REQUIRE(st.write_atomic("bad.report.json", bad.dump()).ok());
  REQUIRE(st.write_atomic("junk.report.json", "{not json").ok());
  std::ofstream(dir / "orphan.log") << "(1.000000) can0 123#00\n";
  st.load_index();
  REQUIRE(st.index().size() == 3);
  CHECK(st.index().at("good").unreadable.empty());
  CHECK(st.index().at("bad").unreadable == "estimates.nu0_1.value: expected a number");
  CHECK(st.index().at("junk").unreadable == "not JSON");
  CHECK(st.logs_without_report().runs == std::vector<std::string>{"orphan"});
  CHECK(st.logs_without_report().skipped.empty());
  CHECK(!st.read_report("bad").ok());
  CHECK(st.read_report("bad").error().describe().find("unreadable") != std::string::npos);
  CHECK(st.read_report("good").ok());

  // through the protocol: the list names the unreadable ones, the history
  // takes the good one only
  View v;
  v.status = [] { return json::object(); };
  v.index = &st.index();
  v.read_report = [&](const std::string& id) { return st.read_report(id); };
  const Outcome list = dispatch(R"({"cmd":"reports"})", v);
  REQUIRE(list.reply["reports"].size() == 3);
  int unreadable = 0;
  for (const auto& e : list.reply["reports"]) unreadable += e["status"] == "unreadable";
  CHECK(unreadable == 2);
  const Outcome h = dispatch(R"({"cmd":"history","unit":"SN-1"})", v);
  CHECK(h.reply["history"]["runs"].size() == 1);
  const Outcome r = dispatch(R"({"cmd":"report","run_id":"bad"})", v);
  CHECK(r.reply["ok"] == false);
  fs::remove_all(dir);
}

namespace {
int g_fail_errno = 0;
int g_writes_before_fail = 0;
ssize_t failing_write(int fd, const void* p, std::size_t n) {
  if (g_writes_before_fail-- <= 0) {
    errno = g_fail_errno;
    return -1;
  }
  return ::write(fd, p, n < 3 ? n : 3);  // short writes too
}
int g_fsyncs_before_fail = 1000;
int failing_fsync(int fd) {
  if (g_fsyncs_before_fail-- <= 0) {
    errno = EIO;
    return -1;
  }
  return ::fsync(fd);
}
bool g_fail_close = false;
int failing_close(int fd) {
  const int r = ::close(fd);  // closed either way, as the kernel does
  if (!g_fail_close) return r;
  errno = EIO;
  return -1;
}
int g_fstats_before_fail = 1000;
int g_fstats_before_append = 1000;  // then a byte is appended (a writer still at it)
int failing_fstat(int fd, struct stat* st) {
  if (g_fstats_before_fail-- <= 0) {
    errno = EIO;
    return -1;
  }
  if (g_fstats_before_append-- == 0) {
    char path[64];
    std::snprintf(path, sizeof path, "/proc/self/fd/%d", fd);
    std::ofstream(path, std::ios::app) << 'x';
  }
  return ::fstat(fd, st);
}
bool g_fail_ftruncate = false;
int failing_ftruncate(int fd, off_t length) {
  if (!g_fail_ftruncate) return ::ftruncate(fd, length);
  errno = ENOSPC;
  return -1;
}
}  // namespace

TEST_CASE("state directory: the report's space is reserved at the start, or the run refused") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-rsv-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  StateDir st(dir);
  REQUIRE(st.create().ok());
  REQUIRE(st.reserve("r1", 1 << 20).ok());
  REQUIRE(fs::exists(dir / ".r1.reserve"));
  CHECK(fs::file_size(dir / ".r1.reserve") == 1 << 20);
  st.release("r1");
  CHECK_FALSE(fs::exists(dir / ".r1.reserve"));
  // more than any disk here holds: refused with the reason, nothing left
  auto big = st.reserve("r2", std::uint64_t{1} << 52);
  REQUIRE_FALSE(big.ok());
  CHECK(big.error().describe().find("could not be reserved") != std::string::npos);
  CHECK_FALSE(fs::exists(dir / ".r2.reserve"));
  // a killed daemon's reservation goes at the next start
  REQUIRE(st.reserve("r3", 4096).ok());
  st.release_stale();
  CHECK_FALSE(fs::exists(dir / ".r3.reserve"));
  fs::remove_all(dir);
}

TEST_CASE("state directory: a write that fails says why and leaves no file, whole or half") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-io-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const FileIo io{failing_write, failing_fsync, failing_close, failing_ftruncate, failing_fstat};
  StateDir st(dir, io);
  REQUIRE(st.create().ok());
  for (const int err : {ENOSPC, EIO}) {
    CAPTURE(err);
    g_fail_errno = err;
    g_writes_before_fail = 2;  // some bytes go, then the disk fails
    auto w = st.write_atomic("r.report.json", std::string(100, 'x'));
    REQUIRE_FALSE(w.ok());
    CHECK(w.error().describe().find(std::strerror(err)) != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "r.report.json"));
    CHECK_FALSE(fs::exists(dir / "r.report.json.tmp"));
  }
  g_writes_before_fail = 1000;
  // the file's fsync, its close, and the directory's fsync after the rename
  struct Step {
    int fsyncs_before_fail;
    bool fail_close;
    const char* says;
    bool file_in_place;
  };
  for (const Step& s :
       {Step{0, false, "cannot sync", false}, Step{1000, true, "cannot close", false},
        Step{1, false, "cannot sync", true}}) {
    CAPTURE(s.says);
    g_fsyncs_before_fail = s.fsyncs_before_fail;
    g_fail_close = s.fail_close;
    fs::remove(dir / "s.report.json");
    auto w = st.write_atomic("s.report.json", "x");
    REQUIRE_FALSE(w.ok());
    CHECK(w.error().describe().find(s.says) != std::string::npos);
    CHECK(fs::exists(dir / "s.report.json") == s.file_in_place);
    CHECK_FALSE(fs::exists(dir / "s.report.json.tmp"));
  }
  g_fsyncs_before_fail = 1000;
  g_fail_close = false;
  REQUIRE(st.write_atomic("r.report.json", "abcdefg").ok());  // short writes are finished
  std::ifstream in(dir / "r.report.json");
  std::string s;
  std::getline(in, s);
  CHECK(s == "abcdefg");
  fs::remove_all(dir);
}

namespace {
/// A file of `bytes` last written `days_ago` days before `now`.
void old_file(const fs::path& p, std::size_t bytes, double now, double days_ago) {
  std::ofstream(p) << std::string(bytes, 'x');
  const double t = now - days_ago * 86400;
  const timespec ts{static_cast<time_t>(t), 0};
  const timespec times[2] = {ts, ts};
  REQUIRE(::utimensat(AT_FDCWD, p.c_str(), times, 0) == 0);
}
}  // namespace

TEST_CASE("state directory: retention removes old logs, keeps every report and unreported log") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-keep-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  StateDir st(dir);
  REQUIRE(st.create().ok());
  const double now = 2'000'000'000;
  // runs a, b, c with reports; d a log without one (an interrupted run
  // before its report); e the running run
  old_file(dir / "20260101T000000Z.log", 4000, now, 40);
  old_file(dir / "20260201T000000Z.log", 3000, now, 20);
  old_file(dir / "20260301T000000Z.log", 2000, now, 5);
  old_file(dir / "20250101T000000Z.log", 1000, now, 400);
  old_file(dir / "20260401T000000Z.log", 500, now, 50);
  for (const char* id : {"20260101T000000Z", "20260201T000000Z", "20260301T000000Z"})
    REQUIRE(st.write_atomic(std::string(id) + ".report.json", sample_report().dump()).ok());
  REQUIRE(st.write_atomic("20260401T000000Z.report.json", sample_report().dump()).ok());
  // f: a report that does not read; g: an interrupted run's note
  old_file(dir / "20240101T000000Z.log", 700, now, 600);
  REQUIRE(st.write_atomic("20240101T000000Z.report.json", "{not json").ok());
  old_file(dir / "20240201T000000Z.log", 800, now, 600);
  json note = sample_report();
  note["status"] = "interrupted";
  REQUIRE(st.write_atomic("20240201T000000Z.report.json", note.dump()).ok());
  st.load_index();

  SUBCASE("nothing configured: nothing goes") {
    CHECK(st.prune_logs({}, now).empty());
    CHECK(fs::exists(dir / "20260101T000000Z.log"));
  }
  SUBCASE("by age: the reported logs older than the limit, never the running run's") {
    const auto p = st.prune_logs({30, 0}, now, "20260401T000000Z");
    REQUIRE(p.size() == 1);
    CHECK(p[0].run_id == "20260101T000000Z");
    CHECK(p[0].bytes == 4000);
    CHECK(p[0].why == "older than 30 days");
    CHECK(p[0].error.empty());
    CHECK_FALSE(fs::exists(dir / "20260101T000000Z.log"));
    CHECK(fs::exists(dir / "20260101T000000Z.report.json"));
    CHECK(fs::exists(dir / "20250101T000000Z.log"));  // no report: the only record
    CHECK(fs::exists(dir / "20260401T000000Z.log"));  // running
    CHECK(fs::exists(dir / "20240101T000000Z.log"));  // its report does not read
    CHECK(fs::exists(dir / "20240201T000000Z.log"));  // interrupted: the log is the run
  }
  SUBCASE("by size: the oldest reported logs until all fit") {
    // 12000 bytes in all; 7500 allowed: a (4000) and b (3000) go, c stays
    const auto p = st.prune_logs({0, 7500}, now);
    REQUIRE(p.size() == 2);
    CHECK(p[0].run_id == "20260101T000000Z");
    CHECK(p[1].run_id == "20260201T000000Z");
    CHECK(fs::exists(dir / "20260301T000000Z.log"));
    CHECK(fs::exists(dir / "20250101T000000Z.log"));
    CHECK(fs::exists(dir / "20260401T000000Z.log"));
  }
  SUBCASE("what is not a file is no log: left alone") {
    fs::remove(dir / "20260101T000000Z.log");
    fs::create_directory(dir / "20260101T000000Z.log");
    const auto p = st.prune_logs({0, 1}, now);
    for (const auto& e : p) CHECK(e.error.empty());
    CHECK(p.size() == 3);  // b, c and the fourth reported log
    CHECK(fs::is_directory(dir / "20260101T000000Z.log"));
  }
  st.load_index();
  CHECK(st.index().size() == 6);  // every report is there still
  fs::remove_all(dir);
}

TEST_CASE("state directory: a killed run's log is cut after its last whole line, no further") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-torn-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  StateDir st(dir);
  const std::string whole =
      "(1.000000) can0 123#0102\n(1.010000) can0 124#0304\n";  // two whole lines
  const auto write = [&](const std::string& id, const std::string& text) {
    std::ofstream(dir / (id + ".log"), std::ios::binary) << text;
  };
  const auto read = [&](const std::string& id) {
    std::ifstream in(dir / (id + ".log"), std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
  };
  // a kill's part of a line is shorter than a whole line (kMaxLogLine
  // with its newline): one byte short of that is cut, that long is damage
  const std::string longest_part(turncal::can::kMaxLogLine - 1, 'x');
  const std::string too_long(turncal::can::kMaxLogLine, 'x');
  struct Case {
    const char* id;
    std::string text;
    std::string cut;
    std::string left;
    const char* error;  // nullptr: none
  };
  for (const Case& c :
       {Case{"whole", whole, "", whole, nullptr}, Case{"empty", "", "", "", nullptr},
        Case{"torn", whole + "(1.02000", "(1.02000", whole, nullptr},
        Case{"fragment", "(1.000000) can0 12", "(1.000000) can0 12", "", nullptr},
        Case{"longest", whole + longest_part, longest_part, whole, nullptr},
        Case{"longest-alone", longest_part, longest_part, "", nullptr},
        Case{"too-long", whole + too_long, "", whole + too_long, "not a line cut short"},
        Case{"too-long-alone", too_long, "", too_long, "not a line cut short"}}) {
    CAPTURE(c.id);
    write(c.id, c.text);
    const TailCut r = st.cut_torn_tail(c.id);
    CHECK(r.bytes == c.cut);
    if (c.error == nullptr)
      CHECK(r.error.empty());
    else
      CHECK(r.error.find(c.error) != std::string::npos);
    CHECK(read(c.id) == c.left);
  }
  const TailCut none = st.cut_torn_tail("absent");
  CHECK(none.bytes.empty());
  CHECK(none.error.find("cannot open") != std::string::npos);
  // never through a link, never anything but a regular file
  write("target", whole + "(1.0");
  fs::create_symlink(dir / "target.log", dir / "link.log");
  const TailCut link = st.cut_torn_tail("link");
  CHECK(link.error.find("cannot open") != std::string::npos);
  CHECK(read("target") == whole + "(1.0");
  CHECK_FALSE(link.regular);  // no report may be made of it
  fs::create_directories(dir / "dir.log");
  const TailCut in_dir = st.cut_torn_tail("dir");
  CHECK(in_dir.error.find("not a regular file") != std::string::npos);
  CHECK_FALSE(in_dir.regular);
  // a FIFO is refused without blocking: opened for reading with no writer,
  // a blocking open would never return (and this test would hang)
  REQUIRE(::mkfifo((dir / "fifo.log").c_str(), 0600) == 0);
  const TailCut fifo = st.cut_torn_tail("fifo");
  CHECK(fifo.error.find("not a regular file") != std::string::npos);
  CHECK_FALSE(fifo.regular);
  CHECK(st.cut_torn_tail("target").regular);
  // nor are they runs a killed daemon left: only regular files are, and
  // each passed over is said with why
  const LogsWithoutReport left = st.logs_without_report();
  CHECK(std::count(left.runs.begin(), left.runs.end(), "target") == 1);
  for (const char* id : {"link", "dir", "fifo"})
    CHECK(std::count(left.runs.begin(), left.runs.end(), id) == 0);
  std::vector<std::string> skipped = left.skipped;
  std::sort(skipped.begin(), skipped.end());
  CHECK(skipped ==
        std::vector<std::string>{"dir.log: not a regular file, no run's log; left as it is",
                                 "fifo.log: not a regular file, no run's log; left as it is",
                                 "link.log: a link, no run's log; left as it is"});

  // the cut, its sync and the close each fail with their reason; after the
  // cut, what was cut is said with the failure
  const FileIo io{failing_write, failing_fsync, failing_close, failing_ftruncate, failing_fstat};
  StateDir failing(dir, io);
  // the look before the read and the look before the cut each fail with
  // their reason, and a file that grew between the two is left as it is
  struct Look {
    int fstats_before_fail;
    int fstats_before_append;
    const char* says;
    bool regular;
  };
  for (const Look& l : {Look{0, 1000, "cannot stat: Input/output error", false},
                        Look{1, 1000, "cannot stat it to cut its last, partial line", true},
                        Look{1000, 1, "changed while it was read; left as it is", true}}) {
    CAPTURE(l.says);
    write("t", whole + "(1.0");
    g_fstats_before_fail = l.fstats_before_fail;
    g_fstats_before_append = l.fstats_before_append;
    const TailCut f = failing.cut_torn_tail("t");
    g_fstats_before_fail = 1000;
    g_fstats_before_append = 1000;
    CHECK(f.error.find(l.says) != std::string::npos);
    CHECK(f.regular == l.regular);
    CHECK(f.bytes.empty());
    CHECK(read("t") == whole + "(1.0" + (l.fstats_before_append == 1 ? "x" : ""));
  }
  struct Step {
    bool fail_ftruncate;
    int fsyncs_before_fail;
    bool fail_close;
    const char* says;
    std::string cut;
    std::string left;
  };
  for (const Step& s : {Step{true, 1000, false, "cannot cut", "", whole + "(1.0"},
                        Step{false, 0, false, "cut, but the sync failed", "(1.0", whole},
                        Step{false, 1000, true, "cut, but the close failed", "(1.0", whole}}) {
    CAPTURE(s.says);
    write("t", whole + "(1.0");
    g_fail_ftruncate = s.fail_ftruncate;
    g_fsyncs_before_fail = s.fsyncs_before_fail;
    g_fail_close = s.fail_close;
    const TailCut f = failing.cut_torn_tail("t");
    g_fail_ftruncate = false;
    g_fsyncs_before_fail = 1000;
    g_fail_close = false;
    CHECK(f.error.find(s.says) != std::string::npos);
    CHECK(f.bytes == s.cut);
    CHECK(read("t") == s.left);
  }
  fs::remove_all(dir);
}

TEST_CASE("state directory: the bytes a kill left are kept as printable text, reversibly") {
  CHECK(printable_bytes("(1.0) can0 12") == "(1.0) can0 12");
  CHECK(printable_bytes(std::string("a\0b", 3)) == "a\\x00b");
  CHECK(printable_bytes("\r\x7f\xff") == "\\x0d\\x7f\\xff");
  // a backslash is doubled, so the text \x00 is not a NUL byte
  CHECK(printable_bytes("\\x00") == "\\\\x00");
  CHECK(printable_bytes("") == "");
  // a double quote too, so the text can be quoted as it is
  CHECK(printable_bytes("a\"b") == "a\\x22b");
}

TEST_CASE("state directory: one process holds it; a second is refused until the first lets go") {
  const fs::path dir = fs::temp_directory_path() / ("turncal-lock-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  StateDir st(dir);
  REQUIRE(st.create().ok());
  {
    auto first = st.lock();
    REQUIRE(first.ok());
    // flock is per open file: a second open of the lock, as another
    // daemon's would be, is refused while the first holds it
    auto second = StateDir(dir).lock();
    REQUIRE_FALSE(second.ok());
    CHECK(second.error().describe().find("held by another process") != std::string::npos);
    CHECK(second.error().describe().find(dir.string()) != std::string::npos);
    DirLock moved = std::move(*first);  // a move keeps it held
    CHECK_FALSE(StateDir(dir).lock().ok());
  }
  CHECK(st.lock().ok());  // let go with its holder
  fs::remove_all(dir);
}

TEST_CASE(
    "a lock is taken on a regular file only, never through a link, and with no right to "
    "write it") {
  // under /tmp (a $TMPDIR may be out of another user's reach)
  const fs::path dir = fs::path("/tmp") / ("turncal-lockf-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string busy = "taken elsewhere";
  // a link to a lock file: refused, and the file it points at is not locked
  std::ofstream(dir / "target") << "";
  fs::create_symlink(dir / "target", dir / "link.lock");
  auto linked = take_lock(dir / "link.lock", busy);
  REQUIRE_FALSE(linked.ok());
  CHECK(linked.error().describe().find("cannot open " + (dir / "link.lock").string()) !=
        std::string::npos);
  CHECK(take_lock(dir / "target", busy).ok());
  // a FIFO: refused at once (a blocking open would wait for a writer)
  REQUIRE(::mkfifo((dir / "fifo.lock").c_str(), 0600) == 0);
  auto fifo = take_lock(dir / "fifo.lock", busy);
  REQUIRE_FALSE(fifo.ok());
  CHECK(fifo.error().describe() == (dir / "fifo.lock").string() + ": not a regular file, no lock");
  // a directory
  fs::create_directories(dir / "dir.lock");
  CHECK_FALSE(take_lock(dir / "dir.lock", busy).ok());
  // a lock file its taker may not write (one a start as root left behind,
  // 0644 and root's): still taken, and held against a second taker
  const fs::path ro = dir / "ro.lock";
  std::ofstream(ro) << "";
  REQUIRE(::chmod(ro.c_str(), 0444) == 0);
  REQUIRE(::chmod(dir.c_str(), 0755) == 0);
  // the taker as another user (root may write any file: nobody then), in
  // a child, so this process keeps its own. Exit 0: taken, and held
  // against a second taker; 1 and 2: not; 3 and 5: the check cannot be
  // set up here (no such user in a user namespace, the file out of its
  // reach); 4: the taker may write the file after all
  constexpr int kCannotCheck[] = {3, 5};
  const uid_t uid = ::geteuid() == 0 ? 65534 : ::geteuid();
  const pid_t pid = ::fork();
  if (pid == 0) {
    if (uid != ::geteuid() &&
        (::setgroups(0, nullptr) != 0 || ::setgid(65534) != 0 || ::setuid(uid) != 0))
      ::_exit(3);
    if (::access(ro.c_str(), R_OK) != 0) ::_exit(5);
    if (::access(ro.c_str(), W_OK) == 0) ::_exit(4);
    auto l = take_lock(ro, busy);
    if (!l.ok()) ::_exit(1);
    auto again = take_lock(ro, busy);
    ::_exit(!again.ok() && again.error().describe() == busy ? 0 : 2);
  }
  REQUIRE(pid > 0);
  int status = 0;
  pid_t waited = 0;
  while ((waited = ::waitpid(pid, &status, 0)) < 0 && errno == EINTR) {
  }
  REQUIRE(waited == pid);
  REQUIRE(WIFEXITED(status));
  const int code = WEXITSTATUS(status);
  if (std::find(std::begin(kCannotCheck), std::end(kCannotCheck), code) != std::end(kCannotCheck))
    MESSAGE("a lock file the taker may not write: not checked here (cannot run as uid "
            << uid << ", exit " << code << ")");
  else
    CHECK(code == 0);
  fs::remove_all(dir);
}

TEST_CASE("state directory: the bus's recent frame rate, and the bytes a log of it takes") {
  BusRate r;
  CHECK(std::isnan(r.per_s()));
  r.add(1'000'000, 100);
  r.add(1'500'000, 200);
  CHECK(std::isnan(r.per_s()));  // half a second: not yet a rate
  r.add(3'000'000, 700);
  CHECK(r.per_s() == doctest::Approx(300.0).epsilon(1e-12));
  // the window is the last 10 s: an early burst leaves it
  for (std::uint64_t t = 4; t <= 20; ++t) r.add(t * 1'000'000, 700 + (t - 3) * 50);
  CHECK(r.per_s() == doctest::Approx(50.0).epsilon(1e-12));
  // a counter that went back (a socket re-opened) starts again
  r.add(21'000'000, 10);
  CHECK(std::isnan(r.per_s()));
  // a log line: "(9999999999.999999) vcan0 1FFFFFFF#0000000000000000\n"
  CHECK(log_bytes_bound(1, 5) == 52);
  CHECK(log_bytes_bound(1000, 5) == 52000);
  CHECK(log_bytes_bound(0, 5) == 0);
  CHECK(log_bytes_bound(NAN, 5) == 0);
}

TEST_CASE("the text report's whiteness line: the Ljung-Box statistics with their lag count") {
  // the count is an integer in the report; formatted as one (a "%d" of the
  // double the text formatter takes printed a garbage number of lags)
  const json i = {{"ljung_box", {18.46, 31.24}},
                  {"ljung_box_lags", 20},
                  {"ljung_box_p", {0.5568, 0.05206}},
                  {"white", true}};
  const std::string s = run::whiteness_text(i);
  CHECK_MESSAGE(s.find("Ljung-Box Q 18.5, 31.2 (20 lags), p 0.557, 0.0521") == 0, s);
}
