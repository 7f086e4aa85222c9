// turncalctl: the operator's command line over turncald's control socket.
//
//   turncalctl [--socket PATH] [--json] start [--profile PLAN.toml] [--watch]
//              [--observe] [--heading-offset DEG] [--unit ID]
//   turncalctl [--socket PATH] [--json] status | watch | abort [REASON]
//   turncalctl [--socket PATH] [--json] reports | show RUN_ID [--truth TRUTH.json]
//   turncalctl [--socket PATH] [--json] history UNIT
//   turncalctl [--json] replay LOG [options]       (no daemon: offline.cpp)
//   turncalctl [--json] plan [options]             (no daemon: offline.cpp)
//   turncalctl dbc FILE.dbc                         (no daemon: offline.cpp)
//   turncalctl decode FILE.dbc LOG [--json]         (no daemon: offline.cpp)
//
// Exit codes: 0 done (a watched run ended done, a request answered ok, a
// replay estimated a whole log, a DBC file read); 1 the daemon refused the request, the
// watched run failed or was aborted, or a replay gave no estimates or met a
// damaged log, or a DBC file cannot be used; 2 usage or a bad configuration; 3 the daemon cannot be
// reached.
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "offline.hpp"
#include "turncal/run/calibration.hpp"
#include "turncal/run/report.hpp"

using nlohmann::json;
using namespace turncal::ctl;
using namespace std::chrono_literals;

namespace {

class Connection {
 public:
  explicit Connection(const std::string& path) {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    if (path.size() >= sizeof a.sun_path) return;
    std::memcpy(a.sun_path, path.c_str(), path.size());
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~Connection() {
    if (fd_ >= 0) ::close(fd_);
  }
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;
  [[nodiscard]] bool ok() const { return fd_ >= 0; }
  bool send(const json& j) {
    const std::string s = j.dump() + "\n";
    return ::send(fd_, s.data(), s.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(s.size());
  }
  /// The next reply line; a discarded json at end of stream.
  json next() {
    for (;;) {
      if (const auto nl = buf_.find('\n'); nl != std::string::npos) {
        const std::string line = buf_.substr(0, nl);
        buf_.erase(0, nl + 1);
        return json::parse(line, nullptr, false);
      }
      char b[65536];
      const ssize_t n = ::recv(fd_, b, sizeof b, 0);
      if (n <= 0) return json::value_t::discarded;
      buf_.append(b, static_cast<std::size_t>(n));
    }
  }

 private:
  int fd_ = -1;
  std::string buf_;
};

std::string clock_text(double s) {
  if (!std::isfinite(s)) return "--:--";
  const long t = std::lround(s);
  char buf[32];
  std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", t / 3600, t / 60 % 60, t % 60);
  return buf;
}

/// A phase the run does not leave.
bool finished(const std::string& phase) {
  return phase == "done" || phase == "failed" || phase == "aborted";
}

/// One progress line: phase, elapsed and remaining, live velocity, table
/// angle, frame health.
std::string progress(const json& s) {
  auto num = [&](const char* k) {
    return s.contains(k) && s[k].is_number() ? s[k].get<double>()
                                             : std::numeric_limits<double>::quiet_NaN();
  };
  std::string phase = s.value("phase", std::string("?"));
  if (s.value("index", 0) > 0) phase += " " + std::to_string(s["index"].get<int>());
  const double dur = num("duration_s"), rem = num("remaining_s");
  const double frac = std::isfinite(rem) && dur > 0 ? 1 - rem / dur : 0;
  std::string bar(20, ' ');
  for (int i = 0; i < static_cast<int>(frac * 20) && i < 20; ++i)
    bar[static_cast<std::size_t>(i)] = '#';
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "[%s] %-10s %s elapsed, %s left | v %+.4f %+.4f m/s | table %8.3f deg", bar.c_str(),
                phase.c_str(), clock_text(num("elapsed_s")).c_str(), clock_text(rem).c_str(),
                num("ve"), num("vn"), num("table_angle_deg"));
  std::string out = buf;
  if (s.contains("health") && !finished(s.value("phase", std::string())))
    for (const auto& [name, h] : s["health"].items())
      out += " | " + name + (h.value("stale", false) ? " STALE" : "") +
             (h.value("dropped", 0) > 0 ? " -" + std::to_string(h["dropped"].get<long>()) : "");
  return out;
}

int watch(Connection& c, bool as_json) {
  if (!c.send({{"cmd", "watch"}})) return kUnreachable;
  const bool tty = ::isatty(STDOUT_FILENO) == 1;
  std::string last_phase;
  auto last_line = std::chrono::steady_clock::now();
  for (;;) {
    const json s = c.next();
    if (s.is_discarded()) {
      std::fprintf(stderr, "\nturncalctl: the daemon closed the connection\n");
      return kUnreachable;
    }
    if (as_json) {
      std::printf("%s\n", s.dump().c_str());
      std::fflush(stdout);
    } else if (tty) {
      std::printf("\r%s\033[K", progress(s).c_str());
      std::fflush(stdout);
    } else if (const auto now = std::chrono::steady_clock::now();
               s.value("phase", std::string()) != last_phase || now - last_line > 10s) {
      // into a file or a pipe: a line at each phase, and every 10 s
      std::printf("%s\n", progress(s).c_str());
      std::fflush(stdout);
      last_line = now;
    }
    const std::string p = s.value("phase", std::string());
    last_phase = p;
    if (finished(p)) {
      if (!as_json) {
        std::printf("%s%s%s\n", tty ? "\n" : "", p.c_str(),
                    s.contains("reason") ? (": " + s["reason"].get<std::string>()).c_str() : "");
      }
      return p == "done" ? kOk : kRefused;
    }
  }
}

}  // namespace

int turncal::ctl::usage(const char* why) {
  std::fprintf(stderr,
               "turncalctl: %s\n"
               "usage: turncalctl [--socket PATH] [--json] COMMAND\n"
               "  start [--profile PLAN.toml|NAME] [--watch]   start a run (a file is sent as its\n"
               "        text; a NAME is a plan in the daemon's profiles directory)\n"
               "        [--observe]                       follow a stand another host drives\n"
               "        [--heading-offset DEG]            INS mounting on the table, this run\n"
               "        [--unit ID]                       the INS under test (serial number)\n"
               "  status                                   the daemon's state\n"
               "  watch                                    progress until the run ends\n"
               "  abort [REASON]                           abort the run (the table quick-stops)\n"
               "  reports                                  the reports kept\n"
               "  show RUN_ID [--truth TRUTH.json]         one report (with turncal-sim's\n"
               "                                           truth beside each estimate)\n"
               "  history UNIT                             one INS's estimates across runs:\n"
               "                                           mean and spread (repeatability)\n"
               "  export RUN_ID|REPORT.json               the determined terms as a calibration\n"
               "        [--format json|toml] [--out FILE]  file: corrections in instrument axes\n"
               "offline (no daemon):\n"
               "  replay LOG                               re-estimate a recorded run\n"
               "        [--config FILE]                   stand configuration (DBC, roles)\n"
               "        [--report LIVE.json|--no-report]  settings of the live run (default:\n"
               "                                           the report next to the log)\n"
               "        [--profile PLAN.toml]             replay with another profile\n"
               "        [--set SECTION.KEY=VALUE]...      what-if: any profile key\n"
               "        [--epoch S] [--mean|--sample]     filter epoch, measurement\n"
               "        [--two-stage|--no-two-stage]      the two-stage comparison\n"
               "        [--second-pass auto|off|always]   the nonlinear second pass: where\n"
               "                                           linearisation matters (default),\n"
               "                                           never, or always\n"
               "        [--heading-offset DEG]            INS mounting on the table\n"
               "        [--json OUT] [--html OUT]         write the report, JSON or HTML\n"
               "        [--truth TRUTH.json]              turncal-sim's truth beside it\n"
               "  check [--config FILE] [--profile PLAN.toml]\n"
               "                                           a stand's configuration, DBC and\n"
               "                                           plans checked without a run\n"
               "  plan                                     predict a planned experiment's sigmas\n"
               "        [--config FILE] [--profile PLAN.toml] [--set SECTION.KEY=VALUE]...\n"
               "        [--epoch S] [--mean|--sample] [--heading-offset DEG]\n"
               "        [--rate HZ]                       INS velocity rate (default 100)\n"
               "        [--no-sweep] [--json OUT]         without the hold/turn table\n"
               "        [--compare PLAN.toml...]          several plans' sigmas side by side\n"
               "  dbc FILE.dbc                             what a DBC file holds as read:\n"
               "                                           messages, signals, multiplexing,\n"
               "                                           then its warnings (file:line)\n"
               "  decode FILE.dbc LOG [--json]             a candump log decoded by a DBC file,\n"
               "                                           a line (a JSON object) per frame;\n"
               "                                           LOG - reads standard input\n"
               "exit codes: 0 ok; 1 refused, the watched run failed, a replay gave no\n"
               "estimates or met a damaged log, or a DBC file cannot be used; 2 usage or\n"
               "bad configuration; 3 no daemon\n",
               why);
  return kUsage;
}

namespace {

/// turncalctl export RUN_ID|REPORT.json [--format json|toml] [--out FILE]:
/// the run's determined terms as a calibration file (calibration.hpp).
/// RUN_ID is asked of the daemon; a report file is read here.
int export_calibration(const std::string& socket, int argc, char** argv, int i) {
  if (i >= argc) return usage("export: missing RUN_ID (or a report file)");
  const std::string target = argv[i++];
  std::string format = "json", out_path;
  for (; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--format" && i + 1 < argc)
      format = argv[++i];
    else if (a == "--out" && i + 1 < argc)
      out_path = argv[++i];
    else
      return usage(("export: unknown argument " + a).c_str());
  }
  if (format != "json" && format != "toml") return usage("export: --format is json or toml");
  json report;
  std::error_code ec;
  if (std::filesystem::is_regular_file(target, ec)) {
    std::ifstream in(target);
    report = json::parse(in, nullptr, false);
    if (!in || report.is_discarded() || !report.is_object()) {
      std::fprintf(stderr, "turncalctl: %s: not a report (JSON)\n", target.c_str());
      return kRefused;
    }
  } else {
    Connection c(socket);
    if (!c.ok()) {
      std::fprintf(stderr, "turncalctl: cannot reach turncald at %s: %s\n", socket.c_str(),
                   std::strerror(errno));
      return kUnreachable;
    }
    if (!c.send({{"cmd", "report"}, {"run_id", target}})) return kUnreachable;
    const json r = c.next();
    if (r.is_discarded()) {
      std::fprintf(stderr, "turncalctl: no answer from turncald\n");
      return kUnreachable;
    }
    if (!r.value("ok", false) || !r.contains("report")) {
      std::fprintf(stderr, "turncalctl: %s\n", r.value("error", std::string("refused")).c_str());
      return kRefused;
    }
    report = r["report"];
  }
  auto cal = turncal::run::calibration_json(report);
  if (!cal) {
    std::fprintf(stderr, "turncalctl: export: %s\n", cal.error().describe().c_str());
    return kRefused;
  }
  const std::string text =
      format == "json" ? cal->dump(2) + "\n" : turncal::run::calibration_toml(*cal);
  if (out_path.empty()) {
    if (std::fwrite(text.data(), 1, text.size(), stdout) != text.size() ||
        std::fflush(stdout) != 0) {
      std::fprintf(stderr, "turncalctl: export: writing standard output: %s\n",
                   std::strerror(errno));
      return kRefused;
    }
    return kOk;
  }
  std::ofstream f(out_path, std::ios::binary | std::ios::trunc);
  f << text;
  f.flush();
  if (!f) {
    std::fprintf(stderr, "turncalctl: export: cannot write %s\n", out_path.c_str());
    return kRefused;
  }
  f.close();
  if (!f) {
    std::fprintf(stderr, "turncalctl: export: cannot write %s\n", out_path.c_str());
    return kRefused;
  }
  return kOk;
}

}  // namespace

int main(int argc, char** argv) {
  std::string socket = "/run/turncal/control.sock";
  if (const char* e = std::getenv("TURNCAL_SOCKET")) socket = e;
  bool as_json = false;
  int i = 1;
  for (; i < argc && argv[i][0] == '-'; ++i) {
    const std::string a = argv[i];
    if (a == "--json")
      as_json = true;
    else if (a == "--socket" && i + 1 < argc)
      socket = argv[++i];
    else if (a == "--help" || a == "-h")
      return usage("help");
    else
      return usage(("unknown option " + a).c_str());
  }
  if (i >= argc) return usage("missing command");
  const std::string cmd = argv[i++];
  if (cmd == "replay") return replay(argc, argv, i, as_json);
  if (cmd == "plan") return plan(argc, argv, i, as_json);
  if (cmd == "check") return check(argc, argv, i, as_json);
  if (cmd == "dbc") return dbc(argc, argv, i, as_json);
  if (cmd == "decode") return decode(argc, argv, i, as_json);
  if (cmd == "export") return export_calibration(socket, argc, argv, i);
  json req = {{"cmd", cmd}};
  bool then_watch = false;
  json truth;  // turncal-sim's truth, shown beside the estimates
  if (cmd == "start") {
    for (; i < argc; ++i) {
      const std::string a = argv[i];
      if (a == "--profile" && i + 1 < argc) {
        // a file is read here, as the operator, and sent as its text: the
        // daemon opens no path a client names. A bare name that is no file
        // here names a plan in the daemon's profiles directory.
        const std::string plan = argv[++i];
        std::error_code ec;
        if (plan.find('/') != std::string::npos || std::filesystem::is_regular_file(plan, ec)) {
          std::ifstream in(plan, std::ios::binary);
          std::stringstream ss;
          ss << in.rdbuf();
          if (!in || ss.str().empty()) {
            std::fprintf(stderr, "turncalctl: cannot read the plan %s\n", plan.c_str());
            return 2;
          }
          req["plan_text"] = ss.str();
          req["plan_name"] = plan;
        } else {
          req["profile"] = plan;
        }
      } else if (a == "--watch")
        then_watch = true;
      else if (a == "--observe")
        req["observe"] = true;
      else if (a == "--unit" && i + 1 < argc)
        req["unit"] = argv[++i];
      else if (a == "--heading-offset" && i + 1 < argc) {
        char* end = nullptr;
        const double deg = std::strtod(argv[++i], &end);
        if (end == argv[i] || *end != '\0') return usage("start: --heading-offset needs degrees");
        req["heading_offset_deg"] = deg;
      } else
        return usage(("start: unknown argument " + a).c_str());
    }
  } else if (cmd == "abort") {
    if (i < argc) req["reason"] = argv[i++];
  } else if (cmd == "show") {
    if (i >= argc) return usage("show: missing RUN_ID");
    req = {{"cmd", "report"}, {"run_id", argv[i++]}};
    if (i + 1 < argc && std::string(argv[i]) == "--truth") {
      std::ifstream in(argv[i + 1]);
      truth = json::parse(in, nullptr, false);
      if (!in || truth.is_discarded() || !truth.contains("errors")) {
        std::fprintf(stderr, "turncalctl: %s: not a turncal-sim truth file\n", argv[i + 1]);
        return kUsage;
      }
      i += 2;
    }
    if (i < argc) return usage(("show: unknown argument " + std::string(argv[i])).c_str());
  } else if (cmd == "history") {
    if (i >= argc) return usage("history: missing the unit (INS identity)");
    req = {{"cmd", "history"}, {"unit", argv[i++]}};
    if (i < argc) return usage(("history: unknown argument " + std::string(argv[i])).c_str());
  } else if (cmd != "status" && cmd != "watch" && cmd != "reports") {
    return usage(("unknown command " + cmd).c_str());
  }
  Connection c(socket);
  if (!c.ok()) {
    std::fprintf(stderr, "turncalctl: cannot reach turncald at %s: %s\n", socket.c_str(),
                 std::strerror(errno));
    return kUnreachable;
  }
  if (cmd == "watch") return watch(c, as_json);
  if (!c.send(req)) return kUnreachable;
  const json r = c.next();
  if (r.is_discarded()) {
    std::fprintf(stderr, "turncalctl: no answer from turncald\n");
    return kUnreachable;
  }
  if (!r.value("ok", false)) {
    if (as_json)
      std::printf("%s\n", r.dump().c_str());
    else
      std::fprintf(stderr, "turncalctl: %s\n", r.value("error", std::string("refused")).c_str());
    return kRefused;
  }
  if (as_json) {
    std::printf("%s\n", (cmd == "show"      ? r["report"]
                         : cmd == "history" ? r["history"]
                                            : r)
                            .dump(2)
                            .c_str());
  } else if (cmd == "status") {
    std::printf("%s%s\n", progress(r).c_str(),
                r.contains("reason") ? ("\n" + r["reason"].get<std::string>()).c_str() : "");
  } else if (cmd == "start") {
    std::printf("run %s started; log %s\n", r["run_id"].get<std::string>().c_str(),
                r["log"].get<std::string>().c_str());
  } else if (cmd == "abort") {
    std::printf("run %s: abort requested\n", r["run_id"].get<std::string>().c_str());
  } else if (cmd == "reports") {
    for (const auto& e : r["reports"])
      std::printf("%s  %-12s %-4s %s\n", e["run_id"].get<std::string>().c_str(),
                  e["status"].get<std::string>().c_str(), e["pass"].get<bool>() ? "pass" : "fail",
                  e.value("unit", json()).is_string() ? e["unit"].get<std::string>().c_str() : "");
  } else if (cmd == "history") {
    std::printf("%s", r["text"].get<std::string>().c_str());
  } else if (cmd == "show") {
    std::printf("%s", truth.is_null() ? r["text"].get<std::string>().c_str()
                                      : turncal::run::report_text(r["report"], &truth).c_str());
  }
  if (then_watch) {
    Connection w(socket);
    if (!w.ok()) return kUnreachable;
    return watch(w, as_json);
  }
  return kOk;
}
