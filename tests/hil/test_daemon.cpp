// turncald on a real SocketCAN stack with turncal-sim as the stand,
// driven through turncalctl: a short experiment end to end, an abort during
// the turn, malformed and oversized control requests.
#include <doctest/doctest.h>

#include <sys/socket.h>
#include <sys/un.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "hil.hpp"
#include "process.hpp"

using namespace turncal;
using hil::Child;
using namespace std::chrono_literals;

namespace {

const std::string kSim = TURNCAL_SIM_BIN;
const std::string kDaemon = TURNCAL_DAEMON_BIN;
const std::string kCtl = TURNCAL_CTL_BIN;
const std::string kSrc = TURNCAL_SOURCE_DIR;
// The stand at 4x with its fast streams at 25 Hz (the ICD: velocity 100 Hz,
// encoder 200 Hz). At the ICD's rates and 4x, "stale after 10 periods" is
// 12 ms of real time, shorter than the scheduling slack of a user-mode Linux
// guest running the stand, the daemon and the tests on one virtual CPU.
constexpr int kSpeed = 4;
constexpr const char* kRates = "25:25";

/// A short plan (20 s alignment, 120 s, +180 deg at 60 s) and a daemon
/// configuration for it, in `dir`.
void write_stand(const hil::fs::path& dir, const std::string& iface) {
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
  set("duration_s", "120");
  set("align_s", "20");
  set("start_s", "60");
  std::ofstream(dir / "short.toml") << plan;
  std::ofstream(dir / "turncal.toml")
      << "[can]\nins_interface = \"" << iface << "\"\ntable_interface = \"" << iface
      << "\"\ndbc = [\"" << kSrc << "/config/reference-stand.dbc\"]\n"
      << "[stand]\ntime_scale = " << kSpeed << "\n"
      << "[daemon]\nstate_directory = \"" << (dir / "state").string() << "\"\nsocket = \""
      << (dir / "control.sock").string() << "\"\nprofile = \"short.toml\"\n";
}

std::string slurp(const hil::fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Sends raw bytes to the control socket; the first reply line.
std::string raw_request(const hil::fs::path& sock, const std::string& bytes) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::strcpy(a.sun_path, sock.c_str());
  REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  (void)!::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
  std::string out;
  char c;
  while (::recv(fd, &c, 1, 0) == 1 && c != '\n') out += c;
  ::close(fd);
  return out;
}

bool wait_for(const hil::fs::path& p, std::chrono::milliseconds t) {
  for (auto end = std::chrono::steady_clock::now() + t; std::chrono::steady_clock::now() < end;
       std::this_thread::sleep_for(20ms))
    if (hil::fs::exists(p)) return true;
  return false;
}

}  // namespace

TEST_SUITE("daemon") {
  TEST_CASE("turncald runs a short experiment on the virtual stand through turncalctl") {
    hil::TempDir dir;
    write_stand(dir.path, hil::if0());
    Child sim({kSim, "--config", (dir.path / "turncal.toml").string(), "--profile",
               (dir.path / "short.toml").string(), "--speed", std::to_string(kSpeed), "--rates",
               kRates, "--seed", "3", "--truth", "truth.json"},
              dir.path);
    Child daemon({kDaemon, "--config", (dir.path / "turncal.toml").string()}, dir.path);
    REQUIRE(wait_for(dir.path / "control.sock", 5000ms));
    const std::string sock = (dir.path / "control.sock").string();

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

    Child start({kCtl, "--socket", sock, "start", "--watch"}, dir.path, dir.path / "watch.out");
    REQUIRE(start.wait(120000ms) == 0);
    Child list({kCtl, "--socket", sock, "--json", "reports"}, dir.path, dir.path / "list.json");
    REQUIRE(list.wait(5000ms) == 0);
    const auto reports = nlohmann::json::parse(slurp(dir.path / "list.json"));
    REQUIRE(reports["reports"].size() == 1);
    const std::string id = reports["reports"][0]["run_id"];
    Child show({kCtl, "--socket", sock, "--json", "show", id}, dir.path, dir.path / "report.json");
    REQUIRE(show.wait(5000ms) == 0);
    const auto r = nlohmann::json::parse(slurp(dir.path / "report.json"));
    CHECK(r["status"] == "done");
    REQUIRE(r["estimates"].size() == 20);
    // the log in the state directory is the one the report names, intact
    const std::string log = slurp(dir.path / "state" / r["log"]["file"].get<std::string>());
    CHECK(log.size() > 100000);
    // against the truth: the sharp combinations within 4 sigma
    const auto truth = nlohmann::json::parse(slurp(dir.path / "truth.json"));
    REQUIRE(!r["combinations"].empty());
    for (const auto& c : r["combinations"]) {
      CAPTURE(c.dump());
      double tv = 0;
      for (const auto& [name, k] : c["coefficients"].items())
        tv += k.get<double>() * truth["errors"][name].get<double>();
      CHECK(std::abs(c["value"].get<double>() - tv) <= 4 * c["sigma"].get<double>());
    }
    // a second run, aborted during the turn: the table quick-stops
    Child again({kCtl, "--socket", sock, "start"}, dir.path);
    REQUIRE(again.wait(5000ms) == 0);
    for (int i = 0; i < 400; ++i) {
      Child st({kCtl, "--socket", sock, "--json", "status"}, dir.path, dir.path / "st.json");
      REQUIRE(st.wait(5000ms) == 0);
      if (slurp(dir.path / "st.json").find("\"phase\": \"turn\"") != std::string::npos) break;
      std::this_thread::sleep_for(50ms);
    }
    Child abort({kCtl, "--socket", sock, "abort"}, dir.path);
    CHECK(abort.wait(5000ms) == 0);
    Child watch({kCtl, "--socket", sock, "watch"}, dir.path, dir.path / "w2.out");
    CHECK(watch.wait(20000ms) == 1);  // the watched run ended aborted
    Child list2({kCtl, "--socket", sock, "--json", "reports"}, dir.path, dir.path / "list2.json");
    REQUIRE(list2.wait(5000ms) == 0);
    const auto reports2 = nlohmann::json::parse(slurp(dir.path / "list2.json"));
    REQUIRE(reports2["reports"].size() == 2);
    const std::string id2 = reports2["reports"][1]["run_id"];
    const auto r2 = nlohmann::json::parse(slurp(dir.path / "state" / (id2 + ".report.json")));
    CHECK(r2["status"] == "aborted");
    CHECK(r2["phases"].back()["phase"] == "aborted");
    CHECK(r2["quick_stop"]["sent"] == true);
    CHECK(r2["quick_stop"]["acknowledged"] == true);

    daemon.terminate();
    CHECK(daemon.wait(10000ms) == 0);
    sim.terminate();
    sim.wait(5000ms);
  }
}
