// turncald on vcan with turncal-sim as the stand: the short plan, its
// configuration, and the ways a test drives them (turncalctl, raw control
// requests), shared by the daemon's hil tests.
#pragma once

#include <doctest/doctest.h>

#include <linux/can.h>
#include <net/if.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "hil.hpp"
#include "process.hpp"
#include "turncal/build_paths.hpp"
#include "turncal/can/candump.hpp"

namespace hil::stand {

using namespace std::chrono_literals;

inline const std::string kSim = turncal::build::sim_bin;
inline const std::string kDaemon = turncal::build::daemon_bin;
inline const std::string kCtl = turncal::build::ctl_bin;
inline const std::string kSrc = turncal::build::source_dir;
// The stand at 4x with its fast streams at 25 Hz (the ICD: velocity 100 Hz,
// encoder 200 Hz). At the ICD's rates and 4x, "stale after 10 periods" is
// 12 ms of real time, shorter than the scheduling slack of a user-mode Linux
// guest running the stand, the daemon and the tests on one virtual CPU.
constexpr int kSpeed = 4;
constexpr const char* kRates = "25:25";

inline std::string slurp(const hil::fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// A short plan (20 s alignment, +180 deg at `turn_s`, 53 s of hold after
/// the turn, 120 s at most) in `dir`,
/// as `name`. The turn's rate limit is 30 deg/s (7 s of stand time, 1.75 s
/// of real time at 4x); a test that acts while the table turns gives itself
/// a slower one, so that a guest slow to answer does not find the turn over.
/// The plan's whole length, s: hold 2 as long as the reference's (turn at
/// 60 s, 30 deg/s, 7 s of turn, 120 s in all: 53 s), not longer; a plan
/// that turns earlier ends earlier, and the tier spends less of its time
/// in holds that check nothing more.
inline int plan_duration_s(int turn_s = 60, int turn_rate_dps = 30) {
  REQUIRE(turn_rate_dps > 0);
  const int turn_time_s = 180 / turn_rate_dps + 1;  // the ramps: 1 s at 30 deg/s^2
  return std::min(120, turn_s + turn_time_s + 53);
}

inline void write_plan(const hil::fs::path& dir, const std::string& name, int turn_s = 60,
                       int turn_rate_dps = 30) {
  std::ifstream in(kSrc + "/config/profiles/tactical.toml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string plan = ss.str();
  auto set = [&](const std::string& key, const std::string& value) {
    const auto at = plan.find("\n" + key + " = ");
    REQUIRE(at != std::string::npos);
    const auto end = plan.find('\n', at + 1);
    plan.replace(at + 1, end - at - 1, key + " = " + value);
  };
  set("duration_s", std::to_string(plan_duration_s(turn_s, turn_rate_dps)));
  set("align_s", "20");
  set("start_s", std::to_string(turn_s));
  set("max_rate_dps", std::to_string(turn_rate_dps));
  std::ofstream(dir / name) << plan;
}

/// The turn rate for a test that acts during the turn: 180 deg at 5 deg/s,
/// 36 s of stand time, 9 s of real time at 4x (at 10 deg/s, a SIGTERM sent
/// as the turn was seen once reached the daemon in hold 2).
constexpr int kSlowTurnDps = 5;

/// The short plan as short.toml, and a daemon configuration for it, in `dir`.
/// `dbc` (under the source tree) and `extra` (further sections) describe
/// another stand.
inline void write_stand(const hil::fs::path& dir, const std::string& iface, bool observe = false,
                        int turn_s = 60, int turn_rate_dps = 30,
                        const std::string& dbc = "config/reference-stand.dbc",
                        const std::string& extra = "") {
  write_plan(dir, "short.toml", turn_s, turn_rate_dps);
  std::ofstream(dir / "turncal.toml")
      << "[can]\nins_interface = \"" << iface << "\"\ntable_interface = \"" << iface
      << "\"\ndbc = [\"" << kSrc << "/" << dbc << "\"]\n"
      << "[stand]\ntime_scale = " << kSpeed
      << "\n"
      // the host's scheduling latency (real ms): the guest shares one
      // virtual CPU between the stand, the daemon and the test, on a CI
      // host that may itself be shared; 250 ms of it were seen
      << "[daemon]\nstale_floor_ms = 250\nstate_directory = \"" << (dir / "state").string()
      << "\"\nsocket = \"" << (dir / "control.sock").string()
      << "\"\nprofile = \"short.toml\"\nobserve = " << (observe ? "true" : "false") << "\n"
      << extra;
}

/// turncalctl with these arguments; its exit status, its stdout in `out`.
/// The time allowed is for a process start in a guest whose one CPU the
/// stand, the daemon and the test share; one that takes over 3 s says so.
inline int ctl(const hil::fs::path& dir, std::vector<std::string> args,
               const std::string& out = "ctl.out", std::chrono::milliseconds timeout = 30000ms) {
  args.insert(args.begin(), {kCtl, "--socket", (dir / "control.sock").string()});
  std::string what;
  bool long_by_design = false;  // a watch lasts the run; a replay runs a filter
  for (const auto& a : args) {
    what += a + " ";
    long_by_design = long_by_design || a == "watch" || a == "--watch" || a == "replay";
  }
  const auto t0 = std::chrono::steady_clock::now();
  hil::Child c(args, dir, dir / out);
  const int rc = c.wait(timeout);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - t0)
          .count();
  // a slow or stuck turncalctl says where it was and what it had printed
  if (rc < 0)
    MESSAGE(what << "did not end in " << ms << " ms; it was in " << c.proc_state()
                 << "; its stdout: " << slurp(dir / out));
  else if (rc > 128)
    MESSAGE(what << "was ended by signal " << rc - 128 << " after " << ms << " ms");
  else if (ms > 3000 && !long_by_design)
    MESSAGE(what << "took " << ms << " ms");
  return rc;
}

/// A connection to the control socket, whose reads give up after 10 s (a
/// reply cut short leaves no test waiting for ever).
inline int connect_control(const hil::fs::path& sock) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::strcpy(a.sun_path, sock.c_str());
  REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  const timeval limit{10, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &limit, sizeof limit);
  return fd;
}

/// A shell command run when it goes out of scope: a test's mounts and
/// devices undone however the test ends.
struct AtExit {
  std::string cmd;
  explicit AtExit(std::string c) : cmd(std::move(c)) {}
  AtExit(const AtExit&) = delete;
  AtExit& operator=(const AtExit&) = delete;
  ~AtExit() { (void)!std::system(cmd.c_str()); }
};

/// Sends raw bytes to the control socket; the first reply line.
inline std::string raw_request(const hil::fs::path& sock, const std::string& bytes) {
  const int fd = connect_control(sock);
  (void)!::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
  std::string out;
  char c;
  while (::recv(fd, &c, 1, 0) == 1 && c != '\n') out += c;
  ::close(fd);
  return out;
}

/// An abort sent at once on the control socket, its reply: what a case that
/// must act within a turn uses (turncalctl's own abort is tested where its
/// start-up time does not matter).
inline std::string abort_now(const hil::fs::path& dir, const std::string& reason) {
  const nlohmann::json req = {{"cmd", "abort"}, {"reason", reason}};
  return raw_request(dir / "control.sock", req.dump() + "\n");
}

/// Polls the daemon's status until its phase is `phase`: raw requests on
/// the control socket every 20 ms (no turncalctl started each time: in a
/// user-mode Linux guest a process start can take longer than a turn).
/// The last status a wait_phase read: what a failed wait shows.
inline std::string& last_status() {
  static std::string s;
  return s;
}

/// Waits until the daemon's run is in `phase`; false on the timeout, or at
/// once when the run ended first (last_status() says how).
inline bool wait_phase(const hil::fs::path& dir, const std::string& phase,
                       std::chrono::milliseconds timeout) {
  const std::string want = "\"phase\":\"" + phase + "\"";
  for (auto end = std::chrono::steady_clock::now() + timeout;
       std::chrono::steady_clock::now() < end; std::this_thread::sleep_for(20ms)) {
    last_status() = raw_request(dir / "control.sock", "{\"cmd\":\"status\"}\n");
    if (last_status().find(want) != std::string::npos) return true;
    for (const char* ended :
         {"\"phase\":\"done\"", "\"phase\":\"failed\"", "\"phase\":\"aborted\""})
      if (last_status().find(ended) != std::string::npos) return false;
  }
  return false;
}

/// Waits until the stand is on the bus: a frame on `iface` (the stand sends
/// from its start; the daemon is not yet started, so the frame is the
/// stand's). A daemon's run started before the stand is up would fail on a
/// table not heard.
inline bool wait_bus(const std::string& iface, std::chrono::milliseconds timeout) {
  const int fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  REQUIRE(fd >= 0);
  sockaddr_can a{};
  a.can_family = AF_CAN;
  a.can_ifindex = static_cast<int>(::if_nametoindex(iface.c_str()));
  REQUIRE(a.can_ifindex > 0);
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  const timeval step{0, 100000};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &step, sizeof step);
  bool heard = false;
  can_frame f{};
  for (auto end = std::chrono::steady_clock::now() + timeout;
       !heard && std::chrono::steady_clock::now() < end;)
    heard = ::read(fd, &f, sizeof f) == static_cast<ssize_t>(sizeof f);
  ::close(fd);
  return heard;
}

/// The virtual stand for the short plan; `extra` arguments after the
/// common ones (faults, --state-out).
inline hil::Child start_sim(const hil::fs::path& dir, const std::string& seed = "3",
                            const std::vector<std::string>& extra = {}) {
  std::vector<std::string> args = {kSim, "--config", (dir / "turncal.toml").string(), "--profile",
                                   (dir / "short.toml").string(), "--speed", std::to_string(kSpeed),
                                   "--rates", kRates, "--seed", seed, "--truth", "truth.json",
                                   // the ICD's 500 ms of host silence before
                                   // the table stops itself, of real time:
                                   // at 4x, 2 s of the stand's (0.5 s of it
                                   // would leave the daemon 125 ms, which a
                                   // guest's stall takes); `extra` may say
                                   // otherwise
                                   "--table-heartbeat-timeout", std::to_string(0.5 * kSpeed)};
  args.insert(args.end(), extra.begin(), extra.end());
  hil::Child sim(args, dir);
  // the INS's interface, as write_stand wrote it
  const std::string conf = slurp(dir / "turncal.toml");
  const auto at = conf.find("ins_interface = \"") + 17;
  REQUIRE_MESSAGE(wait_bus(conf.substr(at, conf.find('"', at) - at), 10000ms),
                  "the stand sent nothing within 10 s");
  return sim;
}

/// A Unix socket of `type` bound at `path` (a stream one listening), close
/// on exec.
inline int unix_socket_at(const hil::fs::path& path, int type) {
  const int fd = ::socket(AF_UNIX, type | SOCK_CLOEXEC, 0);
  REQUIRE(fd >= 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  REQUIRE(path.string().size() < sizeof a.sun_path);
  std::memcpy(a.sun_path, path.c_str(), path.string().size());
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  if (type == SOCK_STREAM) REQUIRE(::listen(fd, 16) == 0);
  return fd;
}

inline bool wait_for(const hil::fs::path& p, std::chrono::milliseconds t) {
  for (auto end = std::chrono::steady_clock::now() + t; std::chrono::steady_clock::now() < end;
       std::this_thread::sleep_for(20ms))
    if (hil::fs::exists(p)) return true;
  return false;
}

/// The records of a candump log, read to its end; a damaged record fails.
inline std::uint64_t log_records(const hil::fs::path& log) {
  auto reader = turncal::can::LogReader::open(log.string());
  REQUIRE(reader.ok());
  std::uint64_t n = 0;
  for (;;) {
    auto rec = reader->next();
    if (!rec.ok()) FAIL("the log is damaged: " << rec.error().describe());
    if (!rec->has_value()) break;
    ++n;
  }
  return n;
}

/// Copies these files into the build's hil-artifacts/, each name prefixed,
/// for a look after a failure.
inline void keep_artifacts(const std::string& prefix, const std::vector<hil::fs::path>& files) {
  const hil::fs::path keep = hil::fs::path(turncal::build::binary_dir) / "hil-artifacts";
  std::error_code ec;
  hil::fs::create_directories(keep, ec);
  for (const hil::fs::path& f : files)
    hil::fs::copy_file(f, keep / (prefix + f.filename().string()),
                       hil::fs::copy_options::overwrite_existing, ec);
}

/// A done run's estimates against the stand's truth (truth.json), as the
/// scenario tier judges them, a fixed seed: each combination the run
/// determined, and each parameter it determined, within 4 of its sigmas (a
/// parameter determined only partly or not at all has a sigma near its
/// prior's, and the check would prove little). Returns how many
/// parameters were judged.
inline int check_against_truth(const nlohmann::json& r, const nlohmann::json& truth) {
  REQUIRE(r.contains("estimates"));
  std::ostringstream judged;
  for (const auto& [name, t] : truth.at("errors").items())
    if (r.at("estimates").contains(name) &&
        r.at("estimates").at(name).at("determined") == "determined") {
      const auto& e = r.at("estimates").at(name);
      judged << name << " " << e.at("value").get<double>() << " +- " << e.at("sigma").get<double>()
             << " (truth " << t.get<double>() << ", z "
             << (e.at("value").get<double>() - t.get<double>()) / e.at("sigma").get<double>()
             << "); ";
    }
  MESSAGE("determined: " << judged.str());
  // when an estimate is off, the clocks that put the encoder on the INS
  // timeline are the first suspects
  CAPTURE(r.value("health", nlohmann::json()).dump());
  CAPTURE(r.value("turns_achieved", nlohmann::json()).dump());
  for (const auto& c : r.value("combinations", nlohmann::json::array())) {
    CAPTURE(c.dump());
    double tv = 0;
    for (const auto& [name, k] : c.at("coefficients").items())
      tv += k.get<double>() * truth.at("errors").at(name).get<double>();
    CHECK(std::abs(c.at("value").get<double>() - tv) <= 4 * c.at("sigma").get<double>());
  }
  int params = 0;
  for (const auto& [name, t] : truth.at("errors").items()) {
    if (!r.at("estimates").contains(name)) continue;
    const auto& e = r.at("estimates").at(name);
    if (e.at("determined") != "determined") continue;
    CAPTURE(name);
    CHECK(std::abs(e.at("value").get<double>() - t.get<double>()) <=
          4 * e.at("sigma").get<double>());
    ++params;
  }
  return params;
}

}  // namespace hil::stand
