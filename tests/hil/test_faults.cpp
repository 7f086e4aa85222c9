// Faults through the real daemon: turncald on vcan, turncal-sim as the
// stand injecting the fault, and each test checks the table's own state
// (the stand's --state-out), the daemon's log (its stderr) and the report.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

#include "daemon_stand.hpp"
#include "turncal/can/candump.hpp"

using namespace turncal;
using namespace hil::stand;
using hil::Child;
using nlohmann::json;

namespace {

/// The CPU time a process has had so far (user and system, /proc/PID/stat).
double cpu_seconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(in, line) || line.rfind(')') == std::string::npos) return NAN;
  // the fields after the command's closing parenthesis: state is the 3rd
  // field of the line, utime and stime the 14th and 15th
  std::istringstream rest(line.substr(line.rfind(')') + 2));
  std::string field;
  double ticks = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i)
    if (i >= 14) ticks += std::stod(field);
  return ticks / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

/// turncald with its stderr (the log outside systemd) in dir/daemon.err.
Child start_daemon(const hil::fs::path& dir) {
  hil::fs::remove(dir / "control.sock");
  if (std::ranges::find(hil::explain_files(), dir / "daemon.err") == hil::explain_files().end())
    hil::explain_files().push_back(dir / "daemon.err");
  return Child({"sh", "-c", "exec \"$0\" --config \"$1\" 2>>daemon.err", kDaemon,
                (dir / "turncal.toml").string()},
               dir);
}

/// The one report of the state directory whose run id is `id`; when there
/// is none, the daemon's log says why.
json report_of(const hil::fs::path& dir, const std::string& id) {
  const hil::fs::path p = dir / "state" / (id + ".report.json");
  REQUIRE_MESSAGE(hil::fs::exists(p), "no report; the daemon's log:\n"
                                          << slurp(dir / "daemon.err"));
  return json::parse(slurp(p));
}

/// The stand's own account, after it was stopped.
json stand_state(Child& sim, const hil::fs::path& dir) {
  sim.terminate();
  CHECK(sim.wait(10000ms) == 0);
  return json::parse(slurp(dir / "stand.json"));
}

std::string start_run(const hil::fs::path& dir) {
  REQUIRE(ctl(dir, {"--json", "start"}, "start.json") == 0);
  return json::parse(slurp(dir / "start.json"))["run_id"];
}

constexpr int kQuickStopped = 5;  // can-icd.md: TBL_Status State
constexpr int kTableFault = 4;    // the drive's own fault state

/// The run's log replayed with the daemon's config: it reads to its end
/// (no damage), and holds every frame the daemon received and every frame
/// of ours the bus confirmed. The replay's report.
json replay_of_log(const hil::fs::path& dir, const std::string& id, const json& report) {
  const hil::fs::path log = dir / "state" / (id + ".log");
  (void)ctl(dir, {"--json", "replay", log.string(), "--config", (dir / "turncal.toml").string()},
            "replay.json", 60000ms);
  const json rp = json::parse(slurp(dir / "replay.json"));
  CHECK(rp.at("replay").at("damage").is_null());
  const json& can = report["can"][hil::if0()];
  CHECK(log_records(log) ==
        can["rx_frames"].get<std::uint64_t>() + can["tx_confirmed"].get<std::uint64_t>());
  return rp;
}

}  // namespace

TEST_SUITE("faults") {
  TEST_CASE(
      "hostile control requests and 300 idle clients during the turn: error replies, the abort "
      "gets through") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 60, kSlowTurnDps);
    // a report file of a wrong shape, as a crash loop would have read it
    hil::fs::create_directories(dir.path / "state");
    std::ofstream(dir.path / "state" / "20200101T000000Z.report.json")
        << R"({"run_id":"20200101T000000Z","status":"done","unit":"SN-9",)"
        << R"("estimates":{"nu0_1":{"value":"x","sigma":1,"prior_sigma":1}}})";
    Child sim = start_sim(dir.path, "5", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const hil::fs::path sock = dir.path / "control.sock";
    // the bad report: listed as unreadable, its history empty, no crash
    REQUIRE(ctl(dir.path, {"--json", "reports"}, "list.json") == 0);
    const json list = json::parse(slurp(dir.path / "list.json"));
    REQUIRE(list["reports"].size() == 1);
    CHECK(list["reports"][0]["status"] == "unreadable");
    CHECK(list["reports"][0]["reason"] == "estimates.nu0_1.value: expected a number");
    CHECK(ctl(dir.path, {"show", "20200101T000000Z"}) == 1);
    CHECK(raw_request(dir.path / "control.sock",
                      "{\"cmd\":\"report\",\"run_id\":\"20200101T000000Z\"}\n")
              .find("unreadable: estimates.nu0_1.value: expected a number") != std::string::npos);
    REQUIRE(ctl(dir.path, {"--json", "history", "SN-9"}, "h.json") == 0);
    CHECK(json::parse(slurp(dir.path / "h.json"))["history"]["runs"].empty());

    const std::string id = start_run(dir.path);
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    // each of these killed turncald before
    CHECK(raw_request(sock, "{\"cmd\":\"abort\",\"reason\":1}\n").find("expected a string") !=
          std::string::npos);
    CHECK(raw_request(sock, "{\"cmd\":\"start\",\"observe\":\"x\"}\n").find("expected true") !=
          std::string::npos);
    CHECK(raw_request(sock, "{\"cmd\":\"report\",\"run_id\":1}\n").find("expected a string") !=
          std::string::npos);
    // the daemon opens no path a client names
    CHECK(raw_request(sock, "{\"cmd\":\"start\",\"profile\":\"../../../etc/passwd\"}\n")
              .find("expected the name of a plan") != std::string::npos);
    // 300 clients that connect and never ask, against max_clients = 16:
    // those past the 16th, while the 16 are new (under a second, not yet
    // heard from), are refused, told why; then each new one closes the one
    // idle longest (told why), so the operator's status and abort get
    // through, in the turn
    std::vector<int> held;
    for (int k = 0; k < 300; ++k) held.push_back(connect_control(sock));
    std::this_thread::sleep_for(1200ms);  // accepted, and no longer new
    // refused in the flood: some of those that came while the 16 were new
    // (how many, the guest's speed decides), each told why
    int refused = 0;
    for (std::size_t k = 16; k < held.size(); ++k) {
      char buf[512];
      const ssize_t n = ::recv(held[k], buf, sizeof buf, MSG_DONTWAIT);
      if (n > 0 && std::string(buf, static_cast<std::size_t>(n))
                           .find("too many control connections (16), none to close now") !=
                       std::string::npos)
        ++refused;
    }
    CHECK(refused >= 1);
    REQUIRE(ctl(dir.path, {"--json", "status"}, "st.json") == 0);
    std::string first;  // the first client's one line: why it was closed
    for (char c; ::recv(held[0], &c, 1, 0) == 1 && c != '\n';) first += c;
    CHECK_MESSAGE(
        first.find("closed to make room for a new one: 16 open (max_clients)") != std::string::npos,
        first);
    CHECK(json::parse(slurp(dir.path / "st.json"))["phase"] == "turn");  // the run went on
    CHECK(ctl(dir.path, {"abort", "operator test"}) == 0);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 20000ms) == 1);
    for (const int fd : held) ::close(fd);
    const json r = report_of(dir.path, id);
    CHECK(r["status"] == "aborted");
    CHECK(r["reason"] == "operator test");
    CHECK(r["quick_stop"]["acknowledged"] == true);
    CHECK(r["schema_version"] == 2);       // report.hpp: kReportSchemaVersion
    (void)replay_of_log(dir.path, id, r);  // whole, every frame in it
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["state"] == kQuickStopped);
    CHECK(st["table"]["rate_dps"] == 0.0);
    CHECK(st["counts"]["quick_stops"].get<int>() >= 1);
    const std::string log = slurp(dir.path / "daemon.err");
    CHECK(log.find("control connection closed to make room for a new one") != std::string::npos);
    CHECK(log.find("control connection refused: 16 open, each new and not yet heard from") !=
          std::string::npos);
    CHECK(log.find("report unreadable: estimates.nu0_1.value") != std::string::npos);
  }

  TEST_CASE(
      "clients that never read or never ask are dropped; with descriptors exhausted the loop "
      "pauses accepting, and accepts again") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    std::ofstream(dir.path / "turncal.toml", std::ios::app) << "client_idle_s = 1\n";
    Child sim = start_sim(dir.path, "16");
    Child daemon = start_daemon(dir.path);
    const hil::fs::path sock = dir.path / "control.sock";
    REQUIRE(wait_for(sock, 5000ms));
    // one asks 2000 statuses (over a megabyte of replies) and reads none;
    // one connects and asks nothing
    const int greedy = connect_control(sock);
    std::string reqs;
    for (int k = 0; k < 2000; ++k) reqs += "{\"cmd\":\"status\"}\n";
    REQUIRE(::send(greedy, reqs.data(), reqs.size(), MSG_NOSIGNAL) ==
            static_cast<ssize_t>(reqs.size()));
    const int silent = connect_control(sock);
    // a watcher that leaves its next request unfinished (it would hold a
    // reload off), and one that sends a line a byte at a time, never ending it
    const int unfinished = connect_control(sock);
    const std::string part = "{\"cmd\":\"watch\"}\n{\"cmd\":\"sta";
    REQUIRE(::send(unfinished, part.data(), part.size(), MSG_NOSIGNAL) ==
            static_cast<ssize_t>(part.size()));
    const int trickle = connect_control(sock);
    int sent = 0;  // until the daemon closes it
    const auto first = std::chrono::steady_clock::now();
    auto since_first = [&] {
      return std::chrono::duration<double>(std::chrono::steady_clock::now() - first).count();
    };
    double last_ok_s = 0;
    for (; sent < 60 && ::send(trickle, "x", 1, MSG_NOSIGNAL) == 1; ++sent) {
      last_ok_s = since_first();
      std::this_thread::sleep_for(100ms);
    }
    // the send that found it closed: the daemon read the first byte after
    // it was sent, and drops the line a second after that, not before; and
    // not long before that send (the sends 0.1 s apart, a guest's sleep
    // stretched by up to 0.3 s)
    const double closed_s = since_first();
    MESSAGE("the trickle sent " << sent << " bytes, one each 0.1 s, the last at " << last_ok_s
                                << " s, and found itself dropped at " << closed_s << " s");
    CHECK(sent < 60);
    CHECK(closed_s >= 1.0);
    CHECK(last_ok_s >= 0.6);
    char c;
    CHECK(::recv(silent, &c, 1, 0) == 0);  // closed by the daemon
    // the watcher got its statuses, then was closed (it would get one each
    // 0.5 s for ever otherwise: 10 s at most)
    std::size_t statuses = 0;
    ssize_t last = -1;
    {
      std::string wbuf(65536, '\0');
      const auto until = std::chrono::steady_clock::now() + 10s;
      while (std::chrono::steady_clock::now() < until &&
             (last = ::recv(unfinished, wbuf.data(), wbuf.size(), 0)) > 0)
        statuses += static_cast<std::size_t>(std::count(wbuf.begin(), wbuf.begin() + last, '\n'));
    }
    CHECK(statuses >= 1);
    CHECK(last == 0);
    ::close(unfinished);
    ::close(trickle);
    std::size_t replies = 0;
    std::string buf(65536, '\0');
    for (ssize_t n; (n = ::recv(greedy, buf.data(), buf.size(), 0)) > 0;)
      replies += static_cast<std::size_t>(std::count(buf.begin(), buf.begin() + n, '\n'));
    CHECK(replies < 2000);  // the rest were never sent: it was dropped
    MESSAGE("the client that did not read got " << replies << " of 2000 replies");
    ::close(greedy);
    ::close(silent);
    CHECK(ctl(dir.path, {"status"}) == 0);

    // descriptors: the daemon's limit set to what it has open and two more
    std::size_t open_fds = 0;
    for (const auto& e :
         hil::fs::directory_iterator("/proc/" + std::to_string(daemon.pid()) + "/fd")) {
      (void)e;
      ++open_fds;
    }
    const std::string lim = std::to_string(open_fds + 2);
    REQUIRE(std::system(
                ("prlimit --pid " + std::to_string(daemon.pid()) + " --nofile=" + lim + ":" + lim)
                    .c_str()) == 0);
    std::vector<int> held;
    for (int k = 0; k < 6; ++k) held.push_back(connect_control(sock));  // the backlog takes them
    std::this_thread::sleep_for(3500ms);
    const std::string err = slurp(dir.path / "daemon.err");
    std::size_t pauses = 0;
    for (std::size_t at = 0;
         (at = err.find("cannot accept a control connection: Too many open files", at)) !=
         std::string::npos;
         ++at)
      ++pauses;
    MESSAGE(pauses << " pauses in 3.5 s");
    CHECK(pauses >= 2);
    CHECK(pauses <= 5);  // one a second: the loop does not spin on the listener
    for (const int fd : held) ::close(fd);
    std::this_thread::sleep_for(2500ms);  // the idle ones go; accepting resumes
    CHECK(ctl(dir.path, {"status"}) == 0);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const std::string log = slurp(dir.path / "daemon.err");
    CHECK(log.find("control client dropped: its replies were left unread for 1 s") !=
          std::string::npos);
    CHECK(log.find("control client dropped: no request for 1 s") != std::string::npos);
    std::size_t unfinished_drops = 0;
    for (std::size_t at = 0;
         (at = log.find("control client dropped: a request left unfinished for 1 s", at)) !=
         std::string::npos;
         ++at)
      ++unfinished_drops;
    CHECK(unfinished_drops == 2);  // the watcher and the trickle
  }

  TEST_CASE(
      "the CAN interface goes down in the turn: the run fails, the quick stop goes when it is "
      "back") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 60, kSlowTurnDps);
    // the table's own heartbeat watchdog out of the way (30 s, not 0.5 s), so
    // only the daemon's quick stop can stop it
    Child sim =
        start_sim(dir.path, "6", {"--state-out", "stand.json", "--table-heartbeat-timeout", "30"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    std::this_thread::sleep_for(500ms);  // well into the turn: the table moves
    REQUIRE(std::system(("ip link set " + hil::if0() + " down").c_str()) == 0);
    std::this_thread::sleep_for(700ms);
    REQUIRE(std::system(("ip link set " + hil::if0() + " up").c_str()) == 0);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 30000ms) == 1);
    const json r = report_of(dir.path, id);
    CAPTURE(r.dump());
    CHECK(r["status"] == "failed");
    CHECK(r["reason"].get<std::string>().find("CAN interface " + hil::if0() + " went down") == 0);
    CHECK(r["quick_stop"]["sent"] == true);
    CHECK(r["quick_stop"]["acknowledged"] == true);
    CHECK(r["quick_stop"]["times"].get<int>() > 1);  // the first was lost with the bus
    const json& can = r["can"][hil::if0()];
    CHECK(can["tx_dropped"].get<int>() > 0);
    // the log replays to the fault
    const hil::fs::path log = dir.path / "state" / (id + ".log");
    (void)ctl(dir.path,
              {"--json", "replay", log.string(), "--config", (dir.path / "turncal.toml").string()},
              "replay.json", 60000ms);
    const json rp = json::parse(slurp(dir.path / "replay.json"));
    CHECK(rp.at("replay").at("damage").is_null());
    bool turn = false;  // the replay sees the run up to the turn
    for (const auto& ph : rp["phases"]) turn = turn || ph["phase"] == "turn";
    CHECK(turn);
    // the log went on after the fault: the quick stop's acknowledgement is in it
    CHECK(log_records(log) ==
          can["rx_frames"].get<std::uint64_t>() + can["tx_confirmed"].get<std::uint64_t>());
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["state"] == kQuickStopped);
    CHECK(st["table"]["fault"] == 0);  // stopped by a command: ours, after the bus came back
    CHECK(st["table"]["rate_dps"] == 0.0);
    CHECK(st["counts"]["quick_stops"].get<int>() >= 1);
    const std::string dlog = slurp(dir.path / "daemon.err");
    CHECK(dlog.find("went down") != std::string::npos);
    CHECK(dlog.find(hil::if0() + " is back") != std::string::npos);
  }

  TEST_CASE("the host checks the encoder: an overshoot, a table that turns by itself") {
    struct Case {
      const char* fault;
      const char* reason;  ///< in the report's reason
    };
    for (const Case k : {Case{"table-overshoot=1", "overshoot, the table passed its target"},
                         Case{"table-drift=40:2", "with no move commanded"}}) {
      CAPTURE(k.fault);
      hil::TempDir dir;
      write_stand(dir.path, hil::if0());
      // the table's own heartbeat watchdog out of the way: only the host stops it
      Child sim = start_sim(
          dir.path, "8",
          {"--state-out", "stand.json", "--table-heartbeat-timeout", "30", "--fault", k.fault});
      Child daemon = start_daemon(dir.path);
      REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
      const std::string id = start_run(dir.path);
      CHECK(ctl(dir.path, {"watch"}, "w.out", 60000ms) == 1);
      const json r = report_of(dir.path, id);
      CAPTURE(r.value("reason", std::string()));
      CHECK(r["status"] == "failed");
      CHECK(r["reason"].get<std::string>().find(k.reason) != std::string::npos);
      CHECK(r["quick_stop"]["acknowledged"] == true);
      const hil::fs::path log = dir.path / "state" / (id + ".log");
      const json& can = r["can"][hil::if0()];
      CHECK(log_records(log) ==
            can["rx_frames"].get<std::uint64_t>() + can["tx_confirmed"].get<std::uint64_t>());
      daemon.terminate();
      CHECK(daemon.wait(10000ms) == 0);
      const json st = stand_state(sim, dir.path);
      CHECK(st["table"]["state"] == kQuickStopped);
      CHECK(st["table"]["fault"] == 0);  // stopped by the host's command
      CHECK(st["table"]["rate_dps"] == 0.0);
      CHECK(slurp(dir.path / "daemon.err").find(k.reason) != std::string::npos);
    }
  }

  TEST_CASE(
      "the disk fills during the run: the table stops, the log replays, the report says why") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 60, kSlowTurnDps);
    // 256 KiB kept for the report; the state directory a file system of
    // 3 MiB, room for the run's log (about 1 MiB), until another writer
    // fills it in the turn
    std::ofstream(dir.path / "turncal.toml", std::ios::app) << "report_reserve_mib = 0.25\n";
    hil::fs::create_directories(dir.path / "state");
    const std::string state = (dir.path / "state").string();
    REQUIRE(std::system(("mount -t tmpfs -o size=3m tmpfs " + state).c_str()) == 0);
    const AtExit unmount{"umount " + state};
    Child sim = start_sim(dir.path, "9", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    // everything left, to another file (dd ends at "No space left")
    CHECK(std::system(("dd if=/dev/zero of=" + state + "/filler bs=16k 2>/dev/null").c_str()) != 0);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 90000ms) == 1);
    const json r = report_of(dir.path, id);  // there: its space was kept
    const std::string reason = r.value("reason", std::string());
    CAPTURE(reason);
    MESSAGE("disk full: " << reason << " (phase " << r["phases"].back()["phase"] << " after "
                          << r["phases"][r["phases"].size() - 2]["phase"] << ")");
    CHECK(r["status"] == "failed");
    // the space check (every 10 s) sees the full disk, or a log write
    // fails first: either stops the run
    const bool seen = reason.find("the disk cannot hold this run's log: the state directory ") == 0;
    const bool failed_write =
        reason.find("log write failed: No space left on device: log kept up to line ") == 0;
    CHECK((seen || failed_write));
    CHECK(r["quick_stop"]["sent"] == true);
    CHECK(r["quick_stop"]["acknowledged"] == true);
    // the log ends at a whole line (the one the reason names, if a write
    // failed), and replays
    const hil::fs::path log = dir.path / "state" / (id + ".log");
    const std::uint64_t lines = log_records(log);
    if (failed_write)
      CHECK(reason.find("up to line " + std::to_string(lines)) != std::string::npos);
    CHECK(lines > 1000);
    CHECK(r["phases"].back()["phase"] == "failed");
    (void)ctl(dir.path,
              {"--json", "replay", log.string(), "--config", (dir.path / "turncal.toml").string()},
              "replay.json", 60000ms);
    const json rp = json::parse(slurp(dir.path / "replay.json"));
    CHECK(rp.at("replay").at("damage").is_null());
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["state"] == kQuickStopped);
    CHECK(st["table"]["rate_dps"] == 0.0);
    CHECK(slurp(dir.path / "daemon.err").find("No space left on device") != std::string::npos);
  }

  TEST_CASE(
      "the disk fails in the turn (I/O errors): the table stops, the log is kept up to the "
      "failure, the run is failed with the reason") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 60, kSlowTurnDps);
    std::ofstream(dir.path / "turncal.toml", std::ios::app) << "report_reserve_mib = 0.25\n";
    const hil::fs::path state = dir.path / "state";
    hil::fs::create_directories(state);
    // the state directory on ext4 on a device-mapper target over a loop
    // device: a linear map now, the "error" target (every I/O fails) later.
    // Device nodes from a devtmpfs of the test's own.
    const std::string d = dir.path.string();
    const std::string setup =
        "set -e; dmesg -n 1; m=/usr/lib/uml/modules/$(uname -r)/kernel; "
        "[ -e /sys/module/loop ] || modprobe loop || insmod $m/drivers/block/loop.ko; "
        "[ -e /sys/module/dm_mod ] || modprobe dm-mod || insmod $m/drivers/md/dm-mod.ko; "
        "mkdir -p " +
        d + "/dev; mount -t devtmpfs devtmpfs " + d +
        "/dev; "
        "truncate -s 16M " +
        d +
        "/disk.img; "
        "losetup " +
        d + "/dev/loop7 " + d +
        "/disk.img; "
        "export DM_DEV_DIR=" +
        d +
        "/dev; "
        "dmsetup create tcfail --table \"0 32768 linear " +
        d +
        "/dev/loop7 0\"; "
        "mkfs.ext4 -q " +
        d +
        "/dev/mapper/tcfail; "
        "mount " +
        d + "/dev/mapper/tcfail " + state.string();
    // (the kernel's console stays quiet after: in user-mode Linux every
    // message is a synchronous write to the host, and the ext4 and device
    // errors the test provokes would hold up the tests after it)
    const AtExit teardown{"umount " + state.string() + " || umount -l " + state.string() +
                          "; DM_DEV_DIR=" + d + "/dev dmsetup remove tcfail || DM_DEV_DIR=" + d +
                          "/dev dmsetup remove --force tcfail; losetup -d " + d +
                          "/dev/loop7; umount " + d + "/dev || umount -l " + d + "/dev"};
    REQUIRE_MESSAGE(std::system(setup.c_str()) == 0, "no loop and device-mapper devices here");
    auto table = [&](const std::string& t) {
      return "DM_DEV_DIR=" + d + "/dev dmsetup suspend --noflush tcfail && DM_DEV_DIR=" + d +
             "/dev dmsetup load tcfail --table \"0 32768 " + t + "\" && DM_DEV_DIR=" + d +
             "/dev dmsetup resume tcfail";
    };
    Child sim = start_sim(dir.path, "14", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    REQUIRE(std::system(table("error").c_str()) == 0);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 90000ms) == 1);
    REQUIRE(ctl(dir.path, {"--json", "status"}, "st.json") == 0);
    const json st = json::parse(slurp(dir.path / "st.json"));
    const std::string reason = st.value("reason", std::string());
    MESSAGE("disk failing: " << reason);
    CHECK(st["phase"] == "failed");
    CHECK(reason.find("log ") == 0);
    CHECK((reason.find("Input/output error") != std::string::npos ||
           reason.find("Read-only file system") != std::string::npos));
    CHECK(reason.find("log kept up to line ") != std::string::npos);
    // "log fsync failed: E: lines after N may be lost: ...": N are on disk
    std::uint64_t synced = 0;
    if (const auto at = reason.find("lines after "); at != std::string::npos)
      synced = std::stoull(reason.substr(at + 12));
    CHECK(synced > 1000);  // the phase ends before the turn were synced
    const std::string err = slurp(dir.path / "daemon.err");
    // the report could not go on that disk, and the daemon says so
    CHECK(err.find("report not written") != std::string::npos);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json stand = stand_state(sim, dir.path);
    CHECK(stand["table"]["state"] == kQuickStopped);
    CHECK(stand["table"]["rate_dps"] == 0.0);
    // the disk back: the log reads whole, and holds every line it said were
    // on disk
    REQUIRE(std::system(table("linear " + d + "/dev/loop7 0").c_str()) == 0);
    // from the disk, not the page cache
    REQUIRE(std::system(("sync; echo 3 > /proc/sys/vm/drop_caches; umount " + state.string() +
                         " && mount " + d + "/dev/mapper/tcfail " + state.string())
                            .c_str()) == 0);
    // the lines said to be on disk read whole; after them the disk may hold
    // what the failure left (lost pages), which is why they were not counted
    std::uint64_t whole = 0;
    if (auto rd = turncal::can::LogReader::open((state / (id + ".log")).string())) {
      for (turncal::can::LogRecord rec;;) {
        auto more = rd->next(rec);
        if (!more || !*more) break;
        ++whole;
      }
    }
    MESSAGE("read back from the disk: " << whole << " whole lines; " << synced << " said synced");
    CHECK(whole >= synced);
  }

  TEST_CASE(
      "a run whose log the disk cannot hold fails before the table moves, or is refused; "
      "retention makes room first") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    // the state directory a file system of 600 KiB, 256 KiB of it kept for
    // the report: the run's log (about 1 MiB) cannot fit
    std::ofstream(dir.path / "turncal.toml", std::ios::app)
        << "report_reserve_mib = 0.25\nkeep_logs_days = 1\n";
    const hil::fs::path state = dir.path / "state";
    hil::fs::create_directories(state);
    REQUIRE(std::system(("mount -t tmpfs -o size=600k tmpfs " + state.string()).c_str()) == 0);
    const AtExit unmount{"umount " + state.string()};
    // an old run's log and report: retention takes the log, keeps the report
    const std::string old_id = "20200101T000000Z";
    std::ofstream(state / (old_id + ".log")) << std::string(100000, 'x');
    REQUIRE(std::system(
                ("touch -d '2020-01-02' " + (state / (old_id + ".log")).string()).c_str()) == 0);
    std::ofstream(state / (old_id + ".report.json"))
        << R"({"run_id":"20200101T000000Z","status":"done","unit":"SN-9"})";
    Child sim = start_sim(dir.path, "12", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    std::this_thread::sleep_for(2000ms);  // the bus's rate known: the idle stand's

    // A start the bus's rate already rules out is refused outright, with
    // nothing recorded. Where the idle stand's rate lets it through (the
    // INS sends its velocity once it navigates), the run's own rate fails
    // it before the turn, and the next start is refused.
    auto expect_refused = [&](const char* out) {
      REQUIRE(ctl(dir.path, {"--json", "start"}, out) != 0);
      const json refused = json::parse(slurp(dir.path / out));
      CAPTURE(refused.dump());
      CHECK(refused["ok"] == false);
      const std::string why = refused.value("error", std::string());
      MESSAGE("at the start: " << why);
      CHECK(why.find("run refused: the state directory ") == 0);
      CHECK(why.find("frames/s the bus has had") != std::string::npos);
    };
    std::size_t runs = 0;
    if (ctl(dir.path, {"--json", "start"}, "start.json") != 0) {
      expect_refused("start.json");
    } else {
      runs = 1;
      const std::string id = json::parse(slurp(dir.path / "start.json"))["run_id"];
      CHECK(ctl(dir.path, {"watch"}, "w.out", 60000ms) == 1);
      const json r = report_of(dir.path, id);
      const std::string reason = r.value("reason", std::string());
      CAPTURE(reason);
      MESSAGE("in the run: " << reason);
      CHECK(r["status"] == "failed");
      CHECK(reason.find("the disk cannot hold this run's log: the state directory ") == 0);
      CHECK(reason.find("MiB of log") != std::string::npos);
      const std::string before = r["phases"][r["phases"].size() - 2]["phase"];
      CHECK((before == "prepare" || before == "align" || before == "hold"));
      CHECK(log_records(state / (id + ".log")) > 0);  // the log up to it is kept, whole
      expect_refused("start2.json");
    }
    // retention ran first either way: the old log gone, its report kept
    CHECK_FALSE(hil::fs::exists(state / (old_id + ".log")));
    CHECK(hil::fs::exists(state / (old_id + ".report.json")));
    std::size_t logs = 0;
    for (const auto& e : hil::fs::directory_iterator(state)) logs += e.path().extension() == ".log";
    CHECK(logs == runs);

    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["rate_dps"] == 0.0);
    CHECK(std::abs(st["table"]["angle_deg"].get<double>()) < 1e-6);  // never turned
    const std::string err = slurp(dir.path / "daemon.err");
    CHECK(err.find("retention: removed the log of run " + old_id) != std::string::npos);
  }

  TEST_CASE(
      "SIGTERM while the estimate is computed: it is finished and reported, then turncald "
      "stops") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    Child sim = start_sim(dir.path, "15", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    // the status, asked on the control socket every 100 ms, and every 2 ms
    // in the last 3 s of the record, until the estimate
    bool in_estimate = false;
    for (auto end = std::chrono::steady_clock::now() + 120s;
         !in_estimate && std::chrono::steady_clock::now() < end;) {
      const json st = json::parse(raw_request(dir.path / "control.sock", "{\"cmd\":\"status\"}\n"),
                                  nullptr, false);
      REQUIRE_FALSE(st.is_discarded());
      in_estimate = st["phase"] == "estimate";
      if (st["phase"] == "done") break;
      const bool near = st["remaining_s"].is_number() && st["remaining_s"].get<double>() < 3.0;
      std::this_thread::sleep_for(near ? 2ms : 100ms);
    }
    REQUIRE_MESSAGE(in_estimate, "the estimate was never seen under way");
    daemon.terminate();
    CHECK(daemon.wait(30000ms) == 0);  // the unit's TimeoutStopSec
    const json r = report_of(dir.path, id);
    CAPTURE(r.value("reason", std::string()));
    CHECK(r["status"] == "done");
    CHECK(r.contains("estimates"));
    REQUIRE(r.contains("stop_signal"));
    CHECK(r["stop_signal"].get<std::string>().find("SIGTERM during the estimate") == 0);
    for (const json& p : r["phases"])
      if (p["phase"] == "estimate")
        MESSAGE("the estimate took " << p["duration_s"] << " s (stand)");
    const std::string err = slurp(dir.path / "daemon.err");
    CHECK(err.find("SIGTERM received") != std::string::npos);
    CHECK(err.find("report written") != std::string::npos);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["rate_dps"] == 0.0);
  }

  TEST_CASE("a flood of unknown frames: the heartbeat keeps its period, the run completes") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 40);
    // 1000 frames per stand second at 4x: 4000 a second of real time, from
    // the hold before the turn to after it
    Child sim =
        start_sim(dir.path, "7", {"--state-out", "stand.json", "--fault", "flood=30:40:1000"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 180000ms) == 0);
    const json r = report_of(dir.path, id);
    CAPTURE(r.value("reason", std::string()));
    CHECK(r["status"] == "done");
    // what the guest's one CPU gave each (the stand, its flood, the daemon)
    MESSAGE("CPU time: the stand " << cpu_seconds(sim.pid()) << " s, turncald "
                                   << cpu_seconds(daemon.pid()) << " s");
    // the table's record of the heartbeat ends with the run: the replay
    // below is this test's own load on the guest's CPU, not the daemon's
    const json st = stand_state(sim, dir.path);
    (void)replay_of_log(dir.path, id, r);  // the flood's frames in it too, whole
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json& hb = st["heartbeat"];
    MESSAGE("heartbeat at the table: mean gap "
            << hb["mean_gap_s"] << " s, max " << hb["max_gap_s"] << " s (ending at stand time "
            << hb["max_gap_end_s"] << " s), " << hb["gaps_off_20_percent"] << " of " << hb["gaps"]
            << " gaps off by over 20%, " << hb["gaps_off_50_percent"]
            << " by over half a period, [end, length] in stand s: "
            << hb["gaps_off_50_percent_end_and_length_s"].dump());
    CHECK(hb["gaps"].get<int>() > 500);
    // 10 Hz of stand time: within 20%
    CHECK(hb["mean_gap_s"].get<double>() == doctest::Approx(0.1).epsilon(0.2));
    // What the table needs of the host under a flood, in the flood and the
    // 5 s after: every period's heartbeat, none later than the ICD's
    // heartbeat timeout (0.5 s; the hil stand's table allows 2 s of its
    // time, start_sim). A loop the flood starved would miss periods and
    // leave gaps of several. How far each gap is off its period is said,
    // not judged: within half a period is 12 ms of real time at 4x, and
    // that measures the guest's one CPU, shared by the stand, its flood,
    // the daemon and this test (from 2 to 102 such gaps of 1440 from one
    // run of the same code to the next, clustered in the turn, where the
    // stand integrates fastest, and in the estimate).
    const auto window = hb["flood_window_s"];
    REQUIRE(window.is_array());
    const double expected = (window[1].get<double>() - window[0].get<double>()) / 0.1;
    MESSAGE("in the flood and the 5 s after: " << hb["in_flood"] << " heartbeats of " << expected
                                               << ", the longest gap " << hb["max_gap_in_flood_s"]
                                               << " s");
    CHECK(hb["in_flood"].get<double>() >= 0.95 * expected);
    CHECK(hb["max_gap_in_flood_s"].get<double>() < 0.5);
  }

  TEST_CASE("the fault list through the daemon: each stops the table, the log replays to it") {
    // the stand's clock: the INS navigates from about 20 s, the turn (180
    // deg) starts about 60 s; each run ends at its fault
    struct Case {
      const char* name;
      std::vector<std::string> sim;  ///< turncal-sim's arguments for the fault
      const char* reason;            ///< the start of the report's reason, or a part of it
      int table_state;               ///< the table's own, at the end
      /// the phase the replay reaches: the live run's last, unless the
      /// fault left no trace an observer sees (a move refused: no motion)
      const char* replay_reaches = nullptr;
      /// the replay (an observer) fails with the same reason: a fault in
      /// the INS's or the encoder's frames, not one the table reports of
      /// itself (an observer does not judge the table's status)
      bool replay_names_it = true;
      int turn_dps = 30;  ///< the turn's rate
    };
    const std::vector<Case> cases = {
        {"INS silent in hold 1",
         {"--fault", "ins-silent=30"},
         "INS velocity lost during hold 1",
         kQuickStopped},
        // the silence 2 s into the turn, timed from the table's first
        // motion (the stand's own clock starts before the run by as long as
        // the guest takes to start a daemon and a run: 2 to 4 s of it), in
        // a turn of 36 s: its loss seen well inside it, live and in the
        // replay alike
        {"INS silent in the turn",
         {"--fault", "ins-silent=turn+2"},
         "INS velocity lost during turn 1",
         kQuickStopped,
         nullptr,
         true,
         kSlowTurnDps},
        {"encoder silent in the turn",
         {"--fault", "encoder-silent=turn+2"},
         "table encoder lost",
         kQuickStopped,
         nullptr,
         true,
         kSlowTurnDps},
        {"the first move stalls",
         {"--fault", "table-stall=1"},
         "table fault: stall",
         kQuickStopped,
         nullptr,
         false},
        {"a drive fault in hold 1",
         {"--fault", "table-fault=30"},
         "table fault: drive fault",
         kQuickStopped,  // the drive takes our quick stop after its fault
         nullptr,
         false},
        {"the turn refused by the table's soft limits",
         {"--angle-limits", "-10:90"},
         "table fault: command refused",
         kQuickStopped,
         "hold",
         false},
        {"INS fault mode in hold 1", {"--fault", "ins-fault=30"}, "INS fault mode", kQuickStopped},
        {"5% of the INS velocity frames garbled",
         {"--fault", "ins-spikes=0.05"},
         "ins-velocity frames implausible: ",
         kQuickStopped},
        {"the INS clock jumps 0.3 s ahead in hold 1",
         {"--fault", "clock-jump=ins:30:0.3"},
         "the INS clock jumped ahead by ",
         kQuickStopped},
    };
    for (const Case& k : cases) SUBCASE(k.name) {
        hil::TempDir dir;
        write_stand(dir.path, hil::if0(), false, 40, k.turn_dps);
        std::vector<std::string> args = {"--state-out", "stand.json"};
        args.insert(args.end(), k.sim.begin(), k.sim.end());
        Child sim = start_sim(dir.path, "5", args);
        Child daemon = start_daemon(dir.path);
        REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
        const std::string id = start_run(dir.path);
        CHECK(ctl(dir.path, {"watch"}, "w.out", 60000ms) == 1);
        const json r = report_of(dir.path, id);
        const std::string reason = r.value("reason", std::string());
        CAPTURE(reason);
        CHECK(r["status"] == "failed");
        CHECK(reason.find(k.reason) != std::string::npos);
        if (std::string(k.reason).ends_with(" by ")) {
          // how far the clock jumped, from its least delayed frame: within
          // 10 ms of real time (40 ms of stand time at 4x), the guest's delays
          const double by = std::strtod(reason.c_str() + reason.find(" by ") + 4, nullptr);
          CHECK(std::abs(by - 0.3) < 0.01 * kSpeed);
        }
        CHECK(r["quick_stop"]["sent"] == true);
        CHECK(r["quick_stop"]["acknowledged"] == true);
        const json rp = replay_of_log(dir.path, id, r);
        // the replay sees the run up to the phase the fault ended
        const std::string at =
            k.replay_reaches != nullptr
                ? std::string(k.replay_reaches)
                : r["phases"][r["phases"].size() - 2]["phase"].get<std::string>();
        bool seen = false;
        for (const auto& ph : rp["phases"]) seen = seen || ph["phase"] == at;
        CHECK_MESSAGE(seen, "the replay never reached " << at);
        // where the fault is in the frames, the replay fails on it too
        if (k.replay_names_it) CHECK(rp.value("reason", std::string()) == reason);
        daemon.terminate();
        CHECK(daemon.wait(10000ms) == 0);
        const json st = stand_state(sim, dir.path);
        CHECK(st["table"]["state"] == k.table_state);
        CHECK(st["table"]["rate_dps"] == 0.0);
        CHECK(st["counts"]["quick_stops"].get<int>() >= 1);  // ours reached the table
        CHECK_MESSAGE(slurp(dir.path / "daemon.err").find(k.reason) != std::string::npos,
                      slurp(dir.path / "daemon.err"));
      }
  }

  TEST_CASE("garbage on the bus and an INS clock that wraps 2^32 us: counted, the run done") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 40);
    // the INS's u32 microsecond tags wrap at 4294.967296 s: 40 s into the run
    Child sim =
        start_sim(dir.path, "4",
                  {"--state-out", "stand.json", "--fault", "garbage=50", "--ins-clock", "4255:0"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    CHECK(ctl(dir.path, {"watch"}, "w.out", 120000ms) == 0);
    const json r = report_of(dir.path, id);
    CAPTURE(r.value("reason", std::string()));
    CHECK(r["status"] == "done");
    const json& h = r["health"];
    MESSAGE("garbage: malformed " << h["malformed"] << ", unknown " << h["unknown_id"]
                                  << "; INS tags dropped " << h["velocity_tags_dropped"]);
    CHECK(h["malformed"].get<int>() > 100);  // 50 Hz of stand time for about 2 min
    CHECK(h["unknown_id"].get<int>() > 100);
    CHECK(h["velocity_tags_dropped"] == 0);  // the wrap is no jump
    CHECK(h["ins_velocity"]["dropped"] == 0);
    // the velocity spans the wrap: the whole run at 25 Hz, but for its
    // first seconds (120 s gave 2900 and more)
    CHECK(r["velocity_samples"].get<int>() > 25 * (plan_duration_s(40) - 4));
    const json rp = replay_of_log(dir.path, id, r);
    CHECK(rp["status"] == "done");
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["state"] != kTableFault);
  }

  TEST_CASE(
      "the realtime clock steps an hour ahead in hold 1 and back in the turn: nothing moves") {
    // only in the guest: natively the clock is the machine's own
    const char* env = std::getenv("TURNCAL_VCAN_ENV");
    if (env == nullptr || std::string(env) != "user-mode-linux") {
      MESSAGE("skipped: the realtime clock is stepped only inside user-mode Linux");
      return;
    }
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 40, kSlowTurnDps);
    Child sim = start_sim(dir.path, "2", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    // the guest's clock, stepped as NTP does at boot (and put back)
    struct PutBack {
      int steps = 0;
      ~PutBack() {
        if (steps > 0) (void)!std::system("date -s '-1 hour' >/dev/null");
      }
    } put_back;
    REQUIRE_MESSAGE(wait_phase(dir.path, "hold", 60000ms), last_status());
    std::this_thread::sleep_for(1000ms);
    REQUIRE(std::system("date -s '+1 hour' >/dev/null") == 0);
    put_back.steps = 1;
    REQUIRE_MESSAGE(wait_phase(dir.path, "turn", 60000ms), last_status());
    std::this_thread::sleep_for(300ms);
    REQUIRE(std::system("date -s '-1 hour' >/dev/null") == 0);
    put_back.steps = 0;
    CHECK(ctl(dir.path, {"watch"}, "w.out", 120000ms) == 0);
    const json r = report_of(dir.path, id);
    CAPTURE(r.value("reason", std::string()));
    CHECK(r["status"] == "done");
    CHECK(r["host_clock"]["realtime_steps"] == 2);
    CHECK(r["host_clock"]["unknown_stamps"] == 0);
    // the phases as planned: hold 1 of 40 s from t0 (the turn starts on
    // the schedule), the turn's own length, the run 120 s from t0
    double hold1 = -1, t0_to_end = 0;
    for (const auto& ph : r["phases"]) {
      if (ph["phase"] == "hold" && ph.value("index", 0) == 1) hold1 = ph["duration_s"];
      if (ph["phase"] == "hold" || ph["phase"] == "turn")
        t0_to_end += ph["duration_s"].get<double>();
    }
    MESSAGE("hold 1 " << hold1 << " s, t0 to the end " << t0_to_end
                      << " s; clock offset at the end " << r["host_clock"]["realtime_offset_s"]
                      << " s");
    CHECK(std::abs(hold1 - 40) < 0.5);       // a tick (0.1 s) and the INS's t0
    CHECK(std::abs(t0_to_end - 120) < 1.5);  // and the record's end
    // the log's times go on the run's clock: no hour in them
    auto reader = can::LogReader::open((dir.path / "state" / (id + ".log")).string());
    REQUIRE(reader.ok());
    std::int64_t first = 0, last = 0, largest_step = 0;
    for (;;) {
      auto rec = reader->next();
      REQUIRE(rec.ok());
      if (!rec->has_value()) break;
      const std::int64_t t = (**rec).time_ns;
      if (first == 0) first = t;
      if (last != 0) largest_step = std::max(largest_step, std::abs(t - last));
      last = t;
    }
    CHECK(static_cast<double>(last - first) * 1e-9 < 200.0 / kSpeed);
    CHECK(largest_step < 1'000'000'000);
    // and the estimates are those of its own log, bit for bit
    const json rp = replay_of_log(dir.path, id, r);
    CHECK(rp["status"] == "done");
    CHECK(rp["estimates"] == r["estimates"]);
    CHECK(slurp(dir.path / "daemon.err").find("the realtime clock stepped") != std::string::npos);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["table"]["state"] != kTableFault);
  }
}

namespace {

/// The shipped CiA 402 stand's [ins], [table], [table.cia402] and roles,
/// for write_stand's `extra`.
std::string cia402_sections() {
  const std::string conf = slurp(hil::fs::path(kSrc) / "config/stands/cia402/turncal.toml");
  const auto from = conf.find("\n[ins]");
  const auto to = conf.find("\n[daemon]");
  REQUIRE(from != std::string::npos);
  REQUIRE(to != std::string::npos);
  std::string sections = conf.substr(from, to - from) + "\n";
  // The guest runs the stand at 4x on one CPU beside the scenario tier,
  // where the stand was seen to fall 150 ms of real time (600 ms of its
  // own) behind, and CI's machine was seen to stop the guest as a whole
  // for up to 0.9 s of real time: the virtual drive, on the same machine,
  // then finds our heartbeat gone when it runs again (EMCY 0x8130), which
  // a real drive, not held with the host, would not. The heartbeats'
  // timeouts and the SDO's, in the stand's time, are over that here (1,
  // 1.25 and 0.5 s real). On a real stand, at 1x, the shipped 300 and
  // 500 ms are six and ten times its 50 ms latency floor.
  for (auto [key, value] : {std::pair{"drive_heartbeat_timeout_ms = ", "4000"},
                            std::pair{"host_heartbeat_consumer_ms = ", "5000"},
                            std::pair{"sdo_timeout_ms = ", "2000"}}) {
    const auto at = sections.find(std::string("\n") + key);
    REQUIRE(at != std::string::npos);
    const auto v = at + 1 + std::string(key).size();
    sections.replace(v, sections.find('\n', v) - v, value);
  }
  return sections;
}

/// The EMCYs 0x8130 (life guard or heartbeat error: ours lost) the drive
/// (node 1) sends on `iface` within `window`.
int lost_host_emcys(const std::string& iface, std::chrono::milliseconds window) {
  auto bus = hil::open(iface);
  const auto rx = hil::receive(bus, std::numeric_limits<std::size_t>::max(), window);
  int n = 0;
  for (const auto& f : rx.frames)
    n += f.frame.id == 0x81 && f.frame.len == 8 && f.frame.data[0] == 0x30 &&
         f.frame.data[1] == 0x81;
  return n;
}

}  // namespace

TEST_SUITE("faults of a CiA 402 drive through the daemon") {
  TEST_CASE("a CiA 402 stand: the operator's abort in the turn quick-stops the drive") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0(), false, 40, 30, "config/stands/cia402/cia402.dbc",
                cia402_sections());
    Child sim = start_sim(dir.path, "5", {"--state-out", "stand.json"});
    Child daemon = start_daemon(dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string id = start_run(dir.path);
    const bool turning = wait_phase(dir.path, "turn", 60000ms);
    REQUIRE_MESSAGE(turning, slurp(dir.path / "daemon.err"));
    std::this_thread::sleep_for(500ms);  // 2 s of the stand's time: turning
    CHECK(abort_now(dir.path, "operator test").find("\"ok\":true") != std::string::npos);
    CHECK(ctl(dir.path, {"watch"}, "w.out") == 1);
    const json r = report_of(dir.path, id);
    CHECK(r["status"] == "aborted");
    CHECK(r["reason"] == "operator test");
    CHECK(r["quick_stop"]["acknowledged"] == true);
    CHECK(slurp(dir.path / "daemon.err").find("operator test") != std::string::npos);
    // every frame of the run in its log, and the replay of it sees the turn
    const json rp = replay_of_log(dir.path, id, r);
    bool turned = false;
    for (const auto& ph : rp["phases"]) turned = turned || ph["phase"] == "turn";
    CHECK(turned);
    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    const json st = stand_state(sim, dir.path);
    CHECK(st["drive"]["state"] == "quick stop active");
    CHECK(st["drive"]["moving"] == false);
    CHECK(st["drive"]["quick_stops"] == 1);
    CHECK(st["drive"]["coasts"] == 0);
    // stopped on the quick stop ramp, well short of the turn's 180 deg
    const double angle = st["drive"]["angle_deg"].get<double>();
    CHECK(angle > 10);
    CHECK(angle < 170);
  }

  TEST_CASE(
      "a CiA 402 stand: turncald stopped when idle, as a reload does: the drive takes its abort "
      "connection option on losing our heartbeat; the next run takes up a quick-stopped drive "
      "and refuses one in fault") {
    struct Case {
      const char* name;
      int option;     ///< abort connection option code, 0x6007
      bool taken_up;  ///< the next run done; else refused, nothing moved
    };
    const std::vector<Case> cases = {
        {"3, quick stop (shipped): taken up again", 3, true},
        // a fault found before the run: its cause was not seen (the EMCY
        // went out while no turncald listened), so it is no fault of ours
        // to reset
        {"1, fault: refused until reset at the stand", 1, false},
    };
    for (const Case& k : cases) SUBCASE(k.name) {
        hil::TempDir dir;
        std::string sections = cia402_sections();
        const std::string key = "\nabort_connection_option_code = ";
        const auto at = sections.find(key);
        REQUIRE(at != std::string::npos);
        sections.replace(at + key.size(), 1, std::to_string(k.option));
        write_stand(dir.path, hil::if0(), false, 40, 30, "config/stands/cia402/cia402.dbc",
                    sections);
        Child sim = start_sim(dir.path, "5", {"--state-out", "stand.json"});
        {
          // a run done leaves the drive in operation enabled, holding,
          // watching our heartbeat (0x1016), which the idle daemon goes on
          // sending
          Child daemon = start_daemon(dir.path);
          REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
          const std::string first = start_run(dir.path);
          CHECK(ctl(dir.path, {"watch"}, "w1.out", 120000ms) == 0);
          CHECK(report_of(dir.path, first)["status"] == "done");
          // idle for twice the drive's consumer time (5000 ms of the
          // stand's time, 1.25 s real): no loss of ours
          CHECK(lost_host_emcys(hil::if0(), 2500ms) == 0);
          daemon.terminate();
          CHECK(daemon.wait(10000ms) == 0);
        }
        // our heartbeat gone: the drive says so
        CHECK(lost_host_emcys(hil::if0(), 2500ms) == 1);
        Child daemon = start_daemon(dir.path);
        REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
        const std::string id = start_run(dir.path);
        CHECK(ctl(dir.path, {"watch"}, "w.out", 120000ms) == (k.taken_up ? 0 : 1));
        const json r = report_of(dir.path, id);
        const std::string reason = r.value("reason", std::string());
        CAPTURE(reason);
        CHECK(r["status"] == (k.taken_up ? "done" : "failed"));
        if (k.taken_up) {
          REQUIRE(r["turns_achieved"].size() == 1);  // it turned: 0 in prepare, then 180
          CHECK(std::abs(r["turns_achieved"][0]["angle_rad"].get<double>() - M_PI) < 1e-3);
        } else {
          CHECK(reason.starts_with("table fault: drive in fault (statusword"));
          CHECK(reason.find("reset it at the stand") != std::string::npos);
          CHECK(r["phases"][r["phases"].size() - 2]["phase"] == "prepare");
        }
        // the stand's account taken while this turncald still sends its
        // heartbeat (stopping it first would be a second loss, in a race)
        const json st = stand_state(sim, dir.path);
        daemon.terminate();
        CHECK(daemon.wait(10000ms) == 0);
        REQUIRE(st["drive"].is_object());
        CHECK(st["drive"]["host_heartbeat_lost"] == 1);
        if (k.option == 3) CHECK(st["drive"]["quick_stops"] == 1);  // the loss's alone
        CHECK(st["drive"]["coasts"] == 0);
        CHECK(st["drive"]["moving"] == false);
        CHECK(st["drive"]["state"] == (k.taken_up ? "operation enabled" : "fault"));
        // where the first run's turn left it (the second's prepare takes
        // it back to 0, its turn to 180 again), or never moved since
        CHECK(std::abs(st["drive"]["angle_deg"].get<double>() - 180) < 0.01);
      }
  }

  TEST_CASE(
      "a CiA 402 stand: the run done with turncald as the CANopen master; its faults stop it") {
    struct Case {
      const char* name;
      std::vector<std::string> sim;  ///< turncal-sim's fault, none: the whole run
      /// a part of the report's reason, any of them; none: done
      std::vector<std::string> reasons;
      int sync_ms = 0;  ///< sync_period_ms: TPDO1 on our SYNC, its samples dated by it
      /// table.cia402.emcy_warnings, as this drive's manual would list them; none: the
      /// shipped configuration's
      const char* emcy_warnings = nullptr;
    };
    const std::vector<Case> cases = {
        // a drive with the ways of real ones: its SDO answers 2 to 5 ms
        // late, bit 12 up for 50 ms after each enable, no bit 10 in quick
        // stop active, a warning EMCY after each boot-up (error passive,
        // reset once operational) and one 2 s into the turn (0x4210, which
        // this drive's manual would list as a warning): each warning told,
        // none changes anything, the run done, its estimates against the
        // truth as on the reference stand
        {"a drive of real drives' ways, warnings at boot and in the turn: told, the run done",
         {"--fault", "drive-warning-in-move=2", "--drive", "sdo-answer=2:5", "--drive",
          "set-point-ack-after-enable=0.05", "--drive", "no-target-reached-in-quick-stop",
          "--drive", "quick-stop-bit-where-free", "--drive", "warning-at-boot=8120"},
         {},
         0,
         R"(["0x4210", "0x8110", "0x8120", "0x8140"])"},
        // the replay dates each sample by the SYNC's echo in the log, as the
        // live run did: the estimates agree bit for bit
        {"no fault, TPDO1 on our SYNC: the run is done, its replay the same", {}, {}, 100},
        {"a drive fault with EMCY in hold 1", {"--fault", "table-fault=30"}, {"EMCY 0x2310"}},
        {"a following error in hold 1",
         {"--fault", "drive-following-error=30"},
         {"following error"}},
        // the host sees the silence as the loss of the drive's heartbeat or
        // of its TPDOs (encoder, status), whichever of its timeouts ends
        // first; the drive's side is checked on the drive
        {"the drive silent in hold 1: each loses the other",
         {"--fault", "drive-silent=30:5"},
         {"drive heartbeat lost", "table encoder lost", "table status lost"}},
    };
    for (const Case& k : cases) SUBCASE(k.name) {
        hil::TempDir dir;
        std::string sections = cia402_sections();
        if (k.emcy_warnings != nullptr) {
          const std::string key = "\nemcy_warnings = ";
          const auto at = sections.find(key);
          REQUIRE(at != std::string::npos);
          const auto end = sections.find('\n', at + 1);
          sections.replace(at + key.size(), end - at - key.size(), k.emcy_warnings);
        }
        if (k.sync_ms > 0) {
          const std::string key = "\nsync_period_ms = 0\n";
          const auto at = sections.find(key);
          REQUIRE(at != std::string::npos);
          sections.replace(at, key.size(),
                           "\nsync_period_ms = " + std::to_string(k.sync_ms) + "\n");
        }
        write_stand(dir.path, hil::if0(), false, 40, 30, "config/stands/cia402/cia402.dbc",
                    sections);
        std::vector<std::string> args = {"--state-out", "stand.json"};
        args.insert(args.end(), k.sim.begin(), k.sim.end());
        Child sim = start_sim(dir.path, "5", args);
        Child daemon = start_daemon(dir.path);
        REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
        const std::string id = start_run(dir.path);
        const bool done = k.reasons.empty();
        CHECK(ctl(dir.path, {"watch"}, "w.out", 120000ms) == (done ? 0 : 1));
        const json r = report_of(dir.path, id);
        const std::string reason = r.value("reason", std::string());
        CAPTURE(reason);
        CHECK(r["status"] == (done ? "done" : "failed"));
        if (!done) {
          const std::string err = slurp(dir.path / "daemon.err");
          bool named = false;
          for (const std::string& why : k.reasons)
            named = named ||
                    (reason.find(why) != std::string::npos && err.find(why) != std::string::npos);
          CHECK_MESSAGE(named, err);
          CHECK(r["quick_stop"]["sent"] == true);
        }
        // every frame of the run in its log; its replay (an observer, the
        // drive's start-up told from the NMT frames) reaches the phase the
        // live run ended in
        const json rp = replay_of_log(dir.path, id, r);
        std::uint64_t sync_dropped = 0;
        if (done) {
          // the whole run: the replay estimates what the live run did, and
          // that is as near the truth as on the reference stand (its
          // daemon test's checks: the combinations and the determined
          // parameters within 4 sigma, the short plan's four at least)
          CHECK(rp.value("status", std::string()) == "done");
          CHECK(rp["estimates"].dump() == r["estimates"].dump());
          CHECK(rp["turns_achieved"].dump() == r["turns_achieved"].dump());
          if (k.sync_ms > 0) {
            // the rate the SYNCs' (late ticks make it lower, never higher:
            // none goes out within half a period of the last), not the
            // shortest gap between two, and the TPDOs lost counted in
            const json& enc = r["health"]["table_encoder"];
            CAPTURE(enc.dump());
            const double periods = enc["nominal_hz"].get<double>() * k.sync_ms / 1000;
            CHECK(periods > 0.8);  // the guest's ticks a quarter late on average, at worst
            CHECK(periods < 1.02);
            sync_dropped = enc["dropped"].get<std::uint64_t>();
          }
          CHECK(!r["combinations"].empty());
          CHECK(check_against_truth(r, json::parse(slurp(dir.path / "truth.json"))) >= 4);
          keep_artifacts("cia402-run-", {dir.path / "state" / (id + ".report.json"),
                                         dir.path / "state" / r["log"]["file"].get<std::string>(),
                                         dir.path / "truth.json"});
        } else {
          const std::string at = r["phases"][r["phases"].size() - 2]["phase"].get<std::string>();
          bool seen = false;
          for (const auto& ph : rp["phases"]) seen = seen || ph["phase"] == at;
          CHECK_MESSAGE(seen, "the replay never reached " << at << ": " << rp["phases"].dump());
        }
        daemon.terminate();
        CHECK(daemon.wait(10000ms) == 0);
        const json st = stand_state(sim, dir.path);
        REQUIRE(st["drive"].is_object());
        CHECK(st["drive"]["moving"] == false);
        MESSAGE("the drive made " << st["drive"]["tpdos"] << " TPDOs; "
                                  << st["drive"]["tpdo_frames_not_sent_late"]
                                  << " frames of them (TPDO1 and TPDO2) were not sent, as the "
                                     "stand was late");
        // with SYNC, a SYNC the drive did not answer in time (the stand was
        // late, and sent nothing rather than a late TPDO1, or at rest sent
        // it late, or its socket queued it) is the one
        // drop turncald may count; no TPDO2 here, so frames are TPDO1s
        // (or a frame a socket lost: turncald's, which the stand never
        // sees, or the stand's, a SYNC it never read or a TPDO1 it could
        // not send)
        if (k.sync_ms > 0) {
          std::uint64_t socket_dropped = 0;
          for (const auto& [iface, c] : r["can"].items())
            socket_dropped += c.value("rx_dropped", std::uint64_t{0});
          for (const char* lost : {"rx_dropped", "tx_overflow", "tx_failed"})
            socket_dropped += st["bus"][lost].get<std::uint64_t>();
          CHECK(sync_dropped <=
                st["drive"]["tpdo_frames_not_sent_late"].get<std::uint64_t>() +
                    st["drive"]["sync_answer_frames_late_or_queued"].get<std::uint64_t>() +
                    socket_dropped);
        }
        const bool warned = k.sim.size() > 1 && k.sim[1].starts_with("drive-warning-in-move");
        if (done) {
          if (warned) {
            // the drive sent its warning in the turn once, one at each
            // boot-up with its error reset, nothing else; the host told each
            int in_turn = 0, at_boot = 0, other = 0;
            for (const auto& c : st["drive"]["emcy"]) {
              const int code = c.get<int>();
              (code == 0x4210 ? in_turn : code == 0x8120 ? at_boot : code == 0 ? at_boot : other)++;
            }
            CHECK(in_turn == 1);
            CHECK(at_boot >= 1);
            CHECK(other == 0);
            for (const char* code : {"EMCY 0x4210", "EMCY 0x8120"}) {
              CAPTURE(code);
              bool told = false;
              for (const auto& n : r["table_notices"])
                told = told ||
                       n.get<std::string>().find(std::string("the drive warned: ") + code) == 0;
              CHECK_MESSAGE(told, r["table_notices"].dump());
              CHECK(slurp(dir.path / "daemon.err").find(std::string("the drive warned: ") + code) !=
                    std::string::npos);
            }
          } else {
            CHECK(st["drive"]["emcy"].empty());
          }
          CHECK(st["drive"]["quick_stops"] == 0);
          CHECK(std::abs(st["drive"]["angle_deg"].get<double>() - 180) < 0.01);
        } else {
          // the drive is not left enabled
          CHECK(st["drive"]["state"] != "operation enabled");
        }
        // never let go while turning (a test with teeth for the faults in
        // the turn: in hold the table does not move, a coast is not counted)
        CHECK(st["drive"]["coasts"] == 0);
        if (k.sim.size() > 1 && k.sim[1].starts_with("drive-silent"))
          CHECK(st["drive"]["host_heartbeat_lost"].get<int>() >= 1);
      }
  }
}
