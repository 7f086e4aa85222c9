#include <doctest/doctest.h>

#include <chrono>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>
#include <utility>
#include <vector>

#include "hil.hpp"

using namespace turncal;
using namespace std::chrono_literals;

namespace {

/// Packets dropped by the kernel's per-CPU input backlog (second column of
/// /proc/net/softnet_stat, hex), which no socket counts.
std::uint64_t backlog_drops() {
  std::ifstream in("/proc/net/softnet_stat");
  std::uint64_t total = 0;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string processed, dropped;
    ls >> processed >> dropped;
    total += std::stoull(dropped, nullptr, 16);
  }
  return total;
}

}  // namespace

TEST_SUITE("socketcan") {
  TEST_CASE("an interface's link kind tells a virtual CAN bus from any other") {
    const auto kind = socketcan::link_kind(hil::if0());
    REQUIRE(kind);
    CHECK(*kind == "vcan");
    CHECK(socketcan::require_virtual_can(hil::if0()));
    // the loopback interface registers no link kind, as a real device's does not
    const auto lo = socketcan::link_kind("lo");
    REQUIRE(lo);
    CHECK(lo->empty());
    const Status lo_virtual = socketcan::require_virtual_can("lo");
    REQUIRE_FALSE(lo_virtual);
    CHECK(lo_virtual.error().describe() == "lo is not a virtual CAN bus (a device's interface)");
    const auto none = socketcan::link_kind("tcnone0");
    REQUIRE_FALSE(none);
    CHECK(none.error().describe().find("tcnone0") != std::string::npos);
  }
  TEST_CASE("frames go from one socket to another") {
    auto a = hil::open(hil::if0());
    auto b = hil::open(hil::if0());
    const auto f1 = hil::frame(0x123, {0xDE, 0xAD, 0xBE, 0xEF});
    const auto f2 = hil::frame(0x1ABCDEF0, {1, 2, 3, 4, 5, 6, 7, 8}, true);
    REQUIRE(a.send(f1).ok());
    REQUIRE(a.send(f2).ok());
    auto rx = hil::receive(b, 2);
    REQUIRE(rx.frames.size() == 2);
    CHECK(rx.frames[0].frame == f1);
    CHECK(rx.frames[1].frame == f2);
    CHECK(a.stats().tx_frames == 2);
    CHECK(b.stats().rx_frames == 2);
    // the sender does not see its own frames unless asked to
    auto own = hil::receive(a, 1, 100ms);
    CHECK(own.frames.empty());
  }

  TEST_CASE("our frames' echoes come in the bus's order among the frames that answer them") {
    // a master's SYNC and the drive's TPDO1 that answers it, three times:
    // the master reads each SYNC's echo before its answer (in_order), as
    // the SYNC's time dates that answer
    socketcan::Options o;
    o.interface = hil::if0();
    o.confirm = true;
    auto master = hil::open(o);
    auto drive = hil::open(hil::if0());
    for (std::uint8_t k = 0; k < 3; ++k) {
      REQUIRE(master.send(hil::frame(0x080, {k})).ok());
      REQUIRE(hil::receive(drive, 1).frames.size() == 1);  // the drive hears it
      REQUIRE(drive.send(hil::frame(0x185, {k})).ok());    // and answers
    }
    const socketcan::RxBatch rx = hil::receive(master, 3);
    REQUIRE(rx.frames.size() == 3);
    REQUIRE(rx.confirmed.size() == 3);
    std::vector<std::pair<std::uint32_t, bool>> order;
    std::vector<std::uint8_t> counters;
    std::int64_t last_ns = 0;
    bool monotonic = true;
    rx.in_order([&](const can::TimedFrame& f, bool echoed) {
      order.emplace_back(f.frame.id, echoed);
      counters.push_back(f.frame.data[0]);
      monotonic = monotonic && f.time_ns >= last_ns;
      last_ns = f.time_ns;
    });
    const std::vector<std::pair<std::uint32_t, bool>> bus = {{0x080, true}, {0x185, false},
                                                             {0x080, true}, {0x185, false},
                                                             {0x080, true}, {0x185, false}};
    CHECK(order == bus);
    CHECK(counters == std::vector<std::uint8_t>{0, 0, 1, 1, 2, 2});
    CHECK(monotonic);  // the stamps in the order read
    CHECK(master.stats().tx_confirmed == 3);
  }

  TEST_CASE("the kernel filters by the configured IDs") {
    socketcan::Options o;
    o.interface = hil::if0();
    o.filters = {{0x123, false, 0}, {0x10000000, true, 0x1FFFFFF0}};
    auto b = hil::open(o);
    auto a = hil::open(hil::if0());
    const std::pair<can::Frame, bool> cases[] = {
        {hil::frame(0x123, {1}), true},
        {hil::frame(0x124, {2}), false},
        {hil::frame(0x123, {3}, true), false},      // same number, extended: another ID
        {hil::frame(0x10000005, {4}, true), true},  // inside the masked range
        {hil::frame(0x10000015, {5}, true), false},
    };
    for (const auto& [f, pass] : cases) REQUIRE(a.send(f).ok());
    auto rx = hil::receive(b, 2, 300ms);
    REQUIRE(rx.frames.size() == 2);
    CHECK(rx.frames[0].frame.data[0] == 1);
    CHECK(rx.frames[1].frame.data[0] == 4);
  }

  TEST_CASE("CAN FD frames travel on FD sockets, and classic sockets do not see them") {
    auto a = hil::open(hil::if0(), true);
    auto b = hil::open(hil::if0(), true);
    auto classic = hil::open(hil::if0(), false);
    can::Frame fd;
    fd.id = 0x321;
    fd.fd = true;
    fd.brs = true;
    fd.len = 64;
    for (std::size_t i = 0; i < 64; ++i) fd.data[i] = static_cast<std::uint8_t>(i * 3);
    const auto cl = hil::frame(0x322, {9, 8, 7});
    REQUIRE(a.send(fd).ok());
    REQUIRE(a.send(cl).ok());
    auto rx = hil::receive(b, 2);
    REQUIRE(rx.frames.size() == 2);
    CHECK(rx.frames[0].frame == fd);
    CHECK(rx.frames[1].frame == cl);
    auto rc = hil::receive(classic, 2, 200ms);
    REQUIRE(rc.frames.size() == 1);
    CHECK(rc.frames[0].frame == cl);
    // and a classic socket refuses to send one
    CHECK_FALSE(classic.send(fd).ok());
  }

  TEST_CASE("receive timestamps are monotonic and near the host clock") {
    auto a = hil::open(hil::if0());
    auto b = hil::open(hil::if0());
    const std::int64_t before = socketcan::realtime_ns();
    for (int i = 0; i < 100; ++i) {
      REQUIRE(a.send(hil::frame(0x100, {static_cast<std::uint8_t>(i)})).ok());
      if (i % 10 == 0) std::this_thread::sleep_for(1ms);
    }
    auto rx = hil::receive(b, 100);
    const std::int64_t after = socketcan::realtime_ns();
    REQUIRE(rx.frames.size() == 100);
    for (std::size_t i = 0; i < rx.frames.size(); ++i) {
      CHECK(rx.frames[i].time_ns >= before);
      CHECK(rx.frames[i].time_ns <= after);
      if (i > 0) CHECK(rx.frames[i].time_ns >= rx.frames[i - 1].time_ns);
      CHECK(rx.frames[i].frame.data[0] == i);
    }
    // the sleeps show up: the stamps are the kernel's, not the read's
    CHECK(rx.frames.back().time_ns - rx.frames.front().time_ns >= 9'000'000);
  }

  TEST_CASE("a flood overflows the receive queue and every lost frame is counted") {
    socketcan::Options o;
    o.interface = hil::if0();
    o.rcvbuf_bytes = 4096;  // the kernel's minimum, a few dozen frames
    auto b = hil::open(o);
    socketcan::Options ao;
    ao.interface = hil::if0();
    ao.tx_queue_limit = 1 << 16;
    auto a = hil::open(ao);
    const std::uint64_t backlog0 = backlog_drops();
    constexpr int kFlood = 5000;
    for (int i = 0; i < kFlood; ++i)
      REQUIRE(a.send(hil::frame(0x200, {static_cast<std::uint8_t>(i)})).ok());
    while (a.flush() > 0) std::this_thread::sleep_for(1ms);
    socketcan::RxBatch rx;
    REQUIRE(b.receive(rx, 1000).ok());
    // SO_RXQ_OVFL reports drops with the next frame queued after them.
    REQUIRE(a.send(hil::frame(0x201, {0xFF})).ok());
    auto tail = hil::receive(b, 1);
    REQUIRE(tail.frames.size() == 1);
    const std::uint64_t sent = a.stats().tx_frames;
    const std::uint64_t received = rx.frames.size() + tail.frames.size();
    const std::uint64_t backlog = backlog_drops() - backlog0;
    MESSAGE("sent " << sent << ", received " << received << ", socket drops "
                    << b.stats().rx_dropped << ", backlog drops " << backlog);
    CHECK(sent == kFlood + 1);
    CHECK(b.stats().rx_dropped > 0);
    CHECK(received + b.stats().rx_dropped + backlog == sent);
  }

  TEST_CASE(
      "a full kernel send queue never blocks: frames wait in a bounded queue, the rest are "
      "counted") {
    // A token-bucket qdisc with a tiny limit makes the kernel refuse frames
    // with ENOBUFS, as a real controller's full queue does.
    const std::string name = "tchil8";
    hil::sh("ip link del " + name + " 2>/dev/null");
    REQUIRE(hil::sh("ip link add dev " + name + " type vcan && ip link set " + name + " up") == 0);
    REQUIRE(hil::sh("tc qdisc add dev " + name + " root tbf rate 1kbit burst 2000 limit 64") == 0);
    socketcan::Options o;
    o.interface = name;
    o.tx_queue_limit = 8;
    auto a = hil::open(o);
    constexpr int kFrames = 400;
    for (int i = 0; i < kFrames; ++i)
      REQUIRE(a.send(hil::frame(0x55, {static_cast<std::uint8_t>(i)})).ok());
    const auto& st = a.stats();
    MESSAGE("sent " << st.tx_frames << ", waiting " << (a.tx_pending() ? st.tx_queued : 0)
                    << ", overflow " << st.tx_overflow);
    CHECK(a.tx_pending());
    CHECK(st.tx_queued == 8);
    CHECK(st.tx_overflow > 0);
    CHECK(st.tx_frames + st.tx_queued + st.tx_overflow == kFrames);
    hil::sh("ip link del " + name);
  }

  TEST_CASE(
      "an urgent frame goes first, replaces the waiting frames of its ID, and a full queue makes "
      "room for it") {
    // the kernel refuses frames (ENOBUFS) behind a token bucket, until it
    // is removed; another socket on the interface sees what goes out. At 8
    // bit/s the bucket frees room for a frame every 16 s: no pause of the
    // guest lets one more through while the test fills the queue.
    const std::string name = "tchil9";
    hil::sh("ip link del " + name + " 2>/dev/null");
    REQUIRE(hil::sh("ip link add dev " + name + " type vcan && ip link set " + name + " up") == 0);
    REQUIRE(hil::sh("tc qdisc add dev " + name + " root tbf rate 8bit burst 2000 limit 64") == 0);
    socketcan::Options o;
    o.interface = name;
    o.tx_queue_limit = 8;
    auto a = hil::open(o);
    auto b = hil::open(name);
    // moves (ID 0x55) until eight wait
    int moves = 0;
    while (a.stats().tx_queued < 8 && moves < 1000)
      REQUIRE(a.send(hil::frame(0x55, {static_cast<std::uint8_t>(moves++)})).ok());
    REQUIRE(a.tx_queue_depth() == 8);
    // the stop (also 0x55) replaces the eight moves
    auto r = a.send_urgent(hil::frame(0x55, {0xEE}));
    REQUIRE(r.ok());
    CHECK(*r == socketcan::TxOutcome::Queued);
    CHECK(a.stats().tx_superseded == 8);
    CHECK(a.tx_queue_depth() == 1);
    // seven heartbeats (0x66) fill the queue behind it; an eighth overflows
    for (std::uint8_t i = 0; i < 8; ++i) REQUIRE(a.send(hil::frame(0x66, {i})).ok());
    CHECK(a.tx_queue_depth() == 8);
    CHECK(a.stats().tx_overflow == 1);
    // an urgent frame of another ID: the newest heartbeat makes room
    r = a.send_urgent(hil::frame(0x77, {0x01}));
    REQUIRE(r.ok());
    CHECK(*r == socketcan::TxOutcome::Queued);
    CHECK(a.tx_queue_depth() == 8);
    CHECK(a.stats().tx_overflow == 2);
    // the bucket gone, what waits goes out in its order
    REQUIRE(hil::sh("tc qdisc del dev " + name + " root") == 0);
    for (int i = 0; i < 100 && a.flush() > 0; ++i) std::this_thread::sleep_for(10ms);
    CHECK_FALSE(a.tx_pending());
    const auto got = hil::receive(b, 1000, 1000ms);
    REQUIRE(got.frames.size() >= 8);
    const auto last8 = std::vector<can::TimedFrame>(got.frames.end() - 8, got.frames.end());
    CHECK(last8[0].frame.id == 0x77);
    CHECK(last8[1].frame.id == 0x55);
    CHECK(last8[1].frame.data[0] == 0xEE);
    for (std::size_t i = 2; i < 8; ++i) {
      CHECK(last8[i].frame.id == 0x66);
      CHECK(last8[i].frame.data[0] == i - 2);  // the heartbeats in order, the 7th made room
    }
    // no move that waited went out after the stop
    bool move_after_stop = false, stop_seen = false;
    for (const auto& f : got.frames) {
      if (f.frame.id == 0x55 && f.frame.data[0] == 0xEE)
        stop_seen = true;
      else if (f.frame.id == 0x55 && stop_seen)
        move_after_stop = true;
    }
    CHECK(stop_seen);
    CHECK_FALSE(move_after_stop);
    hil::sh("ip link del " + name);
  }

  TEST_CASE("an interface that goes down and comes back up is recovered") {
    auto b = hil::open(hil::if1());
    REQUIRE(hil::sh("ip link set " + hil::if1() + " down") == 0);
    auto rx = hil::receive(b, 1, 300ms);
    REQUIRE(rx.events.size() == 1);
    CHECK(rx.events[0].kind == can::BusEventKind::InterfaceDown);
    CHECK(b.link() == socketcan::LinkState::Down);
    CHECK_FALSE(b.try_recover(rx));
    REQUIRE(hil::sh("ip link set " + hil::if1() + " up") == 0);
    socketcan::RxBatch ev;
    CHECK(b.try_recover(ev));
    REQUIRE(ev.events.size() == 1);
    CHECK(ev.events[0].kind == can::BusEventKind::InterfaceBack);
    auto a = hil::open(hil::if1());
    REQUIRE(a.send(hil::frame(0x42, {1})).ok());
    auto after = hil::receive(b, 1);
    REQUIRE(after.frames.size() == 1);
    CHECK(after.frames[0].frame.id == 0x42);
  }

  TEST_CASE("an interface that goes down while a frame is written: the write's error is the news") {
    // the kernel's send path takes the socket's NETDEV_DOWN error before a
    // receive can (a daemon's tick writes its heartbeat before it reads):
    // the loss must be reported all the same
    auto b = hil::open(hil::if1());
    REQUIRE(hil::sh("ip link set " + hil::if1() + " down") == 0);
    auto sent = b.send(hil::frame(0x43, {1}));
    REQUIRE(sent.ok());
    CHECK(*sent == socketcan::TxOutcome::Dropped);
    socketcan::RxBatch rx;
    REQUIRE(b.receive(rx).ok());
    REQUIRE(rx.events.size() == 1);
    CHECK(rx.events[0].kind == can::BusEventKind::InterfaceDown);
    CHECK(b.link() == socketcan::LinkState::Down);
    REQUIRE(hil::sh("ip link set " + hil::if1() + " up") == 0);
    socketcan::RxBatch ev;
    CHECK(b.try_recover(ev));
    REQUIRE(ev.events.size() == 1);
    CHECK(ev.events[0].kind == can::BusEventKind::InterfaceBack);
  }

  TEST_CASE("an interface deleted and re-created is recovered without reopening by hand") {
    const std::string name = "tchil9";
    hil::sh("ip link del " + name + " 2>/dev/null");
    REQUIRE(hil::sh("ip link add dev " + name + " type vcan && ip link set " + name + " up") == 0);
    auto b = hil::open(name);
    REQUIRE(hil::sh("ip link del " + name) == 0);
    auto rx = hil::receive(b, 1, 300ms);
    bool gone = false;
    for (const auto& e : rx.events) gone = gone || e.kind == can::BusEventKind::InterfaceGone;
    CHECK(gone);
    CHECK(b.link() == socketcan::LinkState::Gone);
    CHECK(b.fd() == -1);
    CHECK_FALSE(b.try_recover(rx));
    // sending while gone loses the frame, counted, and never blocks
    REQUIRE(b.send(hil::frame(0x1, {1})).ok());
    CHECK(b.stats().tx_failed == 1);
    REQUIRE(hil::sh("ip link add dev " + name + " type vcan") == 0);
    CHECK_FALSE(b.try_recover(rx));  // exists, but is not up yet
    CHECK(b.link() == socketcan::LinkState::Down);
    REQUIRE(hil::sh("ip link set " + name + " up") == 0);
    CHECK(b.try_recover(rx));
    CHECK(b.fd() >= 0);
    CHECK(b.stats().recoveries == 1);
    auto a = hil::open(name);
    REQUIRE(a.send(hil::frame(0x43, {2})).ok());
    auto after = hil::receive(b, 1);
    REQUIRE(after.frames.size() == 1);
    CHECK(after.frames[0].frame.id == 0x43);
    hil::sh("ip link del " + name);
  }

  TEST_CASE("error frames arrive as bus events") {
    auto a = hil::open(hil::if0());
    auto b = hil::open(hil::if0());
    can::Frame err;
    err.error = true;
    err.id = 0x040 | 0x004;  // bus-off, controller problem
    err.len = 8;
    err.data[1] = 0x20;  // tx passive
    REQUIRE(a.send(err).ok());
    REQUIRE(a.send(hil::frame(0x7, {7})).ok());
    auto rx = hil::receive(b, 1);
    REQUIRE(rx.frames.size() == 1);
    std::set<can::BusEventKind> kinds;
    for (const auto& e : rx.events) kinds.insert(e.kind);
    CHECK(kinds.count(can::BusEventKind::BusOff) == 1);
    CHECK(kinds.count(can::BusEventKind::ControllerProblem) == 1);
    CHECK(b.stats().rx_error_frames == 1);
  }
}
