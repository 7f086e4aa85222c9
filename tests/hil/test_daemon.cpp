// turncald on a real SocketCAN stack with turncal-sim as the stand,
// driven through turncalctl: a short experiment end to end, an abort during
// the turn, malformed and oversized control requests.
#include <doctest/doctest.h>

#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>

#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "daemon_stand.hpp"
#include "hil.hpp"
#include "process.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/run/sha256.hpp"

using namespace turncal;
using hil::Child;
using namespace std::chrono_literals;
using namespace hil::stand;

constexpr int kHeartbeatLostFault = 1;  // can-icd.md: TBL_Status Fault

TEST_SUITE("daemon") {
  TEST_CASE("turncald runs a short experiment through turncalctl; an observer replays its log") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    Child sim = start_sim(dir.path);
    Child daemon({kDaemon, "--config", (dir.path / "turncal.toml").string()}, dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));

    // bad requests are answered with an error and harm nothing
    CHECK(raw_request(dir.path / "control.sock", "not json\n").find("malformed request") !=
          std::string::npos);
    CHECK(raw_request(dir.path / "control.sock", "{\"cmd\": 5}\n").find("malformed") !=
          std::string::npos);
    CHECK(
        raw_request(dir.path / "control.sock", std::string(70000, 'x')).find("request too large") !=
        std::string::npos);
    CHECK(raw_request(dir.path / "control.sock", "{\"cmd\":\"fly\"}\n").find("unknown command") !=
          std::string::npos);

    CHECK(ctl(dir.path, {"start", "--unit", "bad/unit"}) == 1);  // refused: not an identity
    REQUIRE(ctl(dir.path, {"start", "--unit", "SN-0042", "--watch"}, "watch.out", 120000ms) == 0);
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list.json") == 0);
    const auto reports = nlohmann::json::parse(slurp(dir.path / "list.json"));
    REQUIRE(reports["reports"].size() == 1);
    const std::string id = reports["reports"][0]["run_id"];
    REQUIRE(ctl(dir.path, {"--json", "show", id}, "report.json") == 0);
    const auto r = nlohmann::json::parse(slurp(dir.path / "report.json"));
    CHECK(r["status"] == "done");
    CHECK(r["unit"] == "SN-0042");
    REQUIRE(r["estimates"].size() == 22);  // 18, df_eff_1/2, df_obs_1/2
    // the unit's history holds the run
    REQUIRE(ctl(dir.path, {"--json", "history", "SN-0042"}, "history.json") == 0);
    const auto hist = nlohmann::json::parse(slurp(dir.path / "history.json"));
    REQUIRE(hist["runs"].size() == 1);
    CHECK(hist["runs"][0]["run_id"] == id);
    CHECK(hist["parameters"]["nu0_1"]["mean"] == r["estimates"]["nu0_1"]["value"]);
    // the HTML report beside it, with its plots (rendered by chromium in the html tier)
    const std::string html = slurp(dir.path / "state" / (id + ".report.html"));
    CHECK(html.find("<svg") != std::string::npos);
    CHECK(html.find("Normalized innovations") != std::string::npos);
    // the log in the state directory is the one the report names, intact
    const hil::fs::path log = dir.path / "state" / r["log"]["file"].get<std::string>();
    CHECK(slurp(log).size() > 100000);
    // the run's report, log and truth are kept for a look after a failure
    keep_artifacts("daemon-run-",
                   {dir.path / "state" / (id + ".report.json"), log, dir.path / "truth.json"});
    MESSAGE("clocks: ins rms " << r["health"]["ins_clock_rms_s"] << " s, table rms "
                               << r["health"]["table_clock_rms_s"] << " s, outliers "
                               << r["health"]["clock_outliers"]);
    // against the truth: the sharp combinations and the parameters the run
    // determined within 4 sigma
    REQUIRE(!r["combinations"].empty());
    const int params =
        check_against_truth(r, nlohmann::json::parse(slurp(dir.path / "truth.json")));
    CHECK(params >= 4);  // the short plan determines nu0_1, nu0_2, r1, r2 at least

    // turncalctl replay of the log (no daemon): with the live run's settings,
    // from the report next to the log, the estimation is the live one bit for bit
    REQUIRE(ctl(dir.path,
                {"replay", log.string(), "--config", (dir.path / "turncal.toml").string(), "--json",
                 (dir.path / "replay.json").string()},
                "replay.txt", 60000ms) == 0);
    const auto live = nlohmann::json::parse(slurp(dir.path / "state" / (id + ".report.json")));
    const auto rp = nlohmann::json::parse(slurp(dir.path / "replay.json"));
    CHECK(rp["mode"] == "replay");
    CHECK(rp["replay"]["of_live_report"] == true);
    for (const char* k : {"estimates", "combinations", "two_stage", "innovations", "turns_achieved",
                          "velocity_samples", "verdict"}) {
      CAPTURE(k);
      REQUIRE(live.contains(k));
      CHECK(rp[k].dump() == live[k].dump());
    }
    CHECK(slurp(dir.path / "replay.txt").find("replay with the live run's settings") !=
          std::string::npos);

    // replies larger than the socket takes at once arrive whole: 60 reports
    // asked at once (some 2 MB) and read only then
    {
      const int fd = connect_control(dir.path / "control.sock");
      std::string reqs;
      for (int k = 0; k < 60; ++k) reqs += "{\"cmd\":\"report\",\"run_id\":\"" + id + "\"}\n";
      REQUIRE(::send(fd, reqs.data(), reqs.size(), MSG_NOSIGNAL) ==
              static_cast<ssize_t>(reqs.size()));
      std::this_thread::sleep_for(500ms);
      std::string got;
      char buf[65536];
      int lines = 0;
      while (lines < 60) {
        const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
        if (n <= 0) break;
        for (ssize_t k = 0; k < n; ++k) lines += buf[k] == '\n';
        got.append(buf, static_cast<std::size_t>(n));
      }
      ::close(fd);
      CHECK(lines == 60);
      CHECK(got.size() > 60 * 10000);
      std::istringstream in(got);
      std::string line;
      int whole = 0;
      while (std::getline(in, line)) {
        const auto j = nlohmann::json::parse(line, nullptr, false);
        whole += !j.is_discarded() && j.value("ok", false) && j["report"]["run_id"] == id;
      }
      CHECK(whole == 60);
    }

    // a second run, aborted during the turn: the table quick-stops (a plan
    // with a slower turn, so the abort is surely in it)
    write_plan(dir.path, "slow.toml", 60, kSlowTurnDps);
    REQUIRE(ctl(dir.path, {"start", "--profile", (dir.path / "slow.toml").string()}) == 0);
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    const std::string aborted = abort_now(dir.path, "aborted in the turn");
    CHECK(aborted.find("\"ok\":true") != std::string::npos);
    CHECK(ctl(dir.path, {"watch"}, "w2.out") == 1);  // the watched run ended aborted
    // turncalctl's abort with no run to abort: refused, the daemon says why
    CHECK(ctl(dir.path, {"--json", "abort"}, "abort.json") == 1);
    CHECK(slurp(dir.path / "abort.json").find("no run in progress") != std::string::npos);
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list2.json") == 0);
    const auto reports2 = nlohmann::json::parse(slurp(dir.path / "list2.json"));
    REQUIRE(reports2["reports"].size() == 2);
    const std::string id2 = reports2["reports"][1]["run_id"];
    const auto r2 = nlohmann::json::parse(slurp(dir.path / "state" / (id2 + ".report.json")));
    CHECK(r2["status"] == "aborted");
    CHECK(r2["phases"].back()["phase"] == "aborted");
    CHECK(r2["reason"] == "aborted in the turn");
    REQUIRE(r2["phases"].size() >= 2);
    CHECK(r2["phases"][r2["phases"].size() - 2]["phase"] == "turn");  // in the turn
    CHECK(r2["quick_stop"]["sent"] == true);
    CHECK(r2["quick_stop"]["acknowledged"] == true);
    // its log is kept and replays whole: hold 1 and the turn up to the abort
    CHECK(ctl(dir.path,
              {"--json", "replay", (dir.path / "state" / (id2 + ".log")).string(), "--config",
               (dir.path / "turncal.toml").string()},
              "replay2.json", 60000ms) == 0);
    const auto rp2 = nlohmann::json::parse(slurp(dir.path / "replay2.json"));
    const std::string rp2_status = rp2.value("status", std::string());
    CAPTURE(rp2_status);
    CAPTURE(rp2.contains("reason") ? rp2["reason"].dump() : std::string());
    CAPTURE(rp2.contains("phases") ? rp2["phases"].dump() : std::string());
    CAPTURE(r2["phases"].dump());
    CHECK(rp2["replay"]["damage"].is_null());
    CHECK(rp2["estimates"].size() == 22);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    sim.terminate();
    sim.wait(5000ms);

    // Observe mode: a second daemon on the other interface follows the first
    // run played back by canplayer. The estimates equal the live run's within
    // 0.2 sigma: only the receive times differ, and they enter only through
    // the clock fits that put the encoder on the INS timeline.
    hil::TempDir obs;
    write_stand(obs.path, hil::if1(), true);
    Child observer({kDaemon, "--config", (obs.path / "turncal.toml").string()}, obs.path);
    REQUIRE(wait_for(obs.path / "control.sock", 5000ms));
    REQUIRE(ctl(obs.path, {"start"}) == 0);
    Child player({"canplayer", "-I", log.string(), hil::if1() + "=" + hil::if0()}, obs.path);
    CHECK(ctl(obs.path, {"watch"}, "watch.out", 120000ms) == 0);
    CHECK(player.wait(10000ms) == 0);
    REQUIRE(ctl(obs.path, {"--json", "reports"}, "list.json") == 0);
    const auto ol = nlohmann::json::parse(slurp(obs.path / "list.json"));
    REQUIRE(ol["reports"].size() == 1);
    const auto o = nlohmann::json::parse(slurp(
        obs.path / "state" / (ol["reports"][0]["run_id"].get<std::string>() + ".report.json")));
    CHECK(o["status"] == "done");
    CHECK(o["mode"] == "observe");
    REQUIRE(o["estimates"].size() == 22);
    for (const auto& [name, e] : r["estimates"].items()) {
      CAPTURE(name);
      const double sigma = e["sigma"].get<double>();
      CHECK(std::abs(o["estimates"][name]["value"].get<double>() - e["value"].get<double>()) <=
            0.2 * sigma);
      CHECK(o["estimates"][name]["sigma"].get<double>() ==
            doctest::Approx(sigma).epsilon(0.01).scale(0));
    }
    observer.terminate();
    CHECK(observer.wait(10000ms) == 0);
  }

  TEST_CASE(
      "SIGTERM during the turn: quick stop, then a clean exit; SIGKILL: reported next start") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 30, kSlowTurnDps);
    Child sim = start_sim(dir.path, "4", {"--state-out", "stand.json"});
    const std::string config = (dir.path / "turncal.toml").string();
    {
      Child daemon({kDaemon, "--config", config}, dir.path);
      REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
      REQUIRE(ctl(dir.path, {"start"}) == 0);
      REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
      daemon.terminate();
      CHECK(daemon.wait(20000ms) == 0);
    }
    REQUIRE(ctl(dir.path, {"status"}) == 3);  // gone
    hil::fs::path first_report;
    for (const auto& e : hil::fs::directory_iterator(dir.path / "state"))
      if (e.path().string().ends_with(".report.json")) first_report = e.path();
    REQUIRE(!first_report.empty());
    const auto r = nlohmann::json::parse(slurp(first_report));
    CHECK(r["status"] == "aborted");
    CHECK(r["reason"].get<std::string>().find("SIGTERM") != std::string::npos);
    CHECK(r["quick_stop"]["sent"] == true);
    CHECK(r["quick_stop"]["acknowledged"] == true);
    // its log replays whole, to the stop
    const std::string term_log =
        (dir.path / "state" / r["log"]["file"].get<std::string>()).string();
    (void)ctl(dir.path, {"--json", "replay", term_log, "--config", config}, "replay-term.json",
              60000ms);
    const auto rp_term = nlohmann::json::parse(slurp(dir.path / "replay-term.json"));
    CHECK(rp_term["replay"]["damage"].is_null());

    // killed in the turn: the table stops itself on the lost heartbeat; the
    // next start reports the run as interrupted, and its log reads to the end
    std::string killed;
    {
      hil::fs::remove(dir.path / "control.sock");
      Child daemon({kDaemon, "--config", config}, dir.path);
      REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
      REQUIRE(ctl(dir.path, {"--json", "start"}, "start.json") == 0);
      killed = nlohmann::json::parse(slurp(dir.path / "start.json"))["run_id"];
      REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
      // the destructor of a running Child sends SIGKILL
    }
    // the table's heartbeat timeout, 0.5 s of real time (start_sim), and
    // its stop, before a daemon sends heartbeats again
    std::this_thread::sleep_for(2000ms);
    hil::fs::remove(dir.path / "control.sock");
    Child daemon({kDaemon, "--config", config}, dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list.json") == 0);
    const auto list = nlohmann::json::parse(slurp(dir.path / "list.json"));
    nlohmann::json entry;
    for (const auto& e : list["reports"])
      if (e["run_id"] == killed) entry = e;
    REQUIRE(entry.is_object());
    CHECK(entry["status"] == "interrupted");
    const auto ir = nlohmann::json::parse(slurp(dir.path / "state" / (killed + ".report.json")));
    const std::uint64_t records = log_records(dir.path / "state" / (killed + ".log"));
    CHECK(records > 1000);  // prepare, alignment, a hold and part of the turn
    CHECK(ir["log"]["lines"].get<std::uint64_t>() == records);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    sim.terminate();
    CHECK(sim.wait(10000ms) == 0);
    const auto st = nlohmann::json::parse(slurp(dir.path / "stand.json"));
    CHECK(st["table"]["state"] == 5);  // quick-stopped, by itself
    CHECK(st["table"]["fault"] == kHeartbeatLostFault);
    CHECK(st["table"]["rate_dps"] == 0.0);
  }

  TEST_CASE(
      "a killed run's log: a line cut short is cut off at the next start and the report says "
      "so; a damaged end is left and said; a second turncald on the state directory is "
      "refused") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    const hil::fs::path state = dir.path / "state";
    hil::fs::create_directories(state);
    std::string whole;
    for (int k = 0; k < 50; ++k)
      whole += "(1764979200." + std::to_string(100000 + k * 10000) + ") " + hil::if0() +
               " 123#01020304\n";
    // the kill's cut, with a byte no text has and a quote: the report keeps
    // it as printable text that can be quoted
    const std::string torn_tail = "(1764979201.000000) " + hil::if0() + " 12\x01\"";
    const std::string torn_text = "(1764979201.000000) " + hil::if0() + " 12\\x01\\x22";
    std::ofstream(state / "killed.log", std::ios::binary) << whole << torn_tail;
    // no run's logs: a link to one, and a FIFO (read, it would hold the
    // start up); each is passed over and said
    hil::fs::create_symlink(state / "killed.log", state / "alias.log");
    REQUIRE(::mkfifo((state / "pipe.log").c_str(), 0600) == 0);
    // no line's end in a line's length and more: not a kill's cut
    const std::string damaged = whole + std::string(can::kMaxLogLine + 5, '#');
    std::ofstream(state / "damaged.log", std::ios::binary) << damaged;

    const hil::fs::path config = dir.path / "turncal.toml";
    Child daemon({kDaemon, "--config", config.string()}, dir.path, {}, dir.path / "daemon.err");
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list.json") == 0);
    const auto list = nlohmann::json::parse(slurp(dir.path / "list.json"));
    int interrupted = 0;
    for (const auto& e : list["reports"]) interrupted += e["status"] == "interrupted";
    CHECK(interrupted == 2);

    // cut after its last whole line: the log is those lines, and the
    // report's digest and count are of what is kept
    CHECK(slurp(state / "killed.log") == whole);
    CHECK(log_records(state / "killed.log") == 50);
    const auto r = nlohmann::json::parse(slurp(state / "killed.report.json"));
    CHECK(r["status"] == "interrupted");
    CHECK(r["log"]["torn_bytes_cut"] == torn_tail.size());
    CHECK(r["log"]["torn_tail"] == torn_text);  // what was cut, kept in the report
    const std::string cut_said = "cut off its end: " + std::to_string(torn_tail.size()) +
                                 " bytes of a line cut short, \"" + torn_text + "\"";
    CHECK(slurp(state / "killed.report.txt").find(cut_said) != std::string::npos);
    CHECK(slurp(state / "killed.report.html")
              .find("cut off its end: " + std::to_string(torn_tail.size()) +
                    " bytes of a line cut short, &quot;" + torn_text + "&quot;") !=
          std::string::npos);
    CHECK(r["log"]["lines"] == 50);
    const auto dg = run::sha256_file((state / "killed.log").string());
    REQUIRE(dg.ok());
    CHECK(r["log"]["sha256"] == dg->sha256);
    CHECK(r["reason"].get<std::string>().find("cut short (" + std::to_string(torn_tail.size()) +
                                              " bytes, no frame)") != std::string::npos);
    // the damaged one is left byte for byte, and its report says why
    CHECK(slurp(state / "damaged.log") == damaged);
    const auto d = nlohmann::json::parse(slurp(state / "damaged.report.json"));
    CHECK(d["log"]["torn_bytes_cut"] == 0);
    CHECK_FALSE(d["log"].contains("torn_tail"));  // nothing cut, nothing to keep
    CHECK_FALSE(hil::fs::exists(state / "alias.report.json"));
    CHECK_FALSE(hil::fs::exists(state / "pipe.report.json"));
    CHECK(d["reason"].get<std::string>().find("left as it is") != std::string::npos);
    CHECK(d["reason"].get<std::string>().find("no line's end") != std::string::npos);

    // a second daemon on the same state directory (and socket) is refused
    // before it touches a file: a reservation and a torn log without a
    // report, which a start releases and cuts, stay as they are; the first
    // daemon goes on answering
    const std::string reserve = "space held for a report";
    std::ofstream(state / ".live.reserve", std::ios::binary) << reserve;
    std::ofstream(state / "live.log", std::ios::binary) << whole << torn_tail;
    Child second({kDaemon, "--config", config.string()}, dir.path, {}, dir.path / "second.err");
    CHECK(second.wait(10000ms) == 1);
    const std::string refused = slurp(dir.path / "second.err");
    CAPTURE(refused);
    CHECK(refused.find("held by another process") != std::string::npos);
    CHECK(slurp(state / ".live.reserve") == reserve);
    CHECK(slurp(state / "live.log") == whole + torn_tail);
    CHECK_FALSE(hil::fs::exists(state / "live.report.json"));
    CHECK(ctl(dir.path, {"status"}) == 0);
    // nor is one with a state directory of its own on the same socket: it
    // would move its socket over the first's and take the control
    std::string other = slurp(config);
    const std::string state_line = "state_directory = \"" + state.string() + "\"";
    REQUIRE(other.find(state_line) != std::string::npos);
    other.replace(other.find(state_line), state_line.size(),
                  "state_directory = \"" + (dir.path / "other-state").string() + "\"");
    std::ofstream(dir.path / "other.toml") << other;
    // a daemon of `toml` is refused, says so, and leaves `sock` as it was
    const auto refused_by = [&](const std::string& toml, const hil::fs::path& sock) {
      struct stat before {};
      REQUIRE(::stat(sock.c_str(), &before) == 0);
      const hil::fs::path err = dir.path / (toml + ".err");
      Child refusing({kDaemon, "--config", (dir.path / toml).string()}, dir.path, {}, err);
      CHECK(refusing.wait(10000ms) == 1);
      struct stat after {};
      REQUIRE(::stat(sock.c_str(), &after) == 0);
      CHECK(after.st_ino == before.st_ino);  // not moved over
      return slurp(err);
    };
    const std::string third_said = refused_by("other.toml", dir.path / "control.sock");
    CAPTURE(third_said);
    CHECK(third_said.find("the control socket " + (dir.path / "control.sock").string() +
                          " is another process's") != std::string::npos);
    CHECK(ctl(dir.path, {"status"}) == 0);
    // nor over a socket something listens on with no lock beside it (as
    // systemd's socket unit does, for a daemon it starts on demand)
    const hil::fs::path held_sock = dir.path / "held.sock";
    const int listener = unix_socket_at(held_sock, SOCK_STREAM);
    const std::string sock_line = "socket = \"" + (dir.path / "control.sock").string() + "\"";
    REQUIRE(other.find(sock_line) != std::string::npos);
    // `toml`: the other configuration with its socket at `sock`
    const auto socket_at = [&](const std::string& toml, const hil::fs::path& sock) {
      std::string text = other;
      text.replace(text.find(sock_line), sock_line.size(), "socket = \"" + sock.string() + "\"");
      std::ofstream(dir.path / toml) << text;
    };
    socket_at("held.toml", held_sock);
    const std::string fourth_said = refused_by("held.toml", held_sock);
    CAPTURE(fourth_said);
    CHECK(fourth_said.find("the control socket " + held_sock.string() +
                           " has a listener already") != std::string::npos);
    (void)::close(listener);
    // nor over a socket whose connect says neither "no one listens" nor
    // "someone does" (here a datagram socket: EPROTOTYPE): it cannot tell
    const hil::fs::path dgram_sock = dir.path / "dgram.sock";
    const int dgram = unix_socket_at(dgram_sock, SOCK_DGRAM);
    socket_at("dgram.toml", dgram_sock);
    const std::string fifth_said = refused_by("dgram.toml", dgram_sock);
    CAPTURE(fifth_said);
    CHECK(fifth_said.find("cannot tell whether something listens on the control socket " +
                          dgram_sock.string() + ": " + std::strerror(EPROTOTYPE)) !=
          std::string::npos);
    (void)::close(dgram);
    // nor over a file that is no socket (a configuration that names one by
    // mistake): it would be replaced, whatever it held
    const hil::fs::path not_sock = dir.path / "notes.txt";
    std::ofstream(not_sock) << "kept";
    socket_at("file.toml", not_sock);
    const std::string sixth_said = refused_by("file.toml", not_sock);
    CAPTURE(sixth_said);
    CHECK(sixth_said.find("the control socket " + not_sock.string() +
                          " is a file that is no socket; not replaced") != std::string::npos);
    CHECK(slurp(not_sock) == "kept");
    CHECK_FALSE(hil::fs::exists(not_sock.string() + ".lock"));  // refused before a lock is made
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    // the daemon's log says both
    const std::string said = slurp(dir.path / "daemon.err");
    CAPTURE(said);
    CHECK(said.find("run killed was interrupted") != std::string::npos);
    CHECK(said.find("cut the last " + std::to_string(torn_tail.size()) + " bytes of its log") !=
          std::string::npos);
    CHECK(said.find("damaged.log: its last") != std::string::npos);
    CHECK(said.find("alias.log: a link, no run's log; left as it is") != std::string::npos);
    CHECK(said.find("pipe.log: not a regular file, no run's log; left as it is") !=
          std::string::npos);
    CHECK(said.find(": \"" + torn_text + "\"") != std::string::npos);
  }

  TEST_CASE(
      "socket-activated, turncald serves the socket systemd passes it, as it is: no lock, no "
      "probe, no rename") {
    // what systemd does for turncald.socket: the listening socket at fd 3,
    // LISTEN_FDS=1 and LISTEN_PID the daemon's own pid (a shell sets them
    // and execs, keeping its pid). A daemon that took this for a hand start
    // would find its own socket listened on and refuse
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    const hil::fs::path sock = dir.path / "control.sock";
    // inherited by the daemon: above fd 3, so the shell can move it there
    const int made = unix_socket_at(sock, SOCK_STREAM);
    const int listener = ::fcntl(made, F_DUPFD, 4);  // without close-on-exec
    (void)::close(made);
    REQUIRE(listener >= 4);
    struct stat before {};
    REQUIRE(::stat(sock.c_str(), &before) == 0);
    const std::string fd = std::to_string(listener);
    Child daemon(
        {"bash", "-c",  // bash: a redirection of any fd number
         "LISTEN_PID=$$ LISTEN_FDS=1 exec \"$0\" --config \"$1\" 3<&" + fd + " " + fd + "<&-",
         kDaemon, (dir.path / "turncal.toml").string()},
        dir.path, {}, dir.path / "daemon.err");
    hil::explain_files().push_back(dir.path / "daemon.err");
    (void)::close(listener);  // the daemon's now
    CHECK(ctl(dir.path, {"--json", "status"}, "status.json") == 0);
    CHECK(nlohmann::json::parse(slurp(dir.path / "status.json"))["phase"] == "idle");
    struct stat after {};
    REQUIRE(::stat(sock.c_str(), &after) == 0);
    CHECK(after.st_ino == before.st_ino);  // served as passed, not bound anew
    CHECK_FALSE(hil::fs::exists(dir.path / "control.sock.lock"));
    CHECK_FALSE(hil::fs::exists(dir.path / "control.sock.new"));
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);

    // and one that binds its own by a bare name binds it in its working
    // directory (there is no directory to make for it), not its
    // configuration's folder
    std::string bare = slurp(dir.path / "turncal.toml");
    const std::string sock_line = "socket = \"" + sock.string() + "\"";
    REQUIRE(bare.find(sock_line) != std::string::npos);
    bare.replace(bare.find(sock_line), sock_line.size(), "socket = \"bare.sock\"");
    std::ofstream(dir.path / "bare.toml") << bare;
    const hil::fs::path work = dir.path / "work";
    hil::fs::create_directories(work);
    Child by_name({kDaemon, "--config", (dir.path / "bare.toml").string()}, work, {},
                  dir.path / "bare.err");
    hil::explain_files().push_back(dir.path / "bare.err");
    REQUIRE(wait_for(work / "bare.sock", 5000ms));
    CHECK_FALSE(hil::fs::exists(dir.path / "bare.sock"));
    Child asked({kCtl, "--socket", (work / "bare.sock").string(), "status"}, dir.path,
                dir.path / "bare.out");
    CHECK(asked.wait(30000ms) == 0);
    by_name.terminate();
    CHECK(by_name.wait(10000ms) == 0);
  }
  TEST_CASE(
      "an INS with another layout through turncald: North-West-Down in one frame, "
      "timed by its time frame") {
    // config/stands/navigation-ins's INS: cm/s, West, one frame, timed by
    // the INS_TimeStamp frame sent just before it. (Timing by the kernel's
    // receive stamps is tested on logs: in the guest the stand's frames
    // leave up to 0.2 s late when the host is loaded, and their stamps with
    // them.)
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 60, 30,
                "config/stands/navigation-ins/navigation-ins.dbc",
                "[ins]\ntime = \"time-frame\"\nvelocity_rate_hz = 25\neast_sign = -1\n"
                "time_frame_max_age_ms = 1000\n"
                "[can.roles]\nins_vel_east = \"INS_NavVel.VelW\"\n"
                "ins_vel_north = \"INS_NavVel.VelN\"\nins_time = \"INS_TimeStamp.TimeMs\"\n"
                "ins_status_time_tag = \"\"\n");
    Child sim = start_sim(dir.path);
    Child daemon({kDaemon, "--config", (dir.path / "turncal.toml").string()}, dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    REQUIRE(ctl(dir.path, {"start", "--watch"}, "watch.out", 120000ms) == 0);
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list.json") == 0);
    const auto reports = nlohmann::json::parse(slurp(dir.path / "list.json"));
    REQUIRE(reports["reports"].size() == 1);
    const std::string id = reports["reports"][0]["run_id"];
    REQUIRE(ctl(dir.path, {"--json", "show", id}, "report.json") == 0);
    const auto r = nlohmann::json::parse(slurp(dir.path / "report.json"));
    CHECK(r["status"] == "done");
    CAPTURE(r["health"].dump());
    // every velocity frame a sample, each stamped by its time frame
    const double frames = r["health"]["ins_velocity"]["frames"].get<double>();
    CHECK(frames > 100 * 25);
    CHECK(r["health"]["velocity_untimed"] == 0);
    // the run determines what the short plan determines, within 4 sigma of
    // the truth (a fixed seed, as in the first daemon test)
    CHECK(check_against_truth(r, nlohmann::json::parse(slurp(dir.path / "truth.json"))) >= 4);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    sim.terminate();
    sim.wait(5000ms);
  }
}
