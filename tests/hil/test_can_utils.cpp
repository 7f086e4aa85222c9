// Interop with can-utils, both ways: what users already run must read our
// logs, and we must read theirs.
#include <doctest/doctest.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <thread>
#include <vector>

#include "hil.hpp"
#include "process.hpp"
#include "turncal/can/candump.hpp"

using namespace turncal;
using namespace std::chrono_literals;
namespace fs = std::filesystem;
using hil::Child;
using hil::read_log;
using hil::TempDir;

TEST_SUITE("can-utils") {
  TEST_CASE("frames from cansend are read by our socket") {
    auto b = hil::open(hil::if0(), true);
    TempDir dir;
    const char* frames[] = {"123#DEADBEEF", "1F334455#0102030405060708",
                            "321##1AABBCCDDEEFF001122334455", "7FF#R"};
    for (const char* f : frames) {
      Child c({"cansend", hil::if0(), f}, dir.path);
      REQUIRE(c.wait(5000ms) == 0);
    }
    auto rx = hil::receive(b, 4);
    REQUIRE(rx.frames.size() == 4);
    for (std::size_t i = 0; i < 4; ++i) {
      // the same text as cansend was given, through our own formatter
      can::LogRecord rec{0, hil::if0(), rx.frames[i].frame};
      const std::string line = can::format_log_line(rec);
      CHECK(line.substr(line.rfind(' ') + 1) == std::string(frames[i]) + "\n");
    }
    CHECK(rx.frames[2].frame.fd);
    CHECK(rx.frames[2].frame.brs);
    CHECK(rx.frames[3].frame.remote);
  }

  TEST_CASE("a log written by candump -l is read by our reader") {
    TempDir dir;
    constexpr int kFrames = 50;
    Child dump({"candump", "-l", "-n", std::to_string(kFrames), hil::if0()}, dir.path);
    // candump opens its log file once its socket is bound
    const auto end = std::chrono::steady_clock::now() + 5s;
    fs::path log;
    while (log.empty() && std::chrono::steady_clock::now() < end) {
      for (const auto& e : fs::directory_iterator(dir.path))
        if (e.path().extension() == ".log") log = e.path();
      std::this_thread::sleep_for(20ms);
    }
    REQUIRE_FALSE(log.empty());
    auto a = hil::open(hil::if0());
    std::vector<can::Frame> sent;
    const std::int64_t t0 = socketcan::realtime_ns();
    for (int i = 0; i < kFrames; ++i) {
      auto f = (i % 3 == 0) ? hil::frame(0x1000000u + static_cast<std::uint32_t>(i),
                                         {1, 2, static_cast<std::uint8_t>(i)}, true)
                            : hil::frame(0x100u + static_cast<std::uint32_t>(i),
                                         {static_cast<std::uint8_t>(i)});
      REQUIRE(a.send(f).ok());
      sent.push_back(f);
      if (i % 10 == 0) std::this_thread::sleep_for(2ms);
    }
    REQUIRE(dump.wait(10000ms) == 0);
    const std::int64_t t1 = socketcan::realtime_ns();
    auto recs = read_log(log);
    REQUIRE(recs.size() == sent.size());
    for (std::size_t i = 0; i < recs.size(); ++i) {
      CHECK(recs[i].frame == sent[i]);
      CHECK(recs[i].interface == hil::if0());
      CHECK(recs[i].time_ns >= t0 - 1000);  // the log has microseconds
      CHECK(recs[i].time_ns <= t1);
    }
  }

  TEST_CASE("a log of ours is played by canplayer and seen by candump") {
    TempDir dir;
    const fs::path ours = dir.path / "ours.log";
    std::vector<can::Frame> frames;
    {
      auto w = can::LogWriter::open(ours.string());
      REQUIRE(w.ok());
      const std::int64_t base = 1'700'000'000'000'000'000;
      for (int i = 0; i < 30; ++i) {
        can::LogRecord r;
        r.time_ns = base + i * 1'000'000LL;  // 1 ms apart
        r.interface = hil::if0();
        if (i % 5 == 4) {
          r.frame.fd = true;
          r.frame.id = 0x300;
          r.frame.len = 16;
          for (std::size_t k = 0; k < 16; ++k)
            r.frame.data[k] = static_cast<std::uint8_t>(i + static_cast<int>(k));
        } else {
          r.frame = hil::frame(0x200u + static_cast<std::uint32_t>(i),
                               {static_cast<std::uint8_t>(i), 0xAA}, i % 2 == 1);
        }
        frames.push_back(r.frame);
        REQUIRE(w->write(r).ok());
      }
      REQUIRE(w->close().ok());
    }
    const fs::path seen = dir.path / "seen.log";
    Child dump({"candump", "-L", "-n", "30", hil::if0()}, dir.path, seen);
    std::this_thread::sleep_for(700ms);  // let candump bind before playing
    Child play({"canplayer", "-I", ours.string()}, dir.path);
    REQUIRE(play.wait(10000ms) == 0);
    REQUIRE(dump.wait(10000ms) == 0);
    auto recs = read_log(seen);
    REQUIRE(recs.size() == frames.size());
    for (std::size_t i = 0; i < recs.size(); ++i) CHECK(recs[i].frame == frames[i]);
    // canplayer paces by the log's timestamps (29 ms from first to last);
    // its scheduling loop is coarse, so only pacing at all is asserted: with
    // timestamps ignored the 30 frames would leave within a millisecond.
    CHECK(recs.back().time_ns - recs.front().time_ns >= 15'000'000);
  }
}
