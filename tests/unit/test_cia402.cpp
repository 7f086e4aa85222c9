// The CiA 402 master against the virtual CiA 402 drive, in closed loop in
// process: every frame passes both ways, time steps by 1 ms. Each test
// checks the drive's own account as well as the master's.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/drivers/canopen.hpp"
#include "turncal/drivers/cia402.hpp"
#include "turncal/sim/virtual_drive402.hpp"

using namespace turncal;
using cia402::FaultCode;
using cia402::State;
using DriveState = stand::facts::State;  // the virtual drive's own, from CiA 402
using stand::VirtualDrive402;

namespace {

constexpr double kDeg = 0.017453292519943295;
constexpr double kTwoPi = 6.283185307179586;
// the master's rate window (0.1 to 0.2 s at this drive's counts) and a TPDO
constexpr double kRateWindowS = 0.25;

/// An EMCY code the master takes for a fault (current, CiA 301 0x23xx)
/// sent by a drive that goes on, no fault bit in its statusword: a drive
/// that classes its codes otherwise than the master does.
constexpr std::uint16_t kFaultClassCode = 0x2310;

/// 10000 counts per motor turn, 100 motor turns per table turn: 1e6
/// counts per table revolution, one count 6.3e-6 rad.
cia402::MasterSettings master_settings() {
  cia402::MasterSettings s;
  s.node_id = 5;
  s.host_node_id = 127;
  s.counts_per_rev = 10000;
  s.gear_ratio = 100;
  s.profile_velocity_rps = 30 * kDeg;
  s.profile_acceleration_rps2 = 60 * kDeg;
  s.profile_deceleration_rps2 = 40 * kDeg;  // unlike the acceleration: the trapezoid is asymmetric
  s.quick_stop_deceleration_rps2 = 180 * kDeg;
  return s;
}

stand::Drive402Setup drive_setup() {
  stand::Drive402Setup d;
  d.node_id = 5;
  d.counts_per_rev = 10000;
  d.gear_ratio = 100;
  d.tpdo_event_timer_ms = 10;
  return d;
}

/// The master and the drive on one bus.
struct Loop {
  explicit Loop(cia402::MasterSettings ms = master_settings(),
                stand::Drive402Setup ds = drive_setup(), stand::Drive402Faults df = {})
      : master(ms), drive(ds, df) {}
  /// The master in a mode of operation of the test's.
  Loop(const cia402::Master::ModeFactory& mode, cia402::MasterSettings ms,
       stand::Drive402Setup ds = drive_setup())
      : master(ms, mode), drive(ds, {}) {}

  cia402::Master master;
  VirtualDrive402 drive;
  double t = 0;
  std::vector<can::Frame> from_master;
  std::vector<stand::DriveFrame> from_drive;
  std::vector<double> sync_times;
  std::vector<can::Frame> sent;  ///< everything the master sent
  std::vector<cia402::EncoderSample> samples;
  bool saw_moving = false;
  /// From when the master configures, the drive's frames are held back
  /// (the drive still hears everything): a drive slow to answer.
  bool hold_when_configuring = false;
  /// Changes a drive frame on its way to the master (a drive's PDO that
  /// says something else than its objects do).
  std::function<void(can::Frame&)> tamper;

  void deliver() {
    const auto held = [&] {
      return hold_when_configuring && master.phase() == cia402::CommPhase::Configuring;
    };
    while (!from_master.empty() || (!from_drive.empty() && !held())) {
      std::vector<can::Frame> m;
      m.swap(from_master);
      for (const can::Frame& f : m) {
        sent.push_back(f);
        if (f.id == canopen::kSyncId) sync_times.push_back(t);
        drive.receive(t, f, from_drive);
        // the bus's echo of our SYNC and NMT, as the kernel gives it
        if (f.id == canopen::kSyncId || f.id == 0) master.on_frame(f, t, from_master);
      }
      if (held()) continue;
      std::vector<stand::DriveFrame> d;
      d.swap(from_drive);
      for (stand::DriveFrame& f : d) {
        if (tamper) tamper(f.frame);
        master.on_frame(f.frame, f.t_s, from_master);
      }
    }
    if (master.status().state == TableState::Moving) saw_moving = true;
  }
  void step(double dt = 1e-3) {
    t += dt;
    drive.advance(t, from_drive);
    deliver();
    master.tick(t, from_master);
    deliver();
    master.take_samples(samples);
  }
  void start() {
    master.start(t, from_master);
    deliver();
  }
  void run_for(double seconds) {
    const double end = t + seconds;
    while (t < end - 1e-9) step();
  }
  /// Steps until `done` or `timeout` seconds pass; true when done.
  template <class Pred>
  bool run_until(Pred done, double timeout) {
    const double end = t + timeout;
    while (t < end) {
      if (done()) return true;
      step();
    }
    return done();
  }
  Status command(TableCommandCode c, std::uint8_t seq, double target = 0, double rate = 0) {
    Status s = master.command(c, seq, target, rate, t, from_master);
    deliver();
    return s;
  }
  bool running() {
    return run_until([&] { return master.phase() == cia402::CommPhase::Running; }, 2.0);
  }
  bool enabled(std::uint8_t seq) {
    if (!command(TableCommandCode::Enable, seq)) return false;
    return run_until(
        [&] { return master.status().state == TableState::Holding && master.status().ack == seq; },
        1.0);
  }
  /// Started, enabled (seq 1), a relative move of `deg` at `dps` (seq 2)
  /// sent, and `seconds` run on: the table turning, for a fault in a move.
  bool turning(double seconds, double deg = 360, double dps = 30) {
    start();
    if (!running() || !enabled(1) ||
        !command(TableCommandCode::MoveRelative, 2, deg * kDeg, dps * kDeg))
      return false;
    run_for(seconds);
    return true;
  }
  /// Steps for `seconds`: how many steps the master's rate was known, and
  /// how many of those it read kTableAtRestRps or more.
  struct RateTally {
    int known = 0, over = 0;
  };
  RateTally rates_for(double seconds) {
    RateTally n;
    for (const double end = t + seconds; t < end; step()) {
      const double rate = master.status().rate_rps;
      n.known += std::isfinite(rate);
      n.over += std::isfinite(rate) && std::abs(rate) >= kTableAtRestRps;
    }
    return n;
  }
  /// The statusword reads (SDO upload requests of 0x6041) the master sent,
  /// from the `from`th frame it sent on.
  [[nodiscard]] int statusword_reads(std::size_t from = 0) const {
    int n = 0;
    for (std::size_t i = from; i < sent.size(); ++i) {
      const can::Frame& f = sent[i];
      n += f.id == canopen::kSdoRxBase + master.settings().node_id && f.data[0] == 0x40 &&
           f.data[1] == 0x41 && f.data[2] == 0x60;
    }
    return n;
  }
  bool in_position(std::uint8_t seq, double timeout) {
    return run_until(
        [&] {
          return master.status().state == TableState::InPosition && master.status().ack == seq;
        },
        timeout);
  }
};

/// The drive's over-current fault (EMCY 0x2310) at 2 s.
stand::Drive402Faults over_current_at_2s() {
  stand::Drive402Faults df;
  df.fault_at_s = 2.0;
  df.fault_code = 0x2310;
  return df;
}

/// The duration of a trapezoid of `dist` at peak v, acceleration a, deceleration d.
double trapezoid_s(double dist, double v, double a, double d) {
  if (dist < v * v / (2 * a) + v * v / (2 * d)) {
    const double w = std::sqrt(2 * dist * a * d / (a + d));
    return w / a + w / d;
  }
  return dist / v + v / (2 * a) + v / (2 * d);
}

}  // namespace

TEST_SUITE("cia402") {
  TEST_CASE("statusword states and controlword commands as CiA 402 codes them") {
    CHECK(cia402::decode_state(0x0000) == State::NotReadyToSwitchOn);
    CHECK(cia402::decode_state(0x0250) == State::SwitchOnDisabled);  // remote, voltage bits ignored
    CHECK(cia402::decode_state(0x0231) == State::ReadyToSwitchOn);
    CHECK(cia402::decode_state(0x0233) == State::SwitchedOn);
    CHECK(cia402::decode_state(0x1637) == State::OperationEnabled);  // with bits 10, 12
    CHECK(cia402::decode_state(0x0217) == State::QuickStopActive);
    CHECK(cia402::decode_state(0x021F) == State::FaultReactionActive);
    CHECK(cia402::decode_state(0x0218) == State::Fault);
    CHECK(cia402::decode_state(0x0208) == State::Fault);
    CHECK(cia402::decode_state(0x0061) ==
          State::Unknown);  // switch on disabled with ready: no state
    using C = cia402::Command;
    CHECK(cia402::decode_command(0x06, 0) == C::Shutdown);
    CHECK(cia402::decode_command(0x07, 0) == C::SwitchOn);
    CHECK(cia402::decode_command(0x0F, 0) == C::EnableOperation);
    CHECK(cia402::decode_command(0x1F, 0x0F) == C::EnableOperation);  // set-point bits aside
    CHECK(cia402::decode_command(0x00, 0) == C::DisableVoltage);
    CHECK(cia402::decode_command(0x0D, 0) == C::DisableVoltage);
    CHECK(cia402::decode_command(0x02, 0) == C::QuickStop);
    CHECK(cia402::decode_command(0x0B, 0) == C::QuickStop);
    CHECK(cia402::decode_command(0x80, 0x00) == C::FaultReset);
    CHECK(cia402::decode_command(0x80, 0x80) == C::None);  // held high: no edge
  }

  TEST_CASE("abort and EMCY codes decoded to the standard's text") {
    CHECK(canopen::describe_sdo_abort(0x06020000) ==
          "0x06020000 object does not exist in the object dictionary");
    CHECK(canopen::describe_sdo_abort(0x05040000) == "0x05040000 SDO protocol timed out");
    CHECK(canopen::describe_sdo_abort(0x06090011) == "0x06090011 sub-index does not exist");
    CHECK(canopen::describe_sdo_abort(0x08000022).find("present device state") !=
          std::string::npos);
    CHECK(canopen::describe_sdo_abort(0x12345678) == "0x12345678 unknown abort code");
    CHECK(canopen::emcy_text(0x2310) == "EMCY 0x2310 continuous over-current (device output side)");
    CHECK(canopen::emcy_text(0x8611) == "EMCY 0x8611 following error");
    CHECK(canopen::emcy_text(0x7305) == "EMCY 0x7305 incremental sensor 1 fault");
    CHECK(canopen::emcy_text(0xABCD) == "EMCY 0xABCD");
  }

  TEST_CASE("SDO client: a late answer to a transfer that timed out is skipped, not the next's") {
    canopen::SdoClient c(5, 0.5);
    std::vector<can::Frame> out;
    std::vector<canopen::SdoResult> done;
    c.upload(0x6041, 0, [&](const canopen::SdoResult& r) { done.push_back(r); });
    c.upload(0x6064, 0, [&](const canopen::SdoResult& r) { done.push_back(r); });
    c.tick(0, out);
    REQUIRE(out.size() == 1);
    c.tick(0.5, out);  // the statusword's read times out, the position's goes out
    REQUIRE(done.size() == 1);
    CHECK(done[0].abort == 0x05040000);
    REQUIRE(out.size() == 3);  // request, our abort, the next request
    CHECK(out[2].data[0] == 0x40);
    CHECK(canopen::get_le(out[2].payload(), 1, 2) == 0x6064);
    // then the statusword's answer, late: skipped
    can::Frame late;
    late.id = 0x585;
    late.len = 8;
    late.data = {0x4B, 0x41, 0x60, 0x00, 0x37, 0x06, 0, 0};
    out.clear();
    CHECK(c.on_frame(late, 0.6, out));
    CHECK(out.empty());  // no abort of the transfer under way
    CHECK(done.size() == 1);
    CHECK(c.counts().late == 1);
    // and the position's own answer completes its read
    can::Frame own = late;
    own.data = {0x43, 0x64, 0x60, 0x00, 0x10, 0x27, 0, 0};
    CHECK(c.on_frame(own, 0.61, out));
    REQUIRE(done.size() == 2);
    CHECK(done[1].ok());
    CHECK(done[1].index == 0x6064);
    CHECK(canopen::get_le(done[1].data, 0, 4) == 10000);
  }

  TEST_CASE("SDO client: a wrong toggle bit and a silent server abort the transfer") {
    canopen::SdoClient c(5, 0.5);
    std::vector<can::Frame> out;
    std::vector<canopen::SdoResult> done;
    c.upload(0x1008, 0, [&](const canopen::SdoResult& r) { done.push_back(r); });
    c.tick(0, out);
    REQUIRE(out.size() == 1);
    CHECK(out[0].id == 0x605);
    CHECK(out[0].data[0] == 0x40);
    // segmented upload response, 10 bytes
    can::Frame r;
    r.id = 0x585;
    r.len = 8;
    r.data = {0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0};
    out.clear();
    CHECK(c.on_frame(r, 0.01, out));
    REQUIRE(out.size() == 1);
    CHECK(out[0].data[0] == 0x60);                       // first segment request, toggle 0
    r.data = {0x10, 'a', 'b', 'c', 'd', 'e', 'f', 'g'};  // toggle 1: wrong
    out.clear();
    CHECK(c.on_frame(r, 0.02, out));
    REQUIRE(out.size() == 1);
    CHECK(out[0].data[0] == 0x80);
    CHECK(canopen::get_le(out[0].payload(), 4, 4) == 0x05030000);
    REQUIRE(done.size() == 1);
    CHECK(done[0].abort == 0x05030000);
    CHECK_FALSE(done[0].aborted_by_server);
    // a download nobody answers: our abort 0x05040000 after the timeout
    c.download(0x6081, 0, canopen::le_bytes(1000, 4),
               [&](const canopen::SdoResult& res) { done.push_back(res); });
    out.clear();
    c.tick(1.0, out);
    REQUIRE(out.size() == 1);
    CHECK(out[0].data[0] == 0x23);  // expedited, 4 bytes
    out.clear();
    c.tick(1.49, out);
    CHECK(out.empty());
    c.tick(1.5, out);
    REQUIRE(out.size() == 1);
    CHECK(canopen::get_le(out[0].payload(), 4, 4) == 0x05040000);
    REQUIRE(done.size() == 2);
    CHECK(done[1].describe() ==
          "write 0x6081:00: 0x05040000 SDO protocol timed out (aborted by the host)");
    CHECK(c.counts().timeouts == 1);
    // a response of the wrong length is counted and skipped
    r.len = 5;
    CHECK(c.on_frame(r, 1.6, out));
    CHECK(c.counts().malformed == 1);
    // cancelled transfers are not lost: each callback hears the abort
    c.upload(0x6064, 0, [&](const canopen::SdoResult& res) { done.push_back(res); });
    c.upload(0x6041, 0, [&](const canopen::SdoResult& res) { done.push_back(res); });
    out.clear();
    c.tick(2.0, out);
    REQUIRE(out.size() == 1);  // the first under way
    out.clear();
    c.cancel_all(out, 0x08000000);
    REQUIRE(out.size() == 1);  // its abort on the bus
    CHECK(out[0].data[0] == 0x80);
    REQUIRE(done.size() == 4);
    CHECK(done[2].index == 0x6064);
    CHECK(done[3].index == 0x6041);
    CHECK(done[3].abort == 0x08000000);
    CHECK(c.idle());
  }

  TEST_CASE("SDO client: the time its caller's loop was held is not counted against a transfer") {
    canopen::SdoClient c(5, 0.5);
    std::vector<can::Frame> out;
    std::vector<canopen::SdoResult> done;
    c.upload(0x6064, 0, [&](const canopen::SdoResult& res) { done.push_back(res); });
    c.tick(1.0, out);
    REQUIRE(out.size() == 1);  // out at 1.0 s: due by 1.5 s
    out.clear();
    c.held(1.2, 1.5);  // 0.3 s of it held: due by 1.8 s
    c.tick(1.5, out);
    c.tick(1.79, out);
    CHECK(out.empty());
    CHECK(done.empty());
    c.tick(1.8, out);
    REQUIRE(done.size() == 1);
    CHECK(done[0].abort == 0x05040000);
    // a hold before the transfer went out excuses only what overlaps it
    c.upload(0x6064, 0, [&](const canopen::SdoResult& res) { done.push_back(res); });
    out.clear();
    c.tick(2.0, out);
    REQUIRE(out.size() == 1);  // due by 2.5 s
    c.held(1.9, 2.1);          // 0.1 s after it went out
    c.tick(2.59, out);
    CHECK(done.size() == 1);
    c.tick(2.6, out);
    CHECK(done.size() == 2);
    CHECK(c.counts().timeouts == 2);
  }

  TEST_CASE("SDO client: an abort for another object is not ours; a 0-byte download is refused") {
    canopen::SdoClient c(5, 0.5);
    std::vector<can::Frame> out;
    std::vector<canopen::SdoResult> done;
    c.upload(0x6061, 0, [&](const canopen::SdoResult& r) { done.push_back(r); });
    c.tick(0, out);
    REQUIRE(out.size() == 1);
    // a late abort of an earlier transfer (0x6083:00) arrives first
    can::Frame r;
    r.id = 0x585;
    r.len = 8;
    r.data = {0x80, 0x83, 0x60, 0x00, 0x31, 0x00, 0x09, 0x06};
    CHECK(c.on_frame(r, 0.01, out));
    CHECK(done.empty());
    CHECK(c.counts().unexpected == 1);
    r.data = {0x4F, 0x61, 0x60, 0x00, 0x01, 0, 0, 0};  // expedited, 1 byte: 1
    CHECK(c.on_frame(r, 0.02, out));
    REQUIRE(done.size() == 1);
    CHECK(done[0].ok());
    CHECK(done[0].data == std::vector<std::uint8_t>{1});
    // nothing to write: refused, no frame
    out.clear();
    c.download(0x2001, 0, {}, [&](const canopen::SdoResult& x) { done.push_back(x); });
    c.tick(0.03, out);
    CHECK(out.empty());
    REQUIRE(done.size() == 2);
    CHECK(done[1].abort == canopen::abort_code::kLength);
    CHECK(c.idle());
  }

  TEST_CASE("SDO client: urgent downloads go first, in order, and fail_queued keeps them") {
    canopen::SdoClient c(5, 0.5);
    std::vector<can::Frame> out;
    std::vector<std::string> order;  // the transfers' outcomes, in the order they came
    auto note = [&](const char* name) {
      return [&order, name](const canopen::SdoResult& r) {
        order.push_back(std::string(name) + (r.ok() ? " done" : " failed"));
      };
    };
    c.download(0x2000, 0, {1}, note("active"));
    c.tick(0, out);  // under way
    c.download(0x2001, 0, {1}, note("queued 1"));
    c.download_urgent(0x6040, 0, {2, 0}, note("urgent 1"));
    c.download(0x2002, 0, {1}, note("queued 2"));
    c.download_urgent(0x6040, 0, {2, 0}, note("urgent 2"));
    // a callback that queues anew while the queue fails
    c.download(0x2003, 0, {1}, [&](const canopen::SdoResult&) {
      order.push_back("queued 3 failed");
      c.download(0x2004, 0, {1}, note("requeued"));
    });
    c.fail_queued();
    CHECK(order ==
          std::vector<std::string>{"queued 1 failed", "queued 2 failed", "queued 3 failed"});
    // the drive answers each download in turn: urgent 1, urgent 2, then the requeued one
    std::vector<std::uint16_t> written;
    for (int k = 0; k < 4; ++k) {
      can::Frame ack;
      ack.id = 0x585;
      ack.len = 8;
      REQUIRE_FALSE(out.empty());
      const can::Frame req = out.back();
      written.push_back(static_cast<std::uint16_t>(req.data[1] | req.data[2] << 8));
      ack.data = {0x60, req.data[1], req.data[2], req.data[3], 0, 0, 0, 0};
      out.clear();
      REQUIRE(c.on_frame(ack, 0.01 * (k + 1), out));
      c.tick(0.01 * (k + 1), out);
    }
    CHECK(written == std::vector<std::uint16_t>{0x2000, 0x6040, 0x6040, 0x2004});
    CHECK(order.back() == "requeued done");
    CHECK(c.idle());
  }

  TEST_CASE("a drive without 0x605B and 0x605C is configured all the same, the refusals counted") {
    stand::Drive402Faults df;
    df.refuse_objects[0x605B00] = 0x06020000;  // object does not exist
    df.refuse_objects[0x605C00] = 0x06090030;  // value range exceeded
    SUBCASE("both refused: counted") {}
    SUBCASE("another object refused: the configuration fails") {
      df.refuse_objects[0x608300] = 0x06090030;
    }
    const bool fails = df.refuse_objects.count(0x608300) != 0;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    if (fails) {
      REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Failed; }, 1.0));
      CHECK(l.master.status().fault == FaultCode::Configuration);
      CHECK(l.master.status().fault_name.find("0x6083") != std::string::npos);
    } else {
      REQUIRE(l.running());
      CHECK(l.master.counts().ramp_options_refused == 2);
      // and told, once each, for the log: the drive's own defaults stand
      const std::vector<std::string>& told = l.master.notices();
      REQUIRE(told.size() == 2);
      CHECK(told[0].find("0x605B") != std::string::npos);
      CHECK(told[0].find("object does not exist") != std::string::npos);
      CHECK(told[1].find("0x605C") != std::string::npos);
      CHECK(told[1].find("coast") != std::string::npos);
      CHECK(l.master.status().fault == FaultCode::None);
      REQUIRE(l.enabled(1));
    }
  }

  TEST_CASE("the drive reboots while being configured: configured again, from the start") {
    stand::Drive402Setup ds = drive_setup();
    ds.mode_switch_s = 0.05;  // the configuration waits for 0x6061
    Loop l(master_settings(), ds);
    l.start();
    REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Configuring; }, 0.5));
    REQUIRE(l.drive.sdo_writes().size() > 3);
    // another node resets it: its objects are their defaults again
    can::Frame nmt = canopen::nmt_frame(canopen::NmtCommand::ResetNode, 5);
    l.drive.receive(l.t, nmt, l.from_drive);
    REQUIRE(*l.drive.value(0x605B, 0) == 0);
    const auto before = l.drive.sdo_writes().size();
    REQUIRE(l.running());
    CHECK(l.master.counts().configurations == 1);
    CHECK(l.drive.sdo_writes().size() >= before + 11);  // the whole configuration again
    CHECK(*l.drive.value(0x605B, 0) == 1);
    CHECK(*l.drive.value(0x1016, 1) == (127 << 16 | 500));
    CHECK(l.master.status().fault == FaultCode::DriveNmtState);  // said, then cleared by Enable
    REQUIRE(l.enabled(1));
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.master.counts().nmt_resets == 1);  // no communication reset needed
  }

  TEST_CASE("a failed configuration ends a caller's queued transfer through its callback") {
    stand::Drive402Faults df;
    df.refuse_objects[0x608300] = canopen::abort_code::kValueHigh;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    // the boot-up by hand, so a transfer can be queued behind the configuration
    std::vector<stand::DriveFrame> boot;
    l.t = 0.01;
    l.drive.advance(l.t, boot);
    REQUIRE(boot.size() == 1);
    l.master.on_frame(boot[0].frame, l.t, l.from_master);
    REQUIRE(l.master.phase() == cia402::CommPhase::Configuring);
    std::vector<canopen::SdoResult> got;
    l.master.read(0x1008, 0, [&](const canopen::SdoResult& r) { got.push_back(r); });
    l.deliver();
    CHECK(l.master.phase() == cia402::CommPhase::Failed);
    REQUIRE(got.size() == 1);
    CHECK(got[0].index == 0x1008);
    CHECK_FALSE(got[0].ok());
  }

  TEST_CASE("boot-up, configuration in order, start: the values written arrive") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    CHECK(l.drive.nmt() == stand::facts::Nmt::Operational);
    using W = std::pair<std::uint16_t, std::uint8_t>;
    const std::vector<W> order{{0x6060, 0}, {0x6081, 0}, {0x6083, 0}, {0x6084, 0},
                               {0x6085, 0}, {0x605A, 0}, {0x605B, 0}, {0x605C, 0},
                               {0x6007, 0}, {0x1016, 1}, {0x1017, 0}};
    CHECK(l.drive.sdo_writes() == order);
    const double cpr = 1e6 / kTwoPi;
    CHECK(*l.drive.value(0x6060, 0) == 1);
    CHECK(*l.drive.value(0x6061, 0) == 1);
    CHECK(*l.drive.value(0x60F2, 0) == 0);  // read, never written: the drive's own
    CHECK(*l.drive.value(0x6081, 0) == std::llround(30 * kDeg * cpr));
    CHECK(*l.drive.value(0x6083, 0) == std::llround(60 * kDeg * cpr));
    CHECK(*l.drive.value(0x6084, 0) == std::llround(40 * kDeg * cpr));
    CHECK(*l.drive.value(0x6085, 0) == std::llround(180 * kDeg * cpr));
    CHECK(*l.drive.value(0x605A, 0) == 6);
    CHECK(*l.drive.value(0x605B, 0) == 1);  // shutdown slows down on 0x6084 first
    CHECK(*l.drive.value(0x605C, 0) == 1);  // and so does disable operation
    CHECK(*l.drive.value(0x6007, 0) == 3);
    CHECK(*l.drive.value(0x1016, 1) == (127 << 16 | 500));
    CHECK(*l.drive.value(0x1017, 0) == 100);
    CHECK_FALSE(l.master.configured_mapping());
    CHECK(l.master.counts().nmt_resets == 1);
    // both heartbeats flow: 1 s of each at 0.1 s
    const auto drive_hb = l.master.counts().heartbeats;
    const auto host_hb = l.drive.counts().host_heartbeats;
    l.run_for(1.0);
    CHECK(l.master.counts().heartbeats - drive_hb == doctest::Approx(10).epsilon(0.11));
    CHECK(l.drive.counts().host_heartbeats - host_hb == doctest::Approx(10).epsilon(0.11));
    CHECK(l.master.status().state == TableState::Disabled);
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.drive.state() == DriveState::SwitchOnDisabled);
    // encoder samples from TPDO1 at the event timer, the table where it is
    l.samples.clear();
    l.run_for(0.1);
    CHECK(l.samples.size() == doctest::Approx(10).epsilon(0.21));
    REQUIRE_FALSE(l.samples.empty());
    CHECK(l.samples.back().angle_rad == 0);
  }

  TEST_CASE("the virtual drive's TPDOs timed on the bus: event-driven ones and SYNC's") {
    // what turncal-sim leaves unsent when it is late (a real drive samples
    // such a frame as it sends it, by its receipt or within its SYNC's cycle)
    can::Frame tpdo1;
    tpdo1.id = 0x185;
    tpdo1.len = 6;
    can::Frame tpdo2 = tpdo1;
    tpdo2.id = 0x285;
    can::Frame heartbeat = tpdo1;
    heartbeat.id = 0x705;
    heartbeat.len = 1;
    {
      cia402::MasterSettings ms = master_settings();
      ms.configure_mapping = true;
      ms.velocity_pdo = true;
      Loop l(ms);
      l.start();
      REQUIRE(l.running());
      CHECK(*l.drive.value(0x1800, 2) >= 0xFE);  // event-driven
      CHECK(l.drive.timed_on_the_bus(tpdo1));
      CHECK(l.drive.timed_on_the_bus(tpdo2));
      CHECK_FALSE(l.drive.timed_on_the_bus(heartbeat));
      can::Frame ext = tpdo1;
      ext.extended = true;
      CHECK_FALSE(l.drive.timed_on_the_bus(ext));
      // one that was not sent after all: the drive sends its word again at
      // its next chance (any frame it hears), not only on its timer
      can::Frame other;
      other.id = 0x7FF;
      other.len = 0;
      auto tpdos_on = [&](bool drop) {
        if (drop) l.drive.unsent(tpdo1);
        std::vector<stand::DriveFrame> out;
        l.drive.receive(l.t, other, out);  // the same time: no timer due
        return std::count_if(out.begin(), out.end(),
                             [](const stand::DriveFrame& f) { return f.frame.id == 0x185; });
      };
      CHECK(tpdos_on(false) == 0);
      CHECK(tpdos_on(true) == 1);
      CHECK(tpdos_on(false) == 0);
    }
    {
      cia402::MasterSettings ms = master_settings();
      ms.configure_mapping = true;
      ms.sync_period_s = 0.02;
      Loop l(ms);
      l.start();
      REQUIRE(l.running());
      CHECK(*l.drive.value(0x1800, 2) == 1);  // synchronous: dated by its SYNC
      CHECK(l.drive.timed_on_the_bus(tpdo1));
      CHECK_FALSE(l.drive.timed_on_the_bus(heartbeat));
    }
  }

  TEST_CASE("the virtual drive answers a SYNC of no data or a counter; other lengths are counted") {
    cia402::MasterSettings ms = master_settings();
    ms.configure_mapping = true;
    ms.sync_period_s = 0.02;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    REQUIRE(*l.drive.value(0x1800, 2) == 1);  // TPDO1 on every SYNC
    // the frames the drive sends on a frame on 0x080 of `len` bytes, and
    // how many it counted malformed
    auto on_sync_id = [&](std::uint8_t len) {
      can::Frame f;
      f.id = canopen::kSyncId;
      f.len = len;
      const std::uint64_t malformed = l.drive.counts().malformed;
      std::vector<stand::DriveFrame> out;
      l.drive.receive(l.t, f, out);
      const auto tpdo1 = std::count_if(
          out.begin(), out.end(), [](const stand::DriveFrame& d) { return d.frame.id == 0x185; });
      return std::pair{tpdo1, l.drive.counts().malformed - malformed};
    };
    CHECK(on_sync_id(0) == std::pair{std::ptrdiff_t{1}, std::uint64_t{0}});
    CHECK(on_sync_id(1) == std::pair{std::ptrdiff_t{1}, std::uint64_t{0}});
    CHECK(on_sync_id(2) == std::pair{std::ptrdiff_t{0}, std::uint64_t{1}});
    CHECK(on_sync_id(8) == std::pair{std::ptrdiff_t{0}, std::uint64_t{1}});
  }

  TEST_CASE("the PDO mappings written when asked, with SYNC: samples carry the SYNC's time") {
    cia402::MasterSettings ms = master_settings();
    ms.configure_mapping = true;
    ms.sync_period_s = 0.02;
    stand::Drive402Setup ds = drive_setup();
    ds.default_mapping = false;  // the drive maps nothing until told
    ds.angle0_rad = 1.0;
    Loop l(ms, ds);
    l.start();
    REQUIRE(l.running());
    CHECK(l.master.configured_mapping());
    CHECK(*l.drive.value(0x1600, 0) == 2);
    CHECK(*l.drive.value(0x1600, 1) == 0x60400010);
    CHECK(*l.drive.value(0x1600, 2) == 0x607A0020);
    CHECK(*l.drive.value(0x1A00, 0) == 2);
    CHECK(*l.drive.value(0x1A00, 1) == 0x60410010);
    CHECK(*l.drive.value(0x1A00, 2) == 0x60640020);
    CHECK(*l.drive.value(0x1800, 2) == 1);           // synchronous
    CHECK(*l.drive.value(0x1800, 1) == 0x40000185);  // valid again, no RTR (bit 30)
    CHECK(*l.drive.value(0x1400, 1) == 0x205);
    // the PDO went invalid before its mapping was written
    const auto& w = l.drive.sdo_writes();
    const auto first_map =
        std::find(w.begin(), w.end(), std::make_pair<std::uint16_t, std::uint8_t>(0x1600, 0));
    const auto invalid =
        std::find(w.begin(), w.end(), std::make_pair<std::uint16_t, std::uint8_t>(0x1400, 1));
    CHECK(invalid < first_map);
    l.samples.clear();
    l.run_for(0.5);
    REQUIRE(l.samples.size() >= 20);
    for (const auto& s : l.samples)
      CHECK(std::find(l.sync_times.begin(), l.sync_times.end(), s.t_s) != l.sync_times.end());
    CHECK(l.samples.back().angle_rad == doctest::Approx(1.0).epsilon(1e-5));
    CHECK(l.drive.counts().sync >= 25);
    REQUIRE(l.enabled(3));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  // A master running with SYNC every 10 ms; from here the bus is written by
  // hand: SYNCs, NMT and the drive's TPDO1 as it stands, at t0 + t.
  struct HandSync {
    Loop l{[] {
      cia402::MasterSettings ms = master_settings();
      ms.sync_period_s = 0.01;
      return ms;
    }()};
    double t0 = 0;
    std::vector<can::Frame> out;
    std::vector<cia402::EncoderSample> got;
    HandSync() {
      l.start();
      REQUIRE(l.running());
      REQUIRE(l.enabled(1));
      l.run_for(0.1);
      REQUIRE_FALSE(l.samples.empty());
      t0 = l.t;
    }
    void sync(double t) { l.master.on_frame(canopen::sync_frame(), t0 + t, out); }
    void nmt_start(double t, std::uint8_t node = 5) {
      l.master.on_frame(canopen::nmt_frame(canopen::NmtCommand::Start, node), t0 + t, out);
    }
    // a TPDO1 received at t: dated `dated` (from t0), `lost` lost before it
    void expect(double t, double dated, std::int64_t lost) {
      INFO("the TPDO1 received at t0 + " << t);
      const cia402::EncoderSample e = tpdo(t);
      CHECK(e.t_s == t0 + dated);
      CHECK(e.lost_before == lost);
    }
    cia402::EncoderSample tpdo(double t) {
      can::Frame f;
      f.id = 0x185;
      f.len = 6;
      const std::uint16_t sw = l.drive.statusword();
      const auto pos = static_cast<std::uint32_t>(l.drive.position_counts(l.t));
      f.data[0] = static_cast<std::uint8_t>(sw);
      f.data[1] = static_cast<std::uint8_t>(sw >> 8);
      for (unsigned b = 0; b < 4; ++b) f.data[2 + b] = static_cast<std::uint8_t>(pos >> (8 * b));
      l.master.on_frame(f, t0 + t, out);
      got.clear();
      l.master.take_samples(got);
      REQUIRE(got.size() == 1);
      return got.back();
    }
  };

  TEST_CASE("with SYNC: a sample has its SYNC's echo's time; a SYNC no TPDO1 answered is a loss") {
    HandSync h;
    auto& l = h.l;
    const double t0 = h.t0;
    auto& out = h.out;
    auto sync = [&](double t) { h.sync(t); };
    auto tpdo = [&](double t) { return h.tpdo(t); };
    // the SYNC on the bus dates the TPDO1 that answers it
    sync(0.0012);
    h.expect(0.0017, 0.0012, 0);
    // a SYNC queued by the tick is not yet on the bus: its echo's time counts
    l.master.tick(t0 + 0.01, out);
    REQUIRE(std::count_if(out.begin(), out.end(),
                          [](const can::Frame& f) { return f.id == canopen::kSyncId; }) == 1);
    sync(0.0134);  // the echo, 3.4 ms after the tick queued it
    h.expect(0.0139, 0.0134, 0);
    // two SYNCs, one TPDO1: the first one's answer was lost
    sync(0.02);
    sync(0.03);
    h.expect(0.0305, 0.03, 1);
    // three unanswered before it: three lost
    for (int k = 4; k <= 7; ++k) sync(0.01 * k);
    CHECK(tpdo(0.0705).lost_before == 3);
    // a SYNC sent 6 ms late and the next on time, both answered: no loss
    // (their 4 ms gap after a 16 ms one reads as a period missed by time)
    sync(0.086);
    CHECK(tpdo(0.0865).lost_before == 0);
    sync(0.09);
    CHECK(tpdo(0.0905).lost_before == 0);
    // an NMT command to the drive starts its stream over: the SYNCs before
    // its first TPDO1 after are no losses
    h.nmt_start(0.095);
    sync(0.1);
    sync(0.11);
    h.expect(0.1105, 0.11, cia402::EncoderSample::kRestarted);
    sync(0.12);
    CHECK(tpdo(0.1205).lost_before == 0);
    // an NMT command to another node changes nothing
    l.master.on_frame(canopen::nmt_frame(canopen::NmtCommand::Start, 6), t0 + 0.125, out);
    sync(0.13);
    sync(0.14);
    CHECK(tpdo(0.1405).lost_before == 1);
    // a SYNC of a wrong length (CiA 301: none or one byte of counter) is not one
    can::Frame bad = canopen::sync_frame();
    bad.len = 2;
    const auto malformed = l.master.counts().malformed;
    l.master.on_frame(bad, t0 + 0.15, out);
    CHECK(l.master.counts().malformed == malformed + 1);
    // so no SYNC since the last TPDO1: this one's SYNC is not known, and
    // the last SYNC's time is the last sample's; dated by its receipt
    h.expect(0.1505, 0.1505, 0);
    CHECK(l.master.counts().tpdo_unsynced == 1);
    CHECK(l.master.notices().back().find("TPDO1s came with no SYNC within half a period") == 0);
    // and the next SYNC dates its answer again
    sync(0.16);
    h.expect(0.1605, 0.16, 0);
    CHECK(l.master.counts().tpdo_unsynced == 1);
  }

  TEST_CASE(
      "with SYNC: a SYNC's echo read after its answer invents no loss, and dates nothing early") {
    HandSync h;
    auto& l = h.l;
    h.sync(0.0);
    REQUIRE(h.tpdo(0.0005).lost_before == 0);
    // once: TPDO1 n read before the echo of SYNC n; then in order again
    h.expect(0.0105, 0.0105, 0);  // its SYNC not yet seen: its receipt
    h.sync(0.01);                 // the echo, read late: the SYNC that TPDO1 answered
    h.sync(0.02);
    h.expect(0.0205, 0.02, 0);  // was 1: the late echo read as a SYNC unanswered
    // always so: each dated by its own receipt, never by the SYNC before its own
    const auto unsynced = l.master.counts().tpdo_unsynced;
    for (int k = 3; k <= 12; ++k) {
      const double t = 0.01 * k;
      if (k == 7) {
        h.sync(t);  // TPDO1 7 lost: its SYNC's echo alone
        continue;
      }
      const double rx = t + 0.0005;
      CAPTURE(k);
      h.expect(rx, rx, k == 8 ? 1 : 0);  // TPDO1 7, counted once, by the one after
      // the echo stamped when it was on the bus, or (an adapter that hands
      // it over late) a little after the answer it is read after
      h.sync(k % 2 == 0 ? t : rx + 0.0001);
    }
    CHECK(l.master.counts().tpdo_unsynced == unsynced + 9);
    // and in order again: dated by the SYNC
    h.sync(0.13);
    h.expect(0.1305, 0.13, 0);
    // a second answer to one SYNC, 4 ms before the next: dated by its
    // receipt, and the next SYNC (on the bus after it: no echo read late)
    // dates the next answer again
    h.expect(0.136, 0.136, 0);
    h.sync(0.14);
    h.expect(0.1405, 0.14, 0);
    // an answer more than half a period late is no answer: dated by its
    // receipt, its SYNC counted unanswered; the next SYNC is not taken
    h.sync(0.15);
    h.expect(0.1556, 0.1556, 1);
    h.sync(0.16);
    h.expect(0.1605, 0.16, 0);
    // just inside the window, under half a period after: still its answer
    h.sync(0.17);
    h.expect(0.1749, 0.17, 0);
    // a TPDO1 stamped before the last SYNC (stamps crossed, or a second
    // answer to the one before) is no answer to it: that SYNC stays open
    // for its own, and nothing is lost
    h.sync(0.18);
    h.expect(0.1799, 0.1799, 0);
    h.expect(0.1805, 0.18, 0);
  }

  TEST_CASE(
      "with SYNC: a TPDO1 after an NMT command and before the next SYNC is dated by its receipt") {
    HandSync h;
    const double t0 = h.t0;
    h.sync(0.0);
    REQUIRE(h.tpdo(0.0005).t_s == t0);
    // the drive restarted: the SYNC before the command answers nothing after
    h.sync(0.01);
    h.nmt_start(0.012);
    // dated by its receipt (was t0 + 0.01: a SYNC from before the restart)
    h.expect(0.0125, 0.0125, cia402::EncoderSample::kRestarted);
    // the first SYNC after the command, soon after that TPDO1: its own
    h.sync(0.015);
    h.expect(0.0155, 0.015, 0);
    // NMT to all nodes (0) restarts it as well
    h.sync(0.025);
    h.nmt_start(0.027, 0);
    h.expect(0.0275, 0.0275, cia402::EncoderSample::kRestarted);
  }

  TEST_CASE("SYNC keeps its schedule after a late tick, and never two within half a period") {
    cia402::MasterSettings ms = master_settings();
    ms.sync_period_s = 0.01;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    l.run_for(0.1);
    REQUIRE_FALSE(l.sync_times.empty());
    const double grid = l.sync_times.back();  // SYNCs due at grid + k * 10 ms
    l.sync_times.clear();
    // a tick 3 ms late: the next SYNC on the grid again, 7 ms after it
    l.step(grid + 0.013 - l.t);
    l.run_for(0.0495);
    REQUIRE(l.sync_times.size() >= 2);
    CHECK(l.sync_times[0] == doctest::Approx(grid + 0.013).epsilon(1e-9));
    CHECK(l.sync_times[1] == doctest::Approx(grid + 0.02).epsilon(1e-9));
    // a tick 8 ms late (the one at grid + 0.07 and its due SYNC missed):
    // the next SYNC half a period after it, not at the grid's next 2 ms on
    const std::size_t late = l.sync_times.size();
    l.step(grid + 0.078 - l.t);
    l.run_for(0.05);
    REQUIRE(l.sync_times.size() >= late + 3);
    CHECK(l.sync_times[late] == doctest::Approx(grid + 0.078).epsilon(1e-9));
    CHECK(l.sync_times[late + 1] == doctest::Approx(grid + 0.083).epsilon(1e-9));
    double shortest = 1;
    for (std::size_t i = 1; i < l.sync_times.size(); ++i)
      shortest = std::min(shortest, l.sync_times[i] - l.sync_times[i - 1]);
    CHECK(shortest >= 0.005 - 1e-9);
  }

  TEST_CASE("velocity actual in TPDO2: the table's rate is the drive's own") {
    cia402::MasterSettings ms = master_settings();
    ms.configure_mapping = true;
    ms.velocity_pdo = true;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    CHECK(*l.drive.value(0x1A01, 0) == 1);
    CHECK(*l.drive.value(0x1A01, 1) == 0x606C0020);
    CHECK(*l.drive.value(0x1801, 1) == 0x40000285);  // valid
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, -90 * kDeg, 30 * kDeg));
    l.run_for(2.0);  // cruising
    const double v = -static_cast<double>(*l.drive.value(0x6081, 0)) / l.drive.counts_per_rad();
    CHECK(l.drive.rate(l.t) == doctest::Approx(v).epsilon(1e-12));
    CHECK(l.master.status().rate_rps == doctest::Approx(v).epsilon(1e-12));
    CHECK(l.master.velocity_rps() == doctest::Approx(v).epsilon(1e-12));
    CHECK(l.master.counts().velocity_pdo >= 150);
    REQUIRE(l.in_position(2, 5));
    l.run_for(0.05);
    CHECK(l.master.status().rate_rps == 0);
  }

  TEST_CASE("velocity PDO asked for but never sent: the rate is unknown, not zero") {
    cia402::MasterSettings ms = master_settings();
    ms.velocity_pdo = true;  // the drive's TPDO2 stays invalid: nobody maps it
    Loop l(ms);
    REQUIRE(l.turning(1.0, 90, 30));
    CHECK(l.master.counts().velocity_pdo == 0);
    CHECK(std::isnan(l.master.status().rate_rps));
    CHECK(l.master.status().state == TableState::Moving);
  }

  TEST_CASE("a drive whose SDO answers come 2 to 5 ms late: each that late, the run as usual") {
    stand::Drive402Setup ds = drive_setup();
    ds.sdo_answer_min_s = 0.002;
    ds.sdo_answer_max_s = 0.005;
    SUBCASE("the drive alone: every answer between 2 and 5 ms, none at once") {
      stand::VirtualDrive402 d(ds);
      std::vector<stand::DriveFrame> out;
      d.advance(0.1, out);  // booted
      out.clear();
      double t = 0.2;
      for (int k = 0; k < 20; ++k, t += 0.01) {
        can::Frame q;
        q.id = 0x600 + 5;
        q.len = 8;
        q.data = {0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0};  // read the statusword
        d.receive(t, q, out);
        CHECK(out.empty());
        d.advance(t + 0.0099, out);
        REQUIRE(out.size() == 1);
        CAPTURE(k);
        CHECK(out[0].frame.id == 0x585);
        CHECK(out[0].t_s - t >= 0.002 - 1e-12);
        CHECK(out[0].t_s - t <= 0.005 + 1e-12);
        out.clear();
      }
    }
    SUBCASE("through the master: configured, enabled, a move done") {
      Loop l(master_settings(), ds);
      l.start();
      REQUIRE(l.running());
      REQUIRE(l.enabled(1));
      REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
      REQUIRE(l.in_position(2, 10));
      CHECK(l.master.status().fault == FaultCode::None);
      CHECK(l.drive.angle(l.t) == doctest::Approx(M_PI / 2).epsilon(1e-6));
    }
  }

  TEST_CASE("statusword bit 5 set where CiA 402 leaves it free: the states read the same") {
    stand::Drive402Setup ds = drive_setup();
    ds.quick_stop_bit_where_free = true;
    stand::Drive402Faults df;
    df.fault_at_s = 1.0;
    Loop l(master_settings(), ds, df);
    l.start();
    REQUIRE(l.running());
    CHECK((l.drive.statusword() & 0x6F) == 0x60);  // switch on disabled, bit 5 up
    CHECK(l.master.drive_state() == State::SwitchOnDisabled);
    REQUIRE(l.enabled(1));
    REQUIRE(l.run_until([&] { return l.drive.state() == DriveState::Fault; }, 2.0));
    l.run_for(0.05);
    CHECK((l.drive.statusword() & 0x6F) == 0x28);  // fault, bit 5 up
    CHECK(l.master.drive_state() == State::Fault);
    CHECK(l.master.status().state == TableState::Fault);
    REQUIRE(l.enabled(2));  // reset, through switch on disabled (0x0260) again
    CHECK(l.drive.counts().fault_resets == 1);
  }

  TEST_CASE("a warning EMCY at each boot-up, reset once operational: told, the run as usual") {
    stand::Drive402Setup ds = drive_setup();
    ds.boot_warning_code = 0x8120;  // CAN in error passive: a warning by the default classes
    Loop l(master_settings(), ds);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    CHECK(l.master.status().fault == FaultCode::None);
    const std::vector<std::uint16_t>& sent = l.drive.emcy_sent();
    REQUIRE(sent.size() >= 2);
    CHECK(sent[0] == 0x8120);
    CHECK(sent.back() == 0x0000);  // its error reset
    const auto& told = l.master.notices();
    CHECK(std::any_of(told.begin(), told.end(), [](const std::string& n) {
      return n.starts_with("the drive warned: EMCY 0x8120");
    }));
  }

  TEST_CASE("segmented SDO: the device name read, a label written and read back") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    std::vector<canopen::SdoResult> done;
    auto keep = [&](const canopen::SdoResult& r) { done.push_back(r); };
    l.master.read(0x1008, 0, keep);
    const std::string label = "bay 3 turntable, axis Z, serial 0042";
    l.master.write(0x2001, 0, std::vector<std::uint8_t>(label.begin(), label.end()), keep);
    l.master.read(0x2001, 0, keep);
    l.master.write(0x1008, 0, {'x', 'y', 'z', 'w', 'v'}, keep);  // read only
    l.master.read(0x2FFF, 0, keep);
    l.master.read(0x1018, 9, keep);
    l.master.write(0x6060, 0, {3}, keep);  // profile velocity mode: not this drive's
    REQUIRE(l.run_until([&] { return done.size() == 7; }, 1.0));
    CHECK(done[4].abort == 0x06020000);
    CHECK(done[5].abort == 0x06090011);
    CHECK(done[6].abort == 0x06090030);
    CHECK(*l.drive.value(0x6060, 0) == 1);
    REQUIRE(done[0].ok());
    CHECK(std::string(done[0].data.begin(), done[0].data.end()) == "turncal virtual CiA 402 drive");
    CHECK(done[1].ok());
    REQUIRE(done[2].ok());
    CHECK(std::string(done[2].data.begin(), done[2].data.end()) == label);
    CHECK(done[3].abort == 0x06010002);
    CHECK(done[3].aborted_by_server);
    CHECK(done[3].describe().find("attempt to write a read only object") != std::string::npos);
    CHECK(l.drive.sdo_writes().back() == std::make_pair<std::uint16_t, std::uint8_t>(0x2001, 0));
    CHECK(l.drive.counts().sdo_aborts == 4);
  }

  TEST_CASE("an object the drive refuses: the abort's text, the configuration stops") {
    SUBCASE("profile acceleration refused as out of range") {
      stand::Drive402Faults df;
      df.refuse_objects[0x608300] = 0x06090030;
      Loop l(master_settings(), drive_setup(), df);
      l.start();
      REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Failed; }, 2.0));
      const auto st = l.master.status();
      CHECK(st.state == TableState::Fault);
      CHECK(st.fault == FaultCode::Configuration);
      CHECK(st.fault_name.find("0x6083:00") != std::string::npos);
      CHECK(st.fault_name.find("0x06090030 invalid value for parameter") != std::string::npos);
      CHECK(st.fault_name.find("profile acceleration") != std::string::npos);
      // the drive: what came before was written, nothing after, never started
      using W = std::pair<std::uint16_t, std::uint8_t>;
      CHECK(l.drive.sdo_writes() == std::vector<W>{{0x6060, 0}, {0x6081, 0}});
      CHECK(l.drive.nmt() == stand::facts::Nmt::PreOperational);
      // a move is refused with the reason, and sends nothing
      l.from_master.clear();
      const auto sent = l.sent.size();
      const Status s = l.command(TableCommandCode::MoveRelative, 9, 0.1, 0.1);
      CHECK_FALSE(s.ok());
      CHECK(s.error().message.find("enabled") != std::string::npos);
      CHECK(l.sent.size() == sent);
    }
    SUBCASE("a profile velocity above the drive's maximum") {
      stand::Drive402Setup ds = drive_setup();
      ds.max_profile_velocity = 1000;
      Loop l(master_settings(), ds);
      l.start();
      REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Failed; }, 2.0));
      CHECK(l.master.status().fault_name.find("0x06090031 value of parameter written too high") !=
            std::string::npos);
      CHECK(l.drive.value(0x6081, 0) != std::llround(30 * kDeg * 1e6 / kTwoPi));
    }
  }

  TEST_CASE("enable: the state machine to operation enabled, acknowledged") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.run_until([&] { return l.master.statusword().has_value(); }, 0.5));
    CHECK(l.master.drive_state() == State::SwitchOnDisabled);
    REQUIRE(l.enabled(42));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.master.drive_state() == State::OperationEnabled);
    CHECK((l.drive.controlword() & 0x8F) == 0x0F);
    // disable: shutdown (transition 8) to ready to switch on, not disable
    // voltage (9), which would let a moving table coast
    REQUIRE(l.command(TableCommandCode::Disable, 43));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 43; }, 0.5));
    CHECK(l.master.status().state == TableState::Disabled);
    CHECK(l.drive.state() == DriveState::ReadyToSwitchOn);
    CHECK((l.drive.controlword() & 0x8F) == 0x06);
    l.run_for(0.1);
    CHECK(l.drive.state() == DriveState::ReadyToSwitchOn);
    // and enabled again from there
    REQUIRE(l.enabled(44));
  }

  TEST_CASE("relative and absolute moves: handshake, moving, in position within a count") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    const double cpr = 1e6 / kTwoPi;
    // +90 deg relative at the configured 30 deg/s: no SDO before the set-point
    const auto writes = l.drive.sdo_writes().size();
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
    const double t0 = l.t;
    REQUIRE(l.run_until([&] { return l.master.status().ack == 2; }, 0.1));
    CHECK(l.master.status().state == TableState::Moving);
    CHECK(l.drive.moving(l.t));
    REQUIRE(l.in_position(2, 10));
    const double took = l.t - t0;
    CHECK(took ==
          doctest::Approx(trapezoid_s(90 * kDeg, 30 * kDeg, 60 * kDeg, 40 * kDeg)).epsilon(0.01));
    CHECK(l.drive.sdo_writes().size() == writes);
    CHECK(std::fabs(l.drive.angle(l.t) - 90 * kDeg) * cpr <= 1.0);
    CHECK(std::fabs(l.master.angle_rad() - 90 * kDeg) * cpr <= 1.0);
    CHECK(l.drive.position_counts(l.t) == 250000);
    CHECK((l.drive.statusword() & 0x0400) != 0);
    // the handshake is closed: bit 4 cleared by us, bit 12 by the drive
    CHECK((l.drive.controlword() & 0x10) == 0);
    CHECK((l.drive.controlword() & 0x40) == 0);  // relative, sent as an absolute target
    CHECK((l.drive.statusword() & 0x1000) == 0);
    // absolute to -45 deg at 20 deg/s: the profile velocity goes first by SDO
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 3, -45 * kDeg, 20 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.2));
    CHECK(l.drive.sdo_writes().back() == std::make_pair<std::uint16_t, std::uint8_t>(0x6081, 0));
    CHECK(*l.drive.value(0x6081, 0) == std::llround(20 * kDeg * cpr));
    double peak = 0;
    REQUIRE(l.run_until(
        [&] {
          peak = std::max(peak, std::fabs(l.drive.rate(l.t)));
          return l.master.status().state == TableState::InPosition;
        },
        15));
    CHECK(peak == doctest::Approx(20 * kDeg).epsilon(1e-3));
    CHECK(std::fabs(l.drive.angle(l.t) + 45 * kDeg) * cpr <= 1.0);
    CHECK(std::fabs(l.master.angle_rad() + 45 * kDeg) * cpr <= 1.0);
    CHECK(l.drive.counts().set_points == 2);
    // the master's encoder samples follow the drive within a count when at rest
    l.samples.clear();
    l.run_for(0.05);
    REQUIRE_FALSE(l.samples.empty());
    CHECK(l.samples.back().counts == -125000);
    // the rate, over its window (0.1 to 0.2 s), reads the rest
    l.run_for(0.2);
    CHECK(l.master.status().rate_rps == 0);
  }

  TEST_CASE("quick stop by controlword: the drive decelerates at 0x6085, quick-stopped") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 360 * kDeg, 30 * kDeg));
    l.run_for(3.0);                                                          // cruising at 30 deg/s
    REQUIRE(l.drive.rate(l.t) == doctest::Approx(30 * kDeg).epsilon(1e-4));  // to a count/s
    // without TPDO2 the master's rate comes from the encoder steps
    CHECK(l.master.status().rate_rps == doctest::Approx(30 * kDeg).epsilon(2e-3));
    const double from = l.drive.angle(l.t);
    const double t_stop = l.t;
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    CHECK(l.drive.state() == DriveState::QuickStopActive);
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.1));
    CHECK(l.master.status().state == TableState::QuickStopped);
    l.run_for(0.5);
    // 30 deg/s at 180 deg/s^2 (as the drive holds them, in counts): at rest
    // after 1/6 s, 2.5 deg further
    const double cpr = l.drive.counts_per_rad();
    const double v = static_cast<double>(*l.drive.value(0x6081, 0)) / cpr;
    const double q = static_cast<double>(*l.drive.value(0x6085, 0)) / cpr;
    REQUIRE(v == doctest::Approx(30 * kDeg).epsilon(1e-4));
    REQUIRE(q == doctest::Approx(180 * kDeg).epsilon(1e-4));
    CHECK_FALSE(l.drive.moving(l.t));
    CHECK(l.drive.rate(t_stop + v / q + 1e-9) == 0);
    CHECK(l.drive.rate(t_stop + v / q / 2) == doctest::Approx(v / 2).epsilon(1e-9));
    CHECK(l.drive.angle(l.t) - from == doctest::Approx(v * v / (2 * q)).epsilon(1e-9));
    CHECK(l.drive.state() == DriveState::QuickStopActive);  // 0x605A = 6: stays
    CHECK(l.master.status().state == TableState::QuickStopped);
    CHECK(l.drive.counts().quick_stops == 1);
    // enable again from quick stop active
    REQUIRE(l.enabled(4));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("controlled stop by halt: decelerates at 0x6084, in position where it stopped") {
    Loop l;
    REQUIRE(l.turning(3.0));
    const double from = l.drive.angle(l.t);
    REQUIRE(l.command(TableCommandCode::ControlledStop, 3));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.1));
    CHECK(l.master.status().state == TableState::Moving);
    REQUIRE(l.in_position(3, 2));
    // 30 deg/s at 40 deg/s^2: 11.25 deg
    CHECK(l.drive.angle(l.t) - from == doctest::Approx(11.25 * kDeg).epsilon(1e-3));
    CHECK((l.drive.controlword() & 0x100) != 0);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    // a new move clears halt and goes, relative to where the table stopped
    const std::int64_t stopped = l.drive.position_counts(l.t);
    REQUIRE(l.command(TableCommandCode::MoveRelative, 4, -10 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(4, 5));
    CHECK((l.drive.controlword() & 0x100) == 0);
    CHECK(l.drive.position_counts(l.t) == stopped - 27778);  // 10 deg: 27777.8 counts
  }

  TEST_CASE("a drive fault with EMCY: fault with its text; fault reset brings it back") {
    Loop l(master_settings(), drive_setup(), over_current_at_2s());
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 3));
    CHECK(l.t == doctest::Approx(2.0).epsilon(0.01));
    const auto st = l.master.status();
    CHECK(st.fault == FaultCode::Emcy);
    CHECK(st.fault_name == "EMCY 0x2310 continuous over-current (device output side)");
    REQUIRE_FALSE(l.master.emergencies().empty());
    CHECK(l.master.emergencies().front().code == 0x2310);
    CHECK(l.master.emergencies().front().t_s == doctest::Approx(2.0).epsilon(0.01));
    l.run_for(1.0);
    CHECK(l.drive.state() == DriveState::Fault);
    CHECK_FALSE(l.drive.moving(l.t));
    CHECK(*l.drive.value(0x603F, 0) == 0x2310);
    // a move is refused while in fault
    CHECK_FALSE(l.command(TableCommandCode::MoveRelative, 3, 0.1, 0.1).ok());
    REQUIRE(l.enabled(4));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.drive.counts().fault_resets == 1);
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.master.emergencies().back().code == 0x0000);  // the drive's error reset
    CHECK(l.master.counts().nmt_resets == 1);             // no communication reset needed
  }

  TEST_CASE("EMCYs saying no error (code 0) are no news of a fault while a reset reads its word") {
    // A drive may say its error is gone (EMCY 0x0000) at any time, also
    // while the master reads its statusword to reset it: that is no new
    // fault to read again for, and the reset goes through with one read.
    Loop l(master_settings(), drive_setup(), over_current_at_2s());
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 3));
    l.run_for(0.5);
    const std::uint8_t node = master_settings().node_id;
    // an EMCY 0x0000 ahead of every SDO answer and TPDO from the Enable on
    const can::Frame no_error = canopen::emcy_frame(node, 0x0000, 0);
    l.tamper = [&](can::Frame& f) {
      if (f.id == canopen::kSdoTxBase + node || f.id == 0x180U + node)
        l.master.on_frame(no_error, l.t, l.from_master);
    };
    const auto emcys = l.master.counts().emcy;
    REQUIRE(l.command(TableCommandCode::Enable, 4));
    const bool enabled = l.run_until(
        [&] {
          return l.master.status().state == TableState::Holding && l.master.status().ack == 4;
        },
        1.0);
    CHECK(enabled);
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.master.counts().emcy >= emcys + 2);  // before the answer, and the TPDO after
    CHECK(l.statusword_reads() == 1);
  }

  TEST_CASE("an EMCY after the statusword's fault names it, and a failed reset adds to its name") {
    // The drive's fault EMCY reaches the master after a statusword in
    // fault: the fault is then the EMCY's, and what a reset that cannot
    // read the statusword says is added to the EMCY's text.
    stand::Drive402Faults df = over_current_at_2s();
    df.refuse_objects[0x604100] = 0x06020000;  // the statusword not readable by SDO
    Loop l(master_settings(), drive_setup(), df);
    const std::uint8_t node = master_settings().node_id;
    std::optional<can::Frame> late;  // the fault's EMCY, held back
    l.tamper = [&](can::Frame& f) {
      if (f.id == canopen::kEmcyBase + node && (f.data[0] | f.data[1]) != 0 && !late) {
        late = f;
        f.id = 0x7FF;  // nobody's
      }
    };
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 3));
    CHECK(l.master.status().fault == FaultCode::DriveFault);
    REQUIRE(late);
    l.master.on_frame(*late, l.t, l.from_master);
    const std::string emcy = "EMCY 0x2310 continuous over-current (device output side)";
    CHECK(l.master.status().fault == FaultCode::Emcy);
    CHECK(l.master.status().fault_name == emcy);
    REQUIRE(l.command(TableCommandCode::Enable, 3));
    l.run_for(0.5);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK_MESSAGE(l.master.status().fault_name.starts_with(
                      emcy + "; the statusword could not be read for its reset: "),
                  l.master.status().fault_name);
  }

  TEST_CASE("a fault that outlives the first reset: the next Enable resets again") {
    stand::Drive402Faults df;
    df.fault_at_s = 0.5;
    df.fault_code = 0x3210;
    df.resets_ignored = 1;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    l.run_for(1.0);
    REQUIRE(l.master.status().fault_name == "EMCY 0x3210 DC link over-voltage");
    CHECK_FALSE(l.enabled(2));
    CHECK(l.drive.state() == DriveState::Fault);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK(l.master.status().ack == 1);
    REQUIRE(l.enabled(3));
    CHECK(l.drive.counts().fault_resets == 1);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("a profile velocity written for a move that was quick-stopped is remembered") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    // the move's SDO and the quick stop go out before the drive answers
    REQUIRE(l.master.command(TableCommandCode::MoveRelative, 2, 10 * kDeg, 20 * kDeg, l.t,
                             l.from_master));
    REQUIRE(l.master.command(TableCommandCode::QuickStop, 3, 0, 0, l.t, l.from_master));
    l.deliver();
    l.run_for(0.1);
    CHECK(*l.drive.value(0x6081, 0) == std::llround(20 * kDeg * l.drive.counts_per_rad()));
    CHECK(l.drive.counts().set_points == 0);
    REQUIRE(l.enabled(4));
    // 30 deg/s again: the drive holds 20, so the SDO must go first
    REQUIRE(l.command(TableCommandCode::MoveRelative, 5, 90 * kDeg, 30 * kDeg));
    double peak = 0;
    REQUIRE(l.run_until(
        [&] {
          peak = std::max(peak, std::fabs(l.drive.rate(l.t)));
          return l.master.status().state == TableState::InPosition;
        },
        10));
    CHECK(peak == doctest::Approx(30 * kDeg).epsilon(1e-4));
  }

  TEST_CASE("stale PDO: a drive in fault whose TPDO says operation enabled") {
    stand::Drive402Faults df;
    df.fault_at_s = 0.5;
    df.fault_code = 0x4310;
    cia402::MasterSettings ms = master_settings();
    // a stand that lists temperature codes as warnings: the fault is found
    // by the statusword read by SDO after the EMCY, not by the EMCY itself
    const std::vector<std::pair<std::uint16_t, std::uint16_t>> warm = {{0x4000, 0x4FFF}};
    bool listed = false;
    SUBCASE("TPDO silent in fault") {
      df.stale = stand::StalePdo::Silent;
    }
    SUBCASE("TPDO frozen at its last value") {
      df.stale = stand::StalePdo::Frozen;
    }
    SUBCASE("TPDO silent in fault, its EMCY's code a warning") {
      df.stale = stand::StalePdo::Silent;
      ms.emcy_warnings = warm;
      listed = true;
    }
    SUBCASE("TPDO frozen at its last value, its EMCY's code a warning") {
      df.stale = stand::StalePdo::Frozen;
      ms.emcy_warnings = warm;
      listed = true;
    }
    Loop l(ms, drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    l.run_for(1.0);
    const auto tpdo_before = l.master.counts().tpdo;
    CHECK(l.drive.state() == DriveState::Fault);
    // the last (or every) statusword the master has says operation enabled ...
    CHECK(l.master.drive_state() == State::OperationEnabled);
    if (df.stale == stand::StalePdo::Frozen) {
      l.run_for(0.2);
      CHECK(l.master.counts().tpdo > tpdo_before);
      CHECK(l.master.drive_state() == State::OperationEnabled);
    } else {
      l.run_for(0.2);
      CHECK(l.master.counts().tpdo == tpdo_before);
    }
    // ... but the EMCY is fresher
    CHECK(l.master.status().state == TableState::Fault);
    if (!listed)
      CHECK(l.master.status().fault_name == "EMCY 0x4310 excess temperature drive");
    else  // a warning's code: the fault is the statusword's, read after it
      CHECK(l.master.status().fault_name ==
            "EMCY 0x4310 excess temperature drive (statusword 0x0208 read after it)");
    CHECK_FALSE(l.command(TableCommandCode::MoveAbsolute, 2, 0.5, 0.1).ok());
    // only the fault reset and a statusword after it clear it
    REQUIRE(l.enabled(3));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.drive.counts().fault_resets == 1);
  }

  TEST_CASE("the drive goes silent: heartbeat lost, then NMT reset, reconfiguration, fault reset") {
    stand::Drive402Faults df;
    df.silent_at_s = 2.0;
    df.silent_until_s = 4.0;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 3));
    CHECK(l.master.status().fault == FaultCode::DriveHeartbeatLost);
    CHECK(l.master.status().fault_name == "drive heartbeat lost");
    // the last heartbeat before 2.0 s, then 0.3 s
    CHECK(l.t == doctest::Approx(2.3).epsilon(0.05));
    // the drive heard nothing either: its consumer quick-stopped it (0x6007 = 3)
    l.run_for(0.5);
    CHECK(l.drive.counts().host_heartbeat_lost == 1);
    CHECK(l.drive.state() == DriveState::QuickStopActive);
    CHECK_FALSE(l.drive.moving(l.t));
    CHECK(l.drive.emcy_sent().back() == 0x8130);
    l.run_for(1.5);                                       // the drive talks again
    CHECK(l.master.status().state == TableState::Fault);  // still: nothing reset it
    const auto configs = l.master.counts().configurations;
    const auto writes = l.drive.sdo_writes().size();
    REQUIRE(l.enabled(3));
    CHECK(l.master.counts().nmt_resets == 2);
    CHECK(l.drive.counts().nmt_resets == 1);
    CHECK(l.master.counts().configurations == configs + 1);
    CHECK(l.drive.sdo_writes().size() == writes + 11);      // the configuration again
    CHECK(*l.drive.value(0x1016, 1) == (127 << 16 | 500));  // watched again
    CHECK(*l.drive.value(0x1017, 0) == 100);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.drive.nmt() == stand::facts::Nmt::Operational);
    // and it moves again
    REQUIRE(l.command(TableCommandCode::MoveRelative, 4, 10 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(4, 3));
  }

  TEST_CASE("the master's loop held: the drive's heartbeat is judged in the time it ran") {
    // The whole machine stops 0.4 s (the drive's heartbeat timeout is 0.3 s,
    // its own watch of ours 0.5 s): the master's first tick after it comes
    // before the drive has sent anything. The hold does not count; a drive
    // silent from just before it is lost 0.3 s of running time after its
    // last heartbeat.
    for (const bool silent : {false, true}) {
      CAPTURE(silent);
      stand::Drive402Faults df;
      if (silent) df.silent_at_s = 1.95;
      Loop l(master_settings(), drive_setup(), df);
      l.start();
      REQUIRE(l.running());
      REQUIRE(l.enabled(1));
      l.run_until([&] { return l.t >= 2.0 - 1e-9; }, 3);
      const double from = l.t;
      l.t += 0.4;
      l.master.held(from, l.t);
      l.master.tick(l.t, l.from_master);
      l.deliver();
      if (!silent) {
        l.run_for(1.0);
        CHECK(l.master.status().state == TableState::Holding);
        CHECK(l.master.status().fault == FaultCode::None);
        continue;
      }
      CHECK(l.master.status().fault == FaultCode::None);
      REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 1));
      CHECK(l.master.status().fault == FaultCode::DriveHeartbeatLost);
      // the last heartbeat at most 0.1 s before 1.95 s; 0.3 s and the hold on
      CHECK(l.t > 1.85 + 0.3 + 0.4);
      CHECK(l.t < 1.95 + 0.3 + 0.4 + 0.002);
    }
  }

  TEST_CASE(
      "the machine held past a set-point's timeout: its acknowledgement, read first, counts") {
    // The move goes out; the whole machine stops 300 ms (the set-point's
    // timeout is 200 ms here), the drive with it. Its acknowledgement is
    // read before the tick that tells the master of the hold: the timeout
    // is judged in that tick, after it, and the move goes on.
    cia402::MasterSettings ms = master_settings();
    ms.set_point_timeout_s = 0.2;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    // the drive's frames held back while the move goes out
    l.tamper = [](can::Frame& f) { f.id = 0x7FF; };
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
    l.tamper = nullptr;
    const double from = l.t;
    l.t += 0.3;
    // its heartbeat read first, then its TPDO with the acknowledgement
    l.master.on_frame(canopen::heartbeat_frame(5, canopen::NmtState::Operational), l.t,
                      l.from_master);
    l.drive.advance(l.t, l.from_drive);
    l.deliver();
    l.master.held(from, l.t);
    l.master.tick(l.t, l.from_master);
    l.deliver();
    CHECK(l.master.status().fault == FaultCode::None);
    REQUIRE(l.in_position(2, 5));
    CHECK(l.master.status().fault == FaultCode::None);
  }

  TEST_CASE("the host heartbeat stops: the drive quick-stops per 0x6007, EMCY 0x8130") {
    Loop l;
    REQUIRE(l.turning(1.0, 180, 30));
    l.master.set_host_heartbeat(false);
    const double stopped_at = l.t;
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 1));
    // the last heartbeat at most 0.1 s before, then 0.5 s of the drive's watch
    CHECK(l.t - stopped_at > 0.39);
    CHECK(l.t - stopped_at < 0.51);
    CHECK(l.master.status().fault_name == "EMCY 0x8130 life guard error or heartbeat error");
    CHECK(l.drive.state() == DriveState::QuickStopActive);
    CHECK(l.drive.emcy_sent().back() == 0x8130);
    CHECK(l.drive.counts().quick_stops == 1);
    // the sequencer's quick stop is acknowledged: the drive stopped itself
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    l.run_for(0.5);
    CHECK(l.master.status().ack == 3);
    CHECK_FALSE(l.drive.moving(l.t));
  }

  TEST_CASE("the host heartbeat stops with 0x6007 = 1: the drive goes to fault") {
    cia402::MasterSettings ms = master_settings();
    ms.abort_connection_option = 1;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    CHECK(*l.drive.value(0x6007, 0) == 1);
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg));
    l.run_for(1.0);
    l.master.set_host_heartbeat(false);
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 1));
    l.run_for(0.5);
    CHECK(l.drive.state() == DriveState::Fault);
    CHECK(*l.drive.value(0x603F, 0) == 0x8130);
    CHECK_FALSE(l.drive.moving(l.t));
    CHECK(l.master.status().fault_name == "EMCY 0x8130 life guard error or heartbeat error");
    l.master.set_host_heartbeat(true);
    REQUIRE(l.enabled(3));
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("the drive leaves operational or boots again: a fault, and a new configuration") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    std::string why;
    SUBCASE("another node sends it to pre-operational") {
      l.drive.receive(l.t, canopen::nmt_frame(canopen::NmtCommand::EnterPreOperational, 5),
                      l.from_drive);
      why = "drive NMT state pre-operational while running";
    }
    SUBCASE("another node resets it") {
      l.drive.receive(l.t, canopen::nmt_frame(canopen::NmtCommand::ResetNode, 5), l.from_drive);
      why = "drive booted again (boot-up while running)";
    }
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 0.5));
    CHECK(l.master.status().fault == FaultCode::DriveNmtState);
    CHECK(l.master.status().fault_name == why);
    CHECK(l.drive.nmt() == stand::facts::Nmt::PreOperational);
    REQUIRE(l.enabled(2));
    CHECK(l.master.counts().nmt_resets == 2);
    CHECK(l.master.counts().configurations == 2);
    CHECK(l.drive.nmt() == stand::facts::Nmt::Operational);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("a pre-operational heartbeat after our NMT start: late news within the timeout") {
    // drive heartbeat every 100 ms, lost after 300 ms
    Loop l;
    l.start();
    REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Running; }, 2.0));
    const double started = l.t;
    // the drive's own frames held back from here: only what the test sends
    const can::Frame pre_op = canopen::heartbeat_frame(5, canopen::NmtState::PreOperational);
    SUBCASE("a late one, before any operational one: no fault") {
      l.master.on_frame(pre_op, started + 0.25, l.from_master);  // two periods on
      CHECK(l.master.status().fault == FaultCode::None);
      l.master.on_frame(pre_op, started + 0.29, l.from_master);
      CHECK(l.master.status().fault == FaultCode::None);
      // and it still says pre-operational after the timeout: it never started
      l.master.on_frame(pre_op, started + 0.35, l.from_master);
      CHECK(l.master.status().fault == FaultCode::DriveNmtState);
    }
    SUBCASE("after an operational one: a fault at once") {
      l.master.on_frame(canopen::heartbeat_frame(5, canopen::NmtState::Operational), started + 0.05,
                        l.from_master);
      l.master.on_frame(pre_op, started + 0.1, l.from_master);
      CHECK(l.master.status().fault == FaultCode::DriveNmtState);
      CHECK(l.master.status().fault_name == "drive NMT state pre-operational while running");
    }
  }

  TEST_CASE("change set immediately: a new target while moving is taken at once") {
    cia402::MasterSettings ms = master_settings();
    ms.change_set_immediately = true;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 2, 180 * kDeg, 30 * kDeg));
    l.run_for(2.0);
    REQUIRE(l.master.status().state == TableState::Moving);
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 3, 20 * kDeg, 30 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.1));
    CHECK((l.drive.controlword() & 0x20) != 0);
    REQUIRE(l.in_position(3, 10));
    CHECK(std::fabs(l.drive.angle(l.t) - 20 * kDeg) * l.drive.counts_per_rad() <= 1.0);
    CHECK(l.drive.counts().set_points == 2);
  }

  TEST_CASE("without change set immediately a move under way is not replaced") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 2, 90 * kDeg, 30 * kDeg));
    l.run_for(1.0);
    const Status s = l.command(TableCommandCode::MoveAbsolute, 3, 20 * kDeg, 30 * kDeg);
    REQUIRE_FALSE(s.ok());
    CHECK(s.error().message.find("under way") != std::string::npos);
    REQUIRE(l.in_position(2, 10));
    CHECK(l.drive.position_counts(l.t) == 250000);
  }

  TEST_CASE("quick stop option 2: the drive ends switch on disabled, still quick-stopped to us") {
    cia402::MasterSettings ms = master_settings();
    ms.quick_stop_option = 2;
    Loop l(ms);
    REQUIRE(l.turning(1.0, 90, 30));
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    l.run_for(0.5);
    CHECK(l.drive.state() == DriveState::SwitchOnDisabled);
    CHECK_FALSE(l.drive.moving(l.t));
    CHECK(l.master.status().ack == 3);
    CHECK(l.master.status().state == TableState::QuickStopped);
    REQUIRE(l.enabled(4));
  }

  TEST_CASE("the start-up budget: every transfer of a configuration, inert settings too") {
    // 11 writes of the master's, 1 of profile position's (0x6081), 3 PDOs
    // of at most 6 + 8 transfers, the 0x60F2 read and 0x6061: 56 SDO
    // timeouts, besides the boot-up and the mode switch
    cia402::MasterSettings s = master_settings();
    s.boot_timeout_s = 2;
    s.sdo_timeout_s = 0.5;
    s.mode_switch_timeout_s = 0.2;
    const double budget = 2 + 56 * 0.5 + 0.2;
    CHECK(cia402::Master(s).start_up_budget_s() == doctest::Approx(budget).epsilon(1e-12));
    // a profile velocity beyond the drive's u32 counts: settings that fail,
    // a master that sends nothing, and whose budget is still a number
    s.counts_per_rev = 1e12;
    REQUIRE_FALSE(s.check());
    const cia402::Master inert(s);
    double b = 0;
    CHECK_NOTHROW(b = inert.start_up_budget_s());
    CHECK(b == doctest::Approx(budget).epsilon(1e-12));
  }

  TEST_CASE("following error in the statusword alone, no EMCY: the master in fault, named so") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    // bit 13 in the drive's TPDO1 (statusword at byte 0, CiA 402's default
    // layout), its objects and EMCYs untouched
    l.tamper = [](can::Frame& f) {
      if (f.id == 0x180 + 5) f.data[1] = static_cast<std::uint8_t>(f.data[1] | 0x20);
    };
    l.run_for(0.05);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK(l.master.status().fault == FaultCode::FollowingError);
    CHECK(l.master.status().fault_name == "following error (statusword bit 13)");
    CHECK(l.master.counts().emcy == 0);
  }

  TEST_CASE("following error: statusword bit 13 and EMCY 0x8611, the master in fault") {
    stand::Drive402Faults df;
    df.following_error_at_s = 2.0;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 3));
    CHECK(l.master.status().fault_name == "EMCY 0x8611 following error");
    l.run_for(0.5);
    CHECK(l.drive.state() == DriveState::Fault);
    CHECK((l.drive.statusword() & 0x2000) != 0);
    REQUIRE(l.master.statusword().has_value());
    CHECK((*l.master.statusword() & 0x2000) != 0);
    REQUIRE(l.enabled(3));
    CHECK((l.drive.statusword() & 0x2000) == 0);
  }

  TEST_CASE("a refused move is never acknowledged: a set-point timeout") {
    stand::Drive402Faults df;
    df.refuse_moves = true;
    Loop l(master_settings(), drive_setup(), df);
    REQUIRE(l.turning(0.45, 10, 30));
    CHECK(l.master.status().ack == 1);
    CHECK(l.master.status().state == TableState::Holding);
    CHECK((l.drive.controlword() & 0x10) != 0);  // bit 4 held, waiting
    // no bit 12 within the set-point timeout (0.5 s): a fault that names it
    l.run_for(0.1);
    CHECK(l.master.status().ack == 1);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK(l.master.status().fault == FaultCode::SetPointTimeout);
    CHECK(l.master.status().fault_name.find("set-point not acknowledged") != std::string::npos);
    CHECK((l.drive.controlword() & 0x10) == 0);
    CHECK(l.drive.counts().set_points == 0);
    CHECK(l.drive.angle(l.t) == 0);
  }

  TEST_CASE("targets and rates that do not fit the drive's counts: an error, no frame") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    const auto sent = l.sent.size();
    auto refused = [&](TableCommandCode c, double target, double rate, const char* why) {
      const Status s = l.command(c, 7, target, rate);
      REQUIRE_FALSE(s.ok());
      CHECK(s.error().message.find(why) != std::string::npos);
    };
    // 2148 revolutions are 2.148e9 counts, beyond s32
    refused(TableCommandCode::MoveAbsolute, 2148 * kTwoPi, 0.1, "32-bit");
    refused(TableCommandCode::MoveRelative, -2148 * kTwoPi, 0.1, "32-bit");
    refused(TableCommandCode::MoveRelative, 1.0, 1e5, "u32");
    refused(TableCommandCode::MoveRelative, 1.0, 0, "positive");
    refused(TableCommandCode::MoveRelative, 1.0, NAN, "positive");
    refused(TableCommandCode::MoveRelative, NAN, 0.1, "32-bit");
    CHECK(l.sent.size() == sent);
    CHECK(l.master.status().ack == 1);
    CHECK(l.drive.counts().set_points == 0);
    // within the range: 2147 revolutions fit
    CHECK(l.command(TableCommandCode::MoveAbsolute, 8, 2147 * kTwoPi, 0.1).ok());
  }

  TEST_CASE("settings whose values do not fit the drive's objects are refused") {
    cia402::MasterSettings s = master_settings();
    CHECK(s.check().ok());
    s.profile_acceleration_rps2 = 1e-9;  // rounds to 0 counts/s^2
    CHECK_FALSE(cia402::Master::create(s).ok());
    s = master_settings();
    s.profile_velocity_rps = 1e5;
    const auto r = cia402::Master::create(s);
    REQUIRE_FALSE(r.ok());
    CHECK(r.error().message.find("0x6081") != std::string::npos);
    s = master_settings();
    s.host_node_id = s.node_id;
    CHECK_FALSE(s.check().ok());
    s = master_settings();
    s.host_heartbeat_timeout_s = 70;  // 70000 ms > u16
    CHECK_FALSE(s.check().ok());
    // constructed anyway: inert, it says why and sends nothing
    cia402::Master m(s);
    std::vector<can::Frame> out;
    m.start(0, out);
    m.tick(1, out);
    CHECK(out.empty());
    CHECK(m.status().state == TableState::Fault);
    CHECK(m.status().fault_name.find("invalid settings: heartbeat times") == 0);
    const Status c = m.command(TableCommandCode::Enable, 1, 0, 0, 1, out);
    REQUIRE_FALSE(c.ok());
    CHECK(c.error().message.find("invalid CANopen master settings") == 0);
    CHECK(out.empty());
  }

  TEST_CASE("the drive's own TPDO1 transmission, read back: its timer must fit the heartbeat") {
    // The mapping not written and no SYNC: how often TPDO1 comes is the
    // drive's own configuration (0x1800:02 and :05), read back and judged
    // by the rule the written one has (at most half the drive heartbeat
    // timeout, 300 ms here).
    cia402::MasterSettings ms = master_settings();
    ms.configure_mapping = false;
    ms.drive_heartbeat_timeout_s = 0.3;
    struct Case {
      std::uint16_t timer_ms;
      std::uint8_t type;
      const char* why;  // empty: configured
    };
    for (const Case c :
         {Case{150, 0xFF, ""}, Case{10, 0xFE, ""},
          Case{151, 0xFF, "TPDO1's event timer (0x1800:05) reads 151 ms: it must be"},
          Case{0, 0xFF, "reads 0 ms (sent on change only"},
          Case{10, 1, "TPDO1's transmission type (0x1800:02) reads 1: with no SYNC"}}) {
      CAPTURE(c.timer_ms);
      CAPTURE(static_cast<int>(c.type));
      stand::Drive402Setup ds = drive_setup();
      ds.tpdo_event_timer_ms = c.timer_ms;
      ds.tpdo_transmission_type = c.type;  // as the drive's vendor tool left them
      Loop l(ms, ds);
      l.start();
      const bool running = l.running();
      if (*c.why == 0) {
        CHECK(running);
        continue;
      }
      CHECK_FALSE(running);
      CHECK(l.master.phase() == cia402::CommPhase::Failed);
      CHECK(l.master.status().fault == FaultCode::Configuration);
      CHECK_MESSAGE(l.master.status().fault_name.find(c.why) != std::string::npos,
                    l.master.status().fault_name);
    }
  }

  TEST_CASE("settings the drive would misread are refused: times, option codes, COB-IDs") {
    auto refused = [](const cia402::MasterSettings& s, const char* why) {
      const auto r = cia402::Master::create(s);
      REQUIRE_FALSE(r.ok());
      CHECK(r.error().message.find(why) != std::string::npos);
    };
    cia402::MasterSettings s = master_settings();
    REQUIRE(cia402::Master::create(s).ok());
    SUBCASE("a host heartbeat consumer time under 1 ms would switch the watch off") {
      s.host_heartbeat_period_s = 0.0001;
      s.host_heartbeat_timeout_s = 0.0004;
      refused(s, "1 to 65535 ms");
    }
    SUBCASE("TPDO1 rarer than half the drive heartbeat timeout: no rate, no rest known") {
      s.drive_heartbeat_timeout_s = 0.3;
      s.configure_mapping = true;
      s.tpdo_event_timer_s = 0.15;
      CHECK(cia402::Master::create(s).ok());
      s.tpdo_event_timer_s = 0.2;
      refused(s, "TPDO1's period (200 ms, its event timer) must be positive and at most half");
      s.configure_mapping = false;  // the drive's own transmission: its configuration's
      CHECK(cia402::Master::create(s).ok());
      s.sync_period_s = 0.2;
      refused(s, "TPDO1's period (200 ms, the SYNC period)");
      s.sync_period_s = 0.1;
      CHECK(cia402::Master::create(s).ok());
    }
    SUBCASE("option codes CiA 402 does not define") {
      s.quick_stop_option = 9;
      refused(s, "0x605A");
      s.quick_stop_option = -1;
      refused(s, "0x605A");
      s = master_settings();
      s.abort_connection_option = 4;
      refused(s, "0x6007");
      s.abort_connection_option = -2;
      refused(s, "0x6007");
    }
    SUBCASE("option codes that let the table coast or run on without its host") {
      s.quick_stop_option = 0;
      refused(s, "coast on a quick stop");
      s = master_settings();
      s.abort_connection_option = 0;
      refused(s, "(no action, 0x6007)");
      s.abort_connection_option = 2;
      refused(s, "(disable voltage, 0x6007)");
      for (const int ok : {1, 3}) {
        s.abort_connection_option = static_cast<std::int16_t>(ok);
        CHECK(cia402::Master::create(s).ok());
      }
    }
    SUBCASE("PDO identifiers that collide") {
      s.tpdo = cia402::TpdoLayout::defaults(5);
      s.tpdo->cob_id = s.rpdo_layout().cob_id;
      refused(s, "TPDO1's COB-ID 0x205 is RPDO1's");
      s.tpdo->cob_id = 0x585;
      refused(s, "the drive's SDO response");
      s.tpdo->cob_id = 0x085;
      refused(s, "the drive's EMCY");
      s.tpdo->cob_id = 0x77F;
      refused(s, "our heartbeat");
      s = master_settings();
      s.velocity_pdo = true;
      s.tpdo2 = cia402::VelocityPdoLayout::defaults(5);
      s.tpdo2->cob_id = 0x705;
      refused(s, "TPDO2's COB-ID 0x705 is the drive's heartbeat");
    }
  }

  TEST_CASE("frames of a wrong length are counted and skipped") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    can::Frame f;
    f.id = 0x185;  // TPDO1, 3 bytes
    f.len = 3;
    const auto tpdo = l.master.counts().tpdo;
    l.master.on_frame(f, l.t, l.from_master);
    f.id = 0x85;  // EMCY, 4 bytes
    f.len = 4;
    l.master.on_frame(f, l.t, l.from_master);
    f.id = 0x705;  // heartbeat, 2 bytes
    f.len = 2;
    l.master.on_frame(f, l.t, l.from_master);
    CHECK(l.master.counts().malformed == 3);
    CHECK(l.master.counts().tpdo == tpdo);
    CHECK(l.master.emergencies().empty());
    CHECK(l.master.status().state == TableState::Holding);
    // the drive counts a short RPDO and says so by EMCY 0x8210
    f.id = 0x205;
    f.len = 2;
    l.drive.receive(l.t, f, l.from_drive);
    l.deliver();
    CHECK(l.drive.counts().malformed == 1);
    CHECK(l.master.status().fault_name == "EMCY 0x8210 PDO not processed due to length error");
  }

  TEST_CASE("garbage on the bus: counted and skipped, nothing thrown") {
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    std::mt19937 rng(7);
    const std::uint32_t master_ids[] = {0x585, 0x705, 0x085, 0x185, 0x123, 0x7FF};
    std::uint64_t wrong_length = 0;
    const auto malformed = l.master.counts().malformed;
    for (int i = 0; i < 5000; ++i) {
      can::Frame f;
      f.id = master_ids[rng() % 6];
      f.len = static_cast<std::uint8_t>(rng() % 9);
      for (std::size_t k = 0; k < f.len; ++k) f.data[k] = static_cast<std::uint8_t>(rng());
      if ((f.id == 0x185 && f.len < 6) || (f.id == 0x705 && f.len != 1) ||
          (f.id == 0x085 && f.len != 8))
        ++wrong_length;
      CHECK_NOTHROW(l.master.on_frame(f, l.t, l.from_master));
    }
    CHECK(l.master.counts().malformed - malformed == wrong_length);
    CHECK(l.master.sdo_counts().malformed > 0);
    // the random EMCYs and statuswords leave it in fault, with a name
    CHECK(l.master.status().state == TableState::Fault);
    CHECK_FALSE(l.master.status().fault_name.empty());
    // the drive takes garbage too: NMT, SYNC, SDO, RPDO, a heartbeat
    const std::uint32_t drive_ids[] = {0x000, 0x080, 0x605, 0x205, 0x77F};
    for (int i = 0; i < 5000; ++i) {
      can::Frame f;
      f.id = drive_ids[rng() % 5];
      f.len = static_cast<std::uint8_t>(rng() % 9);
      for (std::size_t k = 0; k < f.len; ++k) f.data[k] = static_cast<std::uint8_t>(rng());
      CHECK_NOTHROW(l.drive.receive(l.t, f, l.from_drive));
      l.from_drive.clear();
    }
    CHECK(l.drive.counts().malformed > 0);
    CHECK(l.drive.counts().sdo_aborts > 0);
    // and both go on: time passes without a throw
    CHECK_NOTHROW(l.run_for(1.0));
  }

  TEST_CASE("position actual unwrapped across the drive's 32-bit wrap") {
    cia402::Master m(master_settings());
    std::vector<can::Frame> out;
    auto tpdo = [&](std::uint32_t raw, double t) {
      can::Frame f;
      f.id = 0x185;
      f.len = 6;
      canopen::put_le(f.data, 0, 2, 0x0250);
      canopen::put_le(f.data, 2, 4, raw);
      m.on_frame(f, t, out);
    };
    tpdo(0x7FFFFFF0u, 0.00);
    tpdo(0x80000010u, 0.01);  // +32 counts through the wrap
    tpdo(0x7FFFFFFFu, 0.02);  // and back, -17
    std::vector<cia402::EncoderSample> smp;
    m.take_samples(smp);
    REQUIRE(smp.size() == 3);
    CHECK(smp[0].counts == 0x7FFFFFF0LL);
    CHECK(smp[1].counts == 0x80000010LL);
    CHECK(smp[2].counts == 0x7FFFFFFFLL);
    const double cpr = 1e6 / kTwoPi;
    CHECK(smp[1].angle_rad - smp[0].angle_rad == doctest::Approx(32 / cpr).epsilon(1e-6));
    CHECK(smp[1].t_s == 0.01);
    CHECK(out.empty());  // not started: nothing to say
    // the drive reboots: its count starts afresh, not as a step from the last
    tpdo(0x80000010u, 0.03);
    CHECK(m.counts().position_resets == 0);
    can::Frame boot;
    boot.id = 0x705;
    boot.len = 1;
    boot.data[0] = 0x00;
    m.on_frame(boot, 0.04, out);
    CHECK(m.counts().position_resets == 1);
    tpdo(5, 0.05);
    smp.clear();
    m.take_samples(smp);
    REQUIRE(smp.size() == 2);
    CHECK(smp[1].counts == 5);
    // a heartbeat whose state byte CiA 301 does not define: counted, skipped
    boot.data[0] = 0x42;
    m.on_frame(boot, 0.06, out);
    CHECK(m.counts().unknown_nmt_states == 1);
    CHECK(m.counts().heartbeats == 1);
  }

  TEST_CASE("PDO layouts from the stand's DBC drive the mapping and the codec") {
    const char* dbc =
        "VERSION \"\"\n\nBU_: HOST DRV\n\n"
        "BO_ 389 DRV_Status: 6 DRV\n"
        " SG_ Position : 0|32@1- (1,0) [0|0] \"counts\" HOST\n"
        " SG_ Statusword : 32|16@1+ (1,0) [0|0] \"\" HOST\n\n"
        "BO_ 517 DRV_Command: 6 HOST\n"
        " SG_ Target : 0|32@1- (1,0) [0|0] \"counts\" DRV\n"
        " SG_ Controlword : 32|16@1+ (1,0) [0|0] \"\" DRV\n"
        " SG_ Scaled : 0|32@1- (0.001,0) [0|0] \"deg\" DRV\n"
        " SG_ Motorola : 39|16@0+ (1,0) [0|0] \"\" DRV\n";
    auto db = can::parse_dbc(dbc);
    REQUIRE(db.ok());
    const can::Message* tx = db->find("DRV_Status");
    const can::Message* rx = db->find("DRV_Command");
    REQUIRE(tx != nullptr);
    REQUIRE(rx != nullptr);
    auto tpdo = cia402::TpdoLayout::from_dbc(*tx, "Statusword", "Position");
    REQUIRE(tpdo.ok());
    CHECK(tpdo->cob_id == 0x185);
    CHECK(tpdo->statusword.offset == 4);
    CHECK(tpdo->position_actual.offset == 0);
    auto rpdo = cia402::RpdoLayout::from_dbc(*rx, "Controlword", "Target");
    REQUIRE(rpdo.ok());
    CHECK(rpdo->controlword.offset == 4);
    CHECK(rpdo->target_position.offset == 0);
    CHECK_FALSE(cia402::RpdoLayout::from_dbc(*rx, "Controlword", "Scaled").ok());
    CHECK_FALSE(cia402::RpdoLayout::from_dbc(*rx, "Motorola", "Target").ok());
    CHECK_FALSE(cia402::RpdoLayout::from_dbc(*rx, "Controlword", "Nothing").ok());
    // the master writes that layout and speaks it
    cia402::MasterSettings ms = master_settings();
    ms.configure_mapping = true;
    ms.rpdo = *rpdo;
    ms.tpdo = *tpdo;
    Loop l(ms);
    l.start();
    REQUIRE(l.running());
    CHECK(*l.drive.value(0x1600, 1) == 0x607A0020);
    CHECK(*l.drive.value(0x1600, 2) == 0x60400010);
    CHECK(*l.drive.value(0x1A00, 1) == 0x60640020);
    CHECK(*l.drive.value(0x1A00, 2) == 0x60410010);
    CHECK(*l.drive.value(0x1800, 5) == 10);
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 2, 30 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(2, 5));
    CHECK(std::fabs(l.master.angle_rad() - 30 * kDeg) * 1e6 / kTwoPi <= 1.0);
    CHECK(std::fabs(l.drive.angle(l.t) - 30 * kDeg) * 1e6 / kTwoPi <= 1.0);
  }

  TEST_CASE("no boot-up: a fault that names it, and the reset is tried again") {
    stand::Drive402Faults df;
    df.silent_at_s = 0;  // never heard
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    l.run_for(2.5);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK(l.master.status().fault == FaultCode::NoBootUp);
    CHECK(l.master.status().fault_name.find("no boot-up from drive node 5") != std::string::npos);
    CHECK(l.master.counts().nmt_resets == 2);
    CHECK(l.drive.counts().nmt_resets == 0);
  }

  TEST_CASE("a drive that samples RPDO1 once a cycle: bit 4 held until bit 12, then dropped") {
    cia402::MasterSettings ms = master_settings();
    stand::Drive402Setup ds = drive_setup();
    ds.cycle_s = 0.004;  // the drive sees the last controlword of each 4 ms
    SUBCASE("event-driven TPDO") {}
    SUBCASE("TPDO1 on SYNC, RPDO1 taken at once") {
      ms.sync_period_s = 0.01;
      ds.cycle_s = 0;
    }
    SUBCASE("TPDO1 on SYNC, cyclic drive") {
      ms.sync_period_s = 0.01;
    }
    Loop l(ms, ds);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 20 * kDeg, 30 * kDeg));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 2; }, 0.2));
    CHECK(l.drive.counts().set_points == 1);
    REQUIRE(l.in_position(2, 5));
    CHECK(l.drive.position_counts(l.t) == 55556);  // 20 deg: 55555.6 counts
    // every RPDO from the set-point to the first without bit 4 held it, and
    // bit 4 dropped only after a statusword with bit 12 reached the master
    const auto rpdo = canopen::kRpdo1Base + 5;
    bool raised = false, dropped = false;
    for (const can::Frame& f : l.sent) {
      if (f.id != rpdo) continue;
      const bool bit4 = (f.data[0] & 0x10) != 0;
      if (bit4) raised = true;
      if (raised && !bit4) dropped = true;
      if (dropped) CHECK_FALSE(bit4);  // one set-point, one rising edge
    }
    CHECK(raised);
    CHECK(dropped);
    CHECK((l.drive.controlword() & 0x10) == 0);
    CHECK((l.drive.statusword() & 0x1000) == 0);
    // and a second move goes the same way
    REQUIRE(l.command(TableCommandCode::MoveRelative, 3, -20 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(3, 5));
    CHECK(l.drive.counts().set_points == 2);
    CHECK(l.drive.position_counts(l.t) == 0);
  }

  TEST_CASE("a stale frozen TPDO and a drive that ignores the first fault reset") {
    stand::Drive402Faults df;
    df.fault_at_s = 0.5;
    df.fault_code = 0x4310;
    df.stale = stand::StalePdo::Frozen;
    df.resets_ignored = 1;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    l.run_for(1.0);
    REQUIRE(l.master.status().fault == FaultCode::Emcy);
    // the reset is ignored; the frozen TPDO keeps saying operation enabled
    CHECK_FALSE(l.enabled(2));
    CHECK(l.drive.state() == DriveState::Fault);
    CHECK(l.master.drive_state() == State::OperationEnabled);
    CHECK(l.master.status().state == TableState::Fault);
    CHECK(l.master.status().ack == 1);
    CHECK_FALSE(l.command(TableCommandCode::MoveRelative, 3, 0.1, 0.1).ok());
    // the next reset takes: switch on disabled seen, then enabled
    REQUIRE(l.enabled(4));
    CHECK(l.drive.counts().fault_resets == 1);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("the fault reset's rising edge survives a drive that samples RPDO1 once a cycle") {
    stand::Drive402Setup ds = drive_setup();
    ds.cycle_s = 0.004;
    stand::Drive402Faults df;
    df.fault_at_s = 0.5;
    df.fault_code = 0x3210;
    df.resets_ignored = 1;
    Loop l(master_settings(), ds, df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    l.run_for(1.0);
    REQUIRE(l.master.status().fault == FaultCode::Emcy);
    CHECK_FALSE(l.enabled(2));  // the first reset is ignored: bit 7 stays high
    CHECK(l.drive.state() == DriveState::Fault);
    REQUIRE((l.drive.controlword() & 0x80) != 0);
    // the second needs bit 7 low for one sample, then high
    REQUIRE(l.enabled(3));
    CHECK(l.drive.counts().fault_resets == 1);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
  }

  TEST_CASE("quick stop outside running: refused while the drive boots, by SDO while configuring") {
    stand::Drive402Setup ds = drive_setup();
    ds.mode_switch_s = 0.05;  // the configuration waits for 0x6061
    Loop l(master_settings(), ds);
    l.start();
    REQUIRE(l.master.phase() == cia402::CommPhase::WaitBootUp);
    // no SDO reaches a drive before its boot-up: not sent, not acknowledged
    CHECK_FALSE(l.command(TableCommandCode::QuickStop, 7).ok());
    CHECK(l.master.status().ack == 0);
    REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Configuring; }, 0.5));
    const auto writes = l.drive.sdo_writes().size();
    REQUIRE(l.command(TableCommandCode::QuickStop, 8));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 8; }, 0.1));
    // acknowledged on the drive's answer to the write of 0x6040
    REQUIRE(l.drive.sdo_writes().size() > writes);
    CHECK(l.drive.sdo_writes()[writes] == std::make_pair<std::uint16_t, std::uint8_t>(0x6040, 0));
    CHECK(*l.drive.value(0x6040, 0) == 0x0002);
    REQUIRE(l.running());
    l.run_for(0.1);
    CHECK(l.master.status().state == TableState::QuickStopped);
    CHECK((l.drive.controlword() & 0x8F) == 0x02);  // and by PDO once running
  }

  TEST_CASE("a quick stop while the configuration is queued goes next, and outlives its failure") {
    stand::Drive402Faults df;
    bool fails = false;
    SUBCASE("the configuration goes on") {}
    SUBCASE("the configuration's first write is refused") {
      fails = true;
      df.refuse_objects[0x606000] = 0x06090030;  // value range exceeded
    }
    Loop l(master_settings(), drive_setup(), df);
    l.hold_when_configuring = true;
    l.start();
    REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Configuring; }, 0.5));
    // the first write (0x6060) is under way, its answer held; the rest queued
    REQUIRE(l.drive.sdo_writes().size() <= 1);
    REQUIRE(l.command(TableCommandCode::QuickStop, 8));
    l.hold_when_configuring = false;
    REQUIRE(l.run_until([&] { return l.master.status().ack == 8; }, 0.1));
    CHECK(*l.drive.value(0x6040, 0) == 0x0002);
    using W = std::pair<std::uint16_t, std::uint8_t>;
    const auto& writes = l.drive.sdo_writes();  // those the drive took
    if (fails) {
      CHECK(l.master.phase() == cia402::CommPhase::Failed);
      CHECK(l.master.status().fault == FaultCode::Configuration);
      // the quick stop, and nothing of the configuration after its failure
      CHECK(writes == std::vector<W>{{0x6040, 0}});
    } else {
      REQUIRE(writes.size() > 2);
      CHECK(writes[0] == W{0x6060, 0});
      CHECK(writes[1] == W{0x6040, 0});  // right behind the one under way
      CHECK(l.running());
    }
  }

  TEST_CASE("an EMCY that warns, in a move: told once, nothing latched, the move goes on") {
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;
    cia402::MasterSettings ms = master_settings();
    SUBCASE("0x8120, CAN error passive: a warning by the default classes") {
      df.warning_code = 0x8120;
    }
    SUBCASE("0x4210, excess temperature: a warning by the configuration's 0x4200-0x42FF") {
      df.warning_code = 0x4210;
      ms.emcy_warnings = {{0x4200, 0x42FF}};
    }
    Loop l(ms, drive_setup(), df);
    REQUIRE(l.turning(0));  // started, enabled, a turn of 360 deg at 30 deg/s asked
    const auto from = l.sent.size();
    REQUIRE(l.t < 1.0);
    l.run_for(1.5);  // the warning at 1 s
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.master.counts().emcy == 1);
    CHECK(l.master.counts().emcy_warnings == 1);
    const auto& told = l.master.notices();
    REQUIRE(!told.empty());
    char code[8];
    std::snprintf(code, sizeof code, "0x%04X", static_cast<unsigned>(df.warning_code));
    CHECK(told.back().find(std::string("the drive warned: EMCY ") + code) == 0);
    // the drive's own statusword was read after it (its TPDO may be stale)
    CHECK(l.statusword_reads(from) >= 1);
    CHECK(l.drive.moving(l.t));
    CHECK(l.master.status().state == TableState::Moving);
    // the move ends where it was headed, in position, with no quick stop
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::InPosition; }, 20));
    CHECK(l.drive.counts().quick_stops == 0);
    CHECK(l.drive.angle(l.t) == doctest::Approx(2 * M_PI).epsilon(1e-6));
  }

  TEST_CASE(
      "a warning's code from a drive whose statusword shows the fault later: the second "
      "read finds it") {
    // its TPDO silent in fault, its statusword in fault 50 ms after its
    // EMCY: the read at once finds it enabled, the one 0.1 s later in fault
    stand::Drive402Faults df;
    df.fault_at_s = 1.0;
    df.fault_code = 0x4310;
    df.fault_state_after_emcy_s = 0.05;
    df.stale = stand::StalePdo::Silent;
    cia402::MasterSettings ms = master_settings();
    ms.emcy_warnings = {{0x4000, 0x4FFF}};
    Loop l(ms, drive_setup(), df);
    REQUIRE(l.turning(0));  // started, enabled, a turn of 360 deg at 30 deg/s asked
    const auto from = l.sent.size();
    REQUIRE(l.run_until([&] { return l.master.status().fault != FaultCode::None; }, 1.0));
    CHECK(l.t > 1.0 + cia402::Master::kWarningRecheckS - 0.01);
    CHECK(l.t < 1.0 + cia402::Master::kWarningRecheckS + 0.05);
    CHECK(l.master.status().fault == FaultCode::Emcy);
    CHECK(l.master.status().fault_name.find("EMCY 0x4310") == 0);
    CHECK(l.master.status().fault_name.find("read after it") != std::string::npos);
    CHECK(l.statusword_reads(from) == 2);
    CHECK(l.drive.state() != DriveState::OperationEnabled);
  }

  TEST_CASE("a warning's code, and the drive's statusword cannot be read: taken for a fault") {
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;
    df.warning_code = 0x8120;
    df.refuse_objects[0x604100] = 0x08000000;  // general error
    Loop l(master_settings(), drive_setup(), df);
    REQUIRE(l.turning(1.2));
    CHECK(l.master.status().fault == FaultCode::Emcy);
    const std::string name = l.master.status().fault_name;
    CAPTURE(name);
    CHECK(name.find("EMCY 0x8120") == 0);
    CHECK(name.find("the drive's statusword could not be read after it (read 0x6041:00: "
                    "0x08000000") != std::string::npos);
  }

  TEST_CASE("an EMCY's class is the configuration's: no ranges, every code a fault") {
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;
    df.warning_code = 0x8120;  // a warning by the default classes
    cia402::MasterSettings ms = master_settings();
    ms.emcy_warnings.clear();
    Loop l(ms, drive_setup(), df);
    REQUIRE(l.turning(1.5));
    CHECK(l.master.status().fault == FaultCode::Emcy);
    CHECK(l.master.status().fault_name.find("EMCY 0x8120") == 0);
    CHECK(l.master.counts().emcy_warnings == 0);
  }

  TEST_CASE("a drive fault whose EMCY code alone warns: the statusword's fault bit decides") {
    stand::Drive402Faults df;
    df.fault_at_s = 1.0;
    df.fault_code = 0x4310;  // excess temperature drive: a warning by the stand's classes
    cia402::MasterSettings ms = master_settings();
    ms.emcy_warnings = {{0x4000, 0x4FFF}};
    Loop l(ms, drive_setup(), df);
    REQUIRE(l.turning(1.5));
    REQUIRE(l.drive.state() == DriveState::Fault);
    CHECK(l.master.status().fault == FaultCode::DriveFault);
    CHECK(l.master.status().state == TableState::Fault);
    const std::string name = l.master.status().fault_name;
    CAPTURE(name);
    CHECK(name.find("drive in fault (statusword 0x") == 0);
    CHECK(name.find("after EMCY 0x4310") != std::string::npos);
    CHECK(l.master.counts().emcy_warnings == 1);
  }

  TEST_CASE("emcy_warns: inside a range, both ends in; outside it, a fault") {
    const auto& d = cia402::kDefaultEmcyWarnings;
    for (const int warn : {0x8110, 0x8120, 0x8140}) {
      CAPTURE(warn);
      CHECK(cia402::emcy_warns(static_cast<std::uint16_t>(warn), d));
    }
    for (const int fault : {0x1000, 0x2310, 0x4210, 0x4310, 0x8100, 0x8130, 0x8611, 0xFF00}) {
      CAPTURE(fault);
      CHECK_FALSE(cia402::emcy_warns(static_cast<std::uint16_t>(fault), d));
    }
    CHECK_FALSE(cia402::emcy_warns(0x8120, {}));
    CHECK(cia402::emcy_warns(0x4200, {{0x4200, 0x42FF}}));
    CHECK(cia402::emcy_warns(0x42FF, {{0x4200, 0x42FF}}));
    CHECK_FALSE(cia402::emcy_warns(0x4300, {{0x4200, 0x42FF}}));
  }

  TEST_CASE("an EMCY fault from a drive that goes on: the quick stop waits for its statusword") {
    stand::Drive402Setup ds = drive_setup();
    ds.cycle_s = 0.004;
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), ds, df);
    REQUIRE(l.turning(1.5));
    REQUIRE(l.master.status().fault == FaultCode::Emcy);       // latched, to be safe
    REQUIRE(l.drive.state() == DriveState::OperationEnabled);  // but the drive goes on
    REQUIRE(l.drive.moving(l.t));
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    CHECK(l.master.status().ack != 3);  // the drive has not yet sampled it
    CHECK(l.drive.moving(l.t));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.1));
    CHECK(l.drive.state() == DriveState::QuickStopActive);
    CHECK((l.drive.controlword() & 0x8F) == 0x02);
  }

  TEST_CASE("an EMCY fault latched while the table turns: Enable refused, then recovered at rest") {
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), drive_setup(), df);
    REQUIRE(l.turning(1.5));
    REQUIRE(l.master.status().fault == FaultCode::Emcy);
    REQUIRE(l.drive.state() == DriveState::OperationEnabled);
    REQUIRE(l.drive.moving(l.t));
    // an enable would set a new demand at speed; a fault reset's 0x0000 or
    // 0x0080 would be Disable voltage to this drive, not in fault
    const auto from = l.sent.size();
    const Status refused = l.command(TableCommandCode::Enable, 3);
    REQUIRE_FALSE(refused.ok());
    CHECK(refused.error().message.find("enable refused while the table turns") == 0);
    CHECK(l.sent.size() == from);
    REQUIRE(l.command(TableCommandCode::QuickStop, 4));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 4 && !l.drive.moving(l.t); }, 1));
    l.run_for(kRateWindowS);
    REQUIRE(l.enabled(5));
    CHECK(l.master.status().fault == FaultCode::None);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.drive.counts().coasts == 0);
    CHECK(l.drive.counts().fault_resets == 0);
    // the drive's own statusword was read before anything was decided
    bool read_statusword = false;
    for (std::size_t i = from; i < l.sent.size(); ++i) {
      const can::Frame& f = l.sent[i];
      if (f.id == canopen::kSdoRxBase + 5 && f.data[0] == 0x40 && f.data[1] == 0x41 &&
          f.data[2] == 0x60)
        read_statusword = true;
      if (f.id == canopen::kRpdo1Base + 5) CHECK((f.data[0] & 0x80) == 0);  // no fault reset
    }
    CHECK(read_statusword);
  }

  TEST_CASE("a table still turning is never enabled: reset by another node mid-move, it coasts") {
    Loop l;
    REQUIRE(l.turning(2.0, 720, 30));  // at speed
    can::Frame nmt = canopen::nmt_frame(canopen::NmtCommand::ResetNode, 5);
    l.drive.receive(l.t, nmt, l.from_drive);
    REQUIRE(l.drive.counts().coasts == 1);
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 1.0));
    // the drive's rate is not known here (its PDOs stopped with the reset):
    // taken, the master configures it again, and then sees it turn
    REQUIRE(l.command(TableCommandCode::Enable, 3));
    REQUIRE(
        l.run_until([&] { return l.master.status().fault == FaultCode::TurningAtEnable; }, 3.0));
    CHECK(l.master.status().fault_name.find("the table turns at") != std::string::npos);
    CHECK(l.drive.state() == DriveState::SwitchedOn);  // not enabled onto it
    CHECK(l.drive.moving(l.t));
    l.run_for(0.5);
    CHECK(l.drive.state() == DriveState::SwitchedOn);
    // once it has run down on its own (30 deg/s at 2 deg/s^2): enabled
    REQUIRE(l.run_until([&] { return !l.drive.moving(l.t); }, 16.0));
    l.run_for(0.1);
    REQUIRE(l.enabled(4));
    CHECK(l.master.status().fault == FaultCode::None);
  }

  TEST_CASE("a table at rest whose encoder dithers a count, a TPDO a millisecond: enabled") {
    // one count between two TPDOs 1 ms apart reads as 0.36 deg/s: no turn
    stand::Drive402Setup ds = drive_setup();
    ds.tpdo_event_timer_ms = 1;
    stand::Drive402Faults df;
    df.position_dither_counts = 1;
    Loop l(master_settings(), ds, df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    CHECK(l.master.status().fault == FaultCode::None);
    // it did dither, sample to sample
    bool stepped = false;
    for (std::size_t i = 1; i < l.samples.size(); ++i)
      stepped = stepped || l.samples[i].counts != l.samples[i - 1].counts;
    CHECK(stepped);
    // the rate the engine and the commands see reads the rest, every TPDO
    // of half a second (over two samples it would read 0.36 deg/s)
    const auto [known, over] = l.rates_for(0.5);
    CHECK(known > 400);
    CHECK(over == 0);
    // so the operator may disable it, and enable it again
    REQUIRE(l.command(TableCommandCode::Disable, 2));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 2; }, 0.5));
    CHECK(l.drive.state() == DriveState::ReadyToSwitchOn);  // Shutdown, transition 8
    REQUIRE(l.enabled(3));
  }

  TEST_CASE("a coarse encoder that dithers: the rate's window is longer, rest and turn both read") {
    // 16384 counts per table turn, the coarsest taken: one count 3.8e-4 rad,
    // two over the 0.1 s of a fine encoder 7.7e-3 rad/s, eight times the
    // rest rate; the window is 0.96 s
    cia402::MasterSettings ms = master_settings();
    ms.counts_per_rev = 16384;
    ms.gear_ratio = 1;
    stand::Drive402Setup ds = drive_setup();
    ds.counts_per_rev = 16384;
    ds.gear_ratio = 1;
    stand::Drive402Faults df;
    df.position_dither_counts = 1;
    Loop l(ms, ds, df);
    l.start();
    REQUIRE(l.running());
    l.run_for(1.0);  // the rest test's window
    REQUIRE(l.enabled(1));
    const auto [known, over] = l.rates_for(3.0);
    CHECK(known > 2500);
    CHECK(over == 0);
    // a slow move reads as one: 0.2 deg/s, 3.5 times the rest rate, under
    // a count in 0.1 s (a fine encoder's window would read it as dither,
    // at rest); here 9 counts a second, within 2 of dither and 1 of the
    // window's count: 30%
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 5 * kDeg, 0.2 * kDeg));
    l.run_for(4.0);
    REQUIRE(l.drive.moving(l.t));
    CHECK(l.master.status().rate_rps == doctest::Approx(0.2 * kDeg).epsilon(0.3));
    CHECK_FALSE(l.command(TableCommandCode::Enable, 3).ok());
    // and the end of a stop within two windows
    REQUIRE(l.command(TableCommandCode::QuickStop, 4));
    REQUIRE(l.run_until([&] { return !l.drive.moving(l.t); }, 1.0));
    REQUIRE(l.run_until([&] { return l.master.status().rate_rps == 0; }, 2.0));
    CHECK(l.enabled(5));
  }

  TEST_CASE("a controlled stop with a fault latched stops the table: as a quick stop") {
    stand::Drive402Setup ds = drive_setup();
    ds.cycle_s = 0.004;  // the statusword answering goes with the next cycle
    stand::Drive402Faults df;
    df.warning_at_s = 1.0;  // latched, the drive goes on
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), ds, df);
    REQUIRE(l.turning(1.5));
    REQUIRE(l.master.status().fault == FaultCode::Emcy);
    REQUIRE(l.drive.moving(l.t));
    REQUIRE(l.command(TableCommandCode::ControlledStop, 3));
    CHECK(l.master.status().ack != 3);  // not acked before the drive shows it
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.5));
    CHECK(l.drive.state() == DriveState::QuickStopActive);
    REQUIRE(l.run_until([&] { return !l.drive.moving(l.t); }, 2.0));
    CHECK(l.drive.counts().coasts == 0);
  }

  TEST_CASE("disable refused while the table turns, whatever the master thinks of its move") {
    // a drive without 0x605B (its default 0: Shutdown lets go, the table
    // coasts), and a warning mid-move: latched, the move no longer the
    // master's, the drive goes on
    stand::Drive402Faults df;
    df.refuse_objects[0x605B00] = 0x06020000;
    df.warning_at_s = 1.0;
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), drive_setup(), df);
    REQUIRE(l.turning(1.5));
    REQUIRE(l.master.status().fault == FaultCode::Emcy);
    REQUIRE(l.drive.moving(l.t));
    const auto from = l.sent.size();
    const Status refused = l.command(TableCommandCode::Disable, 3);
    REQUIRE_FALSE(refused.ok());
    CHECK(refused.error().message.find("disable refused while the table turns") == 0);
    CHECK(l.sent.size() == from);
    l.run_for(0.1);
    CHECK(l.drive.counts().coasts == 0);
    REQUIRE(l.command(TableCommandCode::QuickStop, 4));
    REQUIRE(l.run_until([&] { return !l.drive.moving(l.t); }, 2.0));
    l.run_for(kRateWindowS);
    CHECK(l.command(TableCommandCode::Disable, 5).ok());
    CHECK(l.drive.counts().coasts == 0);
  }

  TEST_CASE(
      "a TPDO that never agrees with the drive's own statusword: the reset gives up, says why") {
    stand::Drive402Faults df;
    df.warning_at_s = 0.5;  // latched at rest: the next Enable reads the statusword
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.run_until([&] { return l.master.status().fault == FaultCode::Emcy; }, 1.0));
    l.run_for(0.05);
    // from now on its TPDO1 says switched on, its 0x6041 operation enabled
    l.tamper = [](can::Frame& f) {
      if (f.id == canopen::kTpdo1Base + 5) f.data[0] = 0x33, f.data[1] = 0x02;
    };
    l.run_for(0.05);
    const auto from = l.sent.size();
    REQUIRE(l.command(TableCommandCode::Enable, 2));
    l.run_for(3.0);
    CHECK(l.master.status().fault == FaultCode::Emcy);  // still latched
    CHECK(l.master.status().fault_name.find("kept disagreeing") != std::string::npos);
    for (std::size_t i = from; i < l.sent.size(); ++i)
      if (l.sent[i].id == canopen::kRpdo1Base + 5)
        CHECK((l.sent[i].data[0] & 0x80) == 0);  // no fault reset
    CHECK(l.statusword_reads(from) == cia402::Master::kConfirmReads + 1);
    CHECK(l.drive.counts().fault_resets == 0);
  }

  TEST_CASE(
      "disable while the table's rest is unknown: it waits enabled and halted, never moving") {
    // A move halted (controlled stop) at rest; then TPDO1 lost for longer
    // than the drive's heartbeat timeout: whether the table is at rest is
    // not known. A Disable waits enabled, as it does for a table that
    // turns, and keeps the halt: dropping it would let the drive take up
    // the halted move.
    Loop l;
    REQUIRE(l.turning(1.0, 180, 30));
    REQUIRE(l.command(TableCommandCode::ControlledStop, 3));
    REQUIRE(l.run_until([&] { return !l.drive.moving(l.t); }, 2.0));
    l.run_for(kRateWindowS);
    REQUIRE((l.drive.controlword() & cia402::cw::kHalt) != 0);
    l.tamper = [](can::Frame& f) {
      if (f.id == canopen::kTpdo1Base + 5) f.id = 0x7FF;  // nobody's
    };
    l.run_for(0.4);
    REQUIRE(std::isnan(l.master.status().rate_rps));  // rest not known
    REQUIRE(l.command(TableCommandCode::Disable, 4));
    for (int i = 0; i < 500; ++i) {
      l.step();
      CHECK_FALSE(l.drive.moving(l.t));
      CHECK((l.drive.controlword() & cia402::cw::kHalt) != 0);
    }
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    // TPDO1 back: at rest, then shut down (transition 8)
    l.tamper = nullptr;
    REQUIRE(l.run_until([&] { return l.master.status().ack == 4; }, 1.0));
    CHECK(l.drive.state() == DriveState::ReadyToSwitchOn);
  }

  TEST_CASE("disable, then enable before the drive's statusword says so: not a drive of its own") {
    stand::Drive402Setup ds = drive_setup();
    ds.cycle_s = 0.004;  // the statusword answering goes with the next cycle
    Loop l(master_settings(), ds);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::Disable, 2));
    // the drive has sampled it; the master has not yet heard so
    REQUIRE(l.run_until([&] { return l.drive.state() != DriveState::OperationEnabled; }, 0.01));
    REQUIRE(l.master.drive_state() == State::OperationEnabled);
    REQUIRE(l.command(TableCommandCode::Enable, 3));
    REQUIRE(l.run_until(
        [&] {
          return l.master.status().ack == 3 && l.master.status().state == TableState::Holding;
        },
        0.5));
    CHECK(l.master.status().fault == FaultCode::None);
  }

  TEST_CASE("the virtual drive's power stage let go while turning: the table coasts") {
    Loop l;
    REQUIRE(l.turning(2.0));
    REQUIRE(std::fabs(l.drive.rate(l.t)) == doctest::Approx(30 * kDeg).epsilon(1e-4));
    can::Frame f;  // Disable voltage, as another node might send it
    f.id = canopen::kRpdo1Base + 5;
    f.len = 6;
    l.drive.receive(l.t, f, l.from_drive);
    CHECK(l.drive.state() == DriveState::SwitchOnDisabled);
    CHECK(l.drive.counts().coasts == 1);
    // on friction alone (2 deg/s^2), not the quick stop's 180 deg/s^2
    CHECK(std::fabs(l.drive.rate(l.t + 1)) == doctest::Approx(28 * kDeg).epsilon(1e-3));
    CHECK(l.drive.moving(l.t + 14));
    CHECK_FALSE(l.drive.moving(l.t + 16));
  }

  TEST_CASE("the drive leaves operation enabled by itself: a fault, not enabled again unasked") {
    std::uint8_t word = 0;
    State left_to = State::Unknown;  // as the master names it
    DriveState drive_left_to = DriveState::NotReadyToSwitchOn;
    SUBCASE("quick stop, by another node") {
      word = 0x02;
      left_to = State::QuickStopActive;
      drive_left_to = DriveState::QuickStopActive;
    }
    SUBCASE("disable voltage, by another node") {
      word = 0x00;
      left_to = State::SwitchOnDisabled;
      drive_left_to = DriveState::SwitchOnDisabled;
    }
    Loop l;
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    can::Frame f;
    f.id = canopen::kRpdo1Base + 5;
    f.len = 6;
    f.data[0] = word;
    l.drive.receive(l.t, f, l.from_drive);
    REQUIRE(l.drive.state() == drive_left_to);
    REQUIRE(l.run_until([&] { return l.master.status().fault == FaultCode::LeftEnabled; }, 0.1));
    CHECK(l.master.status().fault_name.find(std::string("the drive left operation enabled by "
                                                        "itself, to ") +
                                            cia402::to_string(left_to)) == 0);
    const auto from = l.sent.size();
    l.run_for(0.5);
    CHECK(l.drive.state() == drive_left_to);  // not enabled again behind anyone's back
    CHECK(l.master.status().state == TableState::Fault);
    for (std::size_t i = from; i < l.sent.size(); ++i)
      CHECK(l.sent[i].id != canopen::kRpdo1Base + 5);
    REQUIRE(l.enabled(2));  // asked: enabled again
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    CHECK(l.master.status().fault == FaultCode::None);
  }

  TEST_CASE(
      "a drive that keeps bit 12 up after enable: the set-point waits, or faults saying why") {
    stand::Drive402Setup ds = drive_setup();
    SUBCASE("50 ms: the set-point goes once it drops, the move done") {
      ds.set_point_ack_after_enable_s = 0.05;
      Loop l(master_settings(), ds);
      l.start();
      REQUIRE(l.running());
      REQUIRE(l.enabled(1));
      REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
      REQUIRE(l.in_position(2, 10));
      CHECK(l.drive.counts().set_points == 1);
      CHECK(l.drive.angle(l.t) == doctest::Approx(M_PI / 2).epsilon(1e-6));
      CHECK(l.master.status().fault == FaultCode::None);
    }
    SUBCASE("never dropped: a fault after the set-point timeout, nothing moved") {
      ds.set_point_ack_after_enable_s = std::numeric_limits<double>::infinity();
      Loop l(master_settings(), ds);
      l.start();
      REQUIRE(l.running());
      REQUIRE(l.enabled(1));
      REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
      REQUIRE(l.run_until([&] { return l.master.status().fault != FaultCode::None; }, 2));
      CHECK(l.master.status().fault == FaultCode::SetPointTimeout);
      CHECK(l.master.status().fault_name.find(
                "set-point not sent: the drive's statusword bit 12") == 0);
      CHECK(l.drive.counts().set_points == 0);
      CHECK_FALSE(l.drive.moving(l.t));
      // no bit 4 ever went out: the drive was never asked
      for (const can::Frame& f : l.sent)
        if (f.id == canopen::kRpdo1Base + 5) CHECK((f.data[0] & 0x10) == 0);
    }
  }

  TEST_CASE("disable: refused while moving; from quick stop active nothing before rest") {
    stand::Drive402Setup ds = drive_setup();
    SUBCASE("a drive that sets bit 10 in quick stop active once at rest") {}
    SUBCASE("a drive that never sets it there: the rest is the table's, by its positions") {
      ds.target_reached_in_quick_stop = false;
    }
    Loop l(master_settings(), ds);
    REQUIRE(l.turning(1.0, 90, 30));
    const auto sent = l.sent.size();
    CHECK_FALSE(l.command(TableCommandCode::Disable, 3).ok());
    CHECK(l.sent.size() == sent);
    CHECK(l.drive.state() == DriveState::OperationEnabled);
    REQUIRE(l.in_position(2, 5));
    // a quick stop, and at once enable again: refused while it decelerates
    // (the drive stays quick stop active, the controlword Quick stop), then
    // enabled at rest
    REQUIRE(l.command(TableCommandCode::MoveRelative, 4, 90 * kDeg, 30 * kDeg));
    l.run_for(1.0);
    REQUIRE(l.command(TableCommandCode::QuickStop, 5));
    l.step();
    REQUIRE(l.drive.moving(l.t));
    const Status early = l.command(TableCommandCode::Enable, 6);
    REQUIRE_FALSE(early.ok());
    CHECK(early.error().message.find("enable refused while the table turns") == 0);
    while (l.drive.moving(l.t)) {
      CHECK(l.drive.state() == DriveState::QuickStopActive);
      CHECK((l.drive.controlword() & 0x8F) == 0x02);
      l.step();
    }
    l.run_for(kRateWindowS);
    REQUIRE(l.enabled(6));
    // and disable from quick stop active, also at rest only
    REQUIRE(l.command(TableCommandCode::MoveRelative, 7, 90 * kDeg, 30 * kDeg));
    l.run_for(1.0);
    REQUIRE(l.command(TableCommandCode::QuickStop, 8));
    l.step();
    REQUIRE(l.drive.moving(l.t));
    const Status early_off = l.command(TableCommandCode::Disable, 9);
    REQUIRE_FALSE(early_off.ok());
    CHECK(early_off.error().message.find("disable refused while the table turns") == 0);
    while (l.drive.moving(l.t)) {
      CHECK(l.drive.state() == DriveState::QuickStopActive);
      l.step();
    }
    l.run_for(kRateWindowS);
    REQUIRE(l.command(TableCommandCode::Disable, 9));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 9; }, 0.5));
    CHECK(l.drive.state() == DriveState::SwitchOnDisabled);  // transition 12
    CHECK(l.master.status().state == TableState::Disabled);
  }

  TEST_CASE("modes of operation display read back: the drive switches late, or never") {
    stand::Drive402Setup ds = drive_setup();
    SUBCASE("late: configuration waits") {
      ds.mode_switch_s = 0.05;
      Loop l(master_settings(), ds);
      l.start();
      REQUIRE(l.running());
      CHECK(*l.drive.value(0x6061, 0) == 1);  // shown before NMT start
      REQUIRE(l.enabled(1));
      REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 10 * kDeg, 30 * kDeg));
      REQUIRE(l.in_position(2, 3));
    }
    SUBCASE("never within the timeout: configuration fails, naming 0x6061") {
      ds.mode_switch_s = 10;
      Loop l(master_settings(), ds);
      l.start();
      l.run_for(0.5);
      CHECK(l.master.phase() == cia402::CommPhase::Failed);
      CHECK(l.master.status().fault == FaultCode::Configuration);
      CHECK(l.master.status().fault_name.find("0x6061") != std::string::npos);
      CHECK(l.drive.nmt() == stand::facts::Nmt::PreOperational);
    }
  }

  TEST_CASE("the mode seam: the master writes, reads back and awaits what its mode says") {
    // A mode of the test's, no move of its own: what the master does with
    // the mode's code, writes and checks is the master's, shared by every
    // mode (the profile position tests above are one mode's).
    struct Probe {
      std::int8_t code = 1;
      std::uint32_t velocity = 12345;  // counts/s, written to 0x6081
      std::string refuse;              // the check's verdict on 0x6081
      int configured = 0;
      int checked = 0;
    };
    class TestMode final : public cia402::OperationMode {
     public:
      explicit TestMode(Probe& p) : p_(p) {}
      std::int8_t code() const override { return p_.code; }
      const char* name() const override { return "the test's mode"; }
      void configuration(std::vector<cia402::ConfigWrite>& w) const override {
        w.push_back({0x6081, 0, canopen::le_bytes(p_.velocity, 4)});
      }
      void configured() override { ++p_.configured; }
      std::vector<cia402::ConfigCheck> checks() const override {
        return {{0x6081, 0, [this](const canopen::SdoResult& r) {
                   ++p_.checked;
                   if (r.data.size() != 4 || canopen::get_le(r.data, 0, 4) != p_.velocity)
                     return std::string("0x6081 does not hold what was written");
                   return p_.refuse;
                 }}};
      }
      std::uint16_t error_bits() const override { return 0; }
      const char* error_name() const override { return "no error"; }
      void reset() override {}
      void left_enabled() override {}
      bool moving() const override { return false; }
      Status move(TableCommandCode, std::uint8_t, double, double, double,
                  std::vector<can::Frame>&) override {
        return make_error("the test's mode makes no moves");
      }
      void halt() override {}
      cia402::ModeProgress on_status(std::uint16_t, std::uint64_t, bool, double, bool) override {
        return {};
      }
      std::uint16_t controlword_bits() const override { return 0; }
      std::uint16_t set_point_bits(std::uint16_t, bool& starts) const override {
        starts = false;
        return 0;
      }
      std::int32_t set_point_target() const override { return 0; }
      void set_point_sent(std::uint64_t, double) override {}
      TableState enabled_state() const override { return TableState::Holding; }
      void held(double, double) override {}

     private:
      Probe& p_;
    };
    Probe probe;
    auto factory = [&probe](const cia402::MasterSettings&, cia402::ModeHost&) {
      return std::make_unique<TestMode>(probe);
    };
    SUBCASE("its code in 0x6060, its writes, its checks, then 0x6061 shows its code") {
      Loop l(factory, master_settings());
      l.start();
      REQUIRE(l.running());
      CHECK(*l.drive.value(0x6060, 0) == 1);
      CHECK(*l.drive.value(0x6081, 0) == 12345);  // the mode's write, not the settings' rate
      CHECK(probe.configured == 1);
      CHECK(probe.checked == 1);
      // the profile position's own write is not the master's: 0x60F2 untouched
      const auto& w = l.drive.sdo_writes();
      CHECK(std::find(w.begin(), w.end(), std::make_pair<std::uint16_t, std::uint8_t>(0x60F2, 0)) ==
            w.end());
      REQUIRE(l.enabled(1));
      const Status move = l.command(TableCommandCode::MoveRelative, 2, 10 * kDeg, 30 * kDeg);
      REQUIRE_FALSE(move);
      CHECK(move.error().message == "the test's mode makes no moves");
    }
    SUBCASE("a check's verdict fails the configuration with its text, nothing started") {
      probe.refuse = "the drive keeps no such mode";
      Loop l(factory, master_settings());
      l.start();
      l.run_for(0.5);
      CHECK(probe.checked == 1);
      CHECK(l.master.phase() == cia402::CommPhase::Failed);
      CHECK(l.master.status().fault == FaultCode::Configuration);
      CHECK(l.master.status().fault_name == "the drive keeps no such mode");
      CHECK(l.drive.nmt() == stand::facts::Nmt::PreOperational);
    }
    SUBCASE("a code the drive lacks: 0x6060 refused, named, nothing read back") {
      probe.code = 3;  // profile velocity, which this drive has not
      Loop l(factory, master_settings());
      l.start();
      l.run_for(0.5);
      CHECK(probe.checked == 0);
      CHECK(l.master.phase() == cia402::CommPhase::Failed);
      CHECK(l.master.status().fault_name.find("0x6060") != std::string::npos);
      CHECK(l.drive.nmt() == stand::facts::Nmt::PreOperational);
    }
  }

  TEST_CASE("a drive that counts clockwise: the table angle, targets and rates negated") {
    cia402::MasterSettings ms = master_settings();
    ms.counts_clockwise = true;
    ms.velocity_pdo = true;
    ms.configure_mapping = true;
    stand::Drive402Setup ds = drive_setup();
    ds.counts_clockwise = true;
    Loop l(ms, ds);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveAbsolute, 2, 90 * kDeg, 30 * kDeg));
    l.run_for(1.5);  // at speed, counter-clockwise
    CHECK(l.drive.rate(l.t) == doctest::Approx(30 * kDeg).epsilon(1e-4));
    CHECK(l.master.status().rate_rps == doctest::Approx(30 * kDeg).epsilon(1e-3));
    CHECK(*l.drive.value(0x606C, 0) < 0);  // the drive's own velocity: clockwise negative
    REQUIRE(l.in_position(2, 10));
    CHECK(l.drive.angle(l.t) == doctest::Approx(90 * kDeg).epsilon(1e-6));  // counter-clockwise
    CHECK(*l.drive.value(0x6064, 0) == -250000);  // a quarter turn, counted the other way
    REQUIRE_FALSE(l.samples.empty());
    CHECK(l.samples.back().angle_rad == doctest::Approx(90 * kDeg).epsilon(1e-6));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 3, -30 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(3, 10));
    // within a count (6.3e-6 rad): -30 deg is not a whole number of counts
    CHECK(l.drive.angle(l.t) == doctest::Approx(60 * kDeg).epsilon(1e-5));
    CHECK(l.samples.back().angle_rad == doctest::Approx(60 * kDeg).epsilon(1e-5));
  }

  TEST_CASE("relative moves go from where the table is, whatever 0x60F2 says: absolute targets") {
    stand::Drive402Setup ds = drive_setup();
    SUBCASE("0x60F2 = 0, from the last target (the default of many drives)") {
      ds.positioning_option = 0;
    }
    SUBCASE("0x60F2 = 1, from the position demand value") {
      ds.positioning_option = 1;
    }
    Loop l(master_settings(), ds);
    l.start();
    REQUIRE(l.running());
    CHECK(*l.drive.value(0x60F2, 0) == ds.positioning_option);  // read, never written
    REQUIRE(l.enabled(1));
    REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
    l.run_for(1.5);
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    l.run_for(0.5);
    REQUIRE(l.enabled(4));
    const std::int64_t stopped = l.drive.position_counts(l.t);
    REQUIRE(stopped < 250000);
    REQUIRE(l.command(TableCommandCode::MoveRelative, 5, 10 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(5, 3));
    CHECK(l.drive.position_counts(l.t) == stopped + 27778);
    // no relative target ever went out (controlword bit 6)
    for (const can::Frame& f : l.sent)
      if (f.id == canopen::kRpdo1Base + 5) CHECK((f.data[0] & 0x40) == 0);
  }

  TEST_CASE(
      "a relative move during a halt goes from where the table is, not the abandoned target") {
    cia402::MasterSettings ms = master_settings();
    ms.change_set_immediately = true;
    Loop l(ms, drive_setup());
    REQUIRE(l.turning(3.0));  // 360 deg at 30 deg/s, cruising
    REQUIRE(l.command(TableCommandCode::ControlledStop, 3));
    l.run_for(0.1);
    REQUIRE(l.drive.moving(l.t));  // still braking
    const std::int64_t at = l.drive.position_counts(l.t);
    REQUIRE(l.command(TableCommandCode::MoveRelative, 4, 10 * kDeg, 30 * kDeg));
    REQUIRE(l.in_position(4, 10));
    // 10 deg is 27778 counts at 1e6 counts per turn, from the master's last
    // position (a TPDO up to 10 ms old: 3000 counts at the most, braking)
    CHECK(std::llabs(l.drive.position_counts(l.t) - (at + 27778)) < 3000);
    CHECK(std::fabs(l.drive.angle(l.t)) < M_PI);  // nowhere near the 360 deg abandoned
  }

  TEST_CASE("relative moves in a row go from the target each reached: no settling carried") {
    stand::Drive402Faults df;
    df.position_dither_counts = 3;  // position actual on the edge of counts at rest
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    for (int k = 0; k < 4; ++k) {
      const auto seq = static_cast<std::uint8_t>(2 + k);
      REQUIRE(l.command(TableCommandCode::MoveRelative, seq, 90 * kDeg, 30 * kDeg));
      REQUIRE(l.in_position(seq, 10));
    }
    // four quarter turns: 4 x 250000 counts exactly, whatever the dither read
    CHECK(*l.drive.value(0x607A, 0) == 1000000);
  }

  TEST_CASE(
      "0x60F2 optional: a drive without it runs, told; one that would not turn as planned "
      "is refused") {
    stand::Drive402Setup ds = drive_setup();
    stand::Drive402Faults df;
    SUBCASE("absent (0x06020000): configured, the notice names it, a move done") {
      df.refuse_objects[0x60F200] = 0x06020000;
      Loop l(master_settings(), ds, df);
      l.start();
      REQUIRE(l.running());
      const auto& told = l.master.notices();
      CHECK(std::any_of(told.begin(), told.end(), [](const std::string& n) {
        return n.starts_with("read 0x60F2:00: 0x06020000") &&
               n.find("optional in CiA 402") != std::string::npos;
      }));
      REQUIRE(l.enabled(1));
      REQUIRE(l.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg));
      REQUIRE(l.in_position(2, 10));
      CHECK(l.drive.angle(l.t) == doctest::Approx(M_PI / 2).epsilon(1e-6));
    }
    SUBCASE("a rotary axis the shortest way (bits 6-7 = 11): refused before anything moves") {
      ds.positioning_option = 0x00C0;
      Loop l(master_settings(), ds, df);
      l.start();
      REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Failed; }, 2.0));
      const std::string why = l.master.status().fault_name;
      CAPTURE(why);
      CHECK(why.find("positioning option code (0x60F2) reads 0x00C0") == 0);
      CHECK(why.find("rotary axis direction option") != std::string::npos);
      CHECK(l.drive.nmt() != stand::facts::Nmt::Operational);
      CHECK(l.drive.counts().set_points == 0);
    }
    SUBCASE("refused otherwise (0x08000000): the configuration fails with it") {
      df.refuse_objects[0x60F200] = 0x08000000;
      Loop l(master_settings(), ds, df);
      l.start();
      REQUIRE(l.run_until([&] { return l.master.phase() == cia402::CommPhase::Failed; }, 2.0));
      CHECK(l.master.status().fault_name.find("0x60F2:00") != std::string::npos);
    }
  }

  TEST_CASE("heartbeat lost while the drive stays enabled: no reset after reconfiguration") {
    stand::Drive402Faults df;
    df.ignores_lost_host = true;  // the drive takes no action on our lost heartbeat
    df.silent_at_s = 1.0;
    df.silent_until_s = 1.5;
    Loop l(master_settings(), drive_setup(), df);
    l.start();
    REQUIRE(l.running());
    REQUIRE(l.enabled(1));
    REQUIRE(l.run_until([&] { return l.master.status().state == TableState::Fault; }, 2.0));
    INFO(l.master.status().fault_name);
    REQUIRE(l.master.status().fault == FaultCode::DriveHeartbeatLost);
    l.run_for(0.5);  // it talks again, still enabled
    REQUIRE(l.drive.state() == DriveState::OperationEnabled);
    const auto from = l.sent.size();
    REQUIRE(l.command(TableCommandCode::Enable, 2));
    REQUIRE(l.run_until(
        [&] {
          CHECK(l.drive.state() == DriveState::OperationEnabled);  // never let go
          return l.master.status().ack == 2 && l.master.status().state == TableState::Holding;
        },
        1.0));
    CHECK(l.master.counts().configurations == 2);
    CHECK(l.drive.counts().fault_resets == 0);
    for (std::size_t i = from; i < l.sent.size(); ++i)
      if (l.sent[i].id == canopen::kRpdo1Base + 5) CHECK((l.sent[i].data[0] & 0x8F) == 0x0F);
  }

  TEST_CASE("a quick stop is kept commanded by PDO while a fault is latched") {
    stand::Drive402Setup ds = drive_setup();
    ds.mode_switch_s = 0.05;  // configuring for a while
    stand::Drive402Faults df;
    df.warning_at_s = 0.02;  // an EMCY during the configuration: latched
    df.warning_code = kFaultClassCode;
    Loop l(master_settings(), ds, df);
    l.start();
    REQUIRE(l.run_until([&] { return l.master.status().fault == FaultCode::Emcy; }, 0.1));
    REQUIRE(l.master.phase() == cia402::CommPhase::Configuring);
    REQUIRE(l.command(TableCommandCode::QuickStop, 3));
    REQUIRE(l.run_until([&] { return l.master.status().ack == 3; }, 0.1));
    REQUIRE(l.running());
    l.run_for(0.05);
    CHECK(l.master.status().fault == FaultCode::Emcy);
    bool pdo_quick_stop = false;
    for (const can::Frame& f : l.sent)
      if (f.id == canopen::kRpdo1Base + 5 && (f.data[0] & 0x8F) == 0x02) pdo_quick_stop = true;
    CHECK(pdo_quick_stop);
  }
}

TEST_SUITE("turncal-sim's late TPDOs") {
  // a TPDO made at 10 s, of a table at rest, with nothing since: it goes
  // out late; each thing that could have changed the drive keeps it back
  stand::LateTpdo quiet(bool on_sync) {
    stand::LateTpdo l;
    l.t_s = 10.0;
    l.at_rest = true;
    l.on_sync = on_sync;
    l.command_taken_t = 9.5;
    l.sync_taken_t = on_sync ? 10.0 : 9.9;
    l.syncs_taken_then = 1;
    l.bus_read = true;
    return l;
  }

  TEST_CASE("a late TPDO goes out only if what it says is as true at its receipt") {
    for (const bool on_sync : {false, true}) {
      CAPTURE(on_sync);
      CHECK(stand::still_true_late(quiet(on_sync)));
      stand::LateTpdo l = quiet(on_sync);
      l.at_rest = false;  // the table turning: its angle is the frame's time's
      CHECK_FALSE(stand::still_true_late(l));
      l = quiet(on_sync);
      l.scripted_host = true;
      CHECK_FALSE(stand::still_true_late(l));
      l = quiet(on_sync);
      l.command_taken_t = 10.0;  // in the tick that made it, so after it
      CHECK_FALSE(stand::still_true_late(l));
      l.command_taken_t = 10.002;  // since
      CHECK_FALSE(stand::still_true_late(l));
      l = quiet(on_sync);
      l.command_waiting = true;
      CHECK_FALSE(stand::still_true_late(l));
      l = quiet(on_sync);
      l.bus_read = false;  // a socket not read to the end, gone or in error
      CHECK_FALSE(stand::still_true_late(l));
    }
  }

  TEST_CASE("a late answer to a SYNC goes out only while no later SYNC is taken or waiting") {
    stand::LateTpdo l = quiet(true);
    l.sync_taken_t = 10.001;  // the next SYNC already taken
    CHECK_FALSE(stand::still_true_late(l));
    l = quiet(true);
    l.syncs_taken_then = 2;  // two in its tick: which it answers is not known
    CHECK_FALSE(stand::still_true_late(l));
    l = quiet(true);
    l.sync_waiting = true;
    CHECK_FALSE(stand::still_true_late(l));
    l = quiet(true);
    l.stand_tx_waiting = true;  // it would go after frames a later SYNC may overtake
    CHECK_FALSE(stand::still_true_late(l));
    // none of these matter to an event-driven TPDO, dated by its receipt
    l = quiet(false);
    l.sync_taken_t = 10.0;
    l.syncs_taken_then = 2;
    CHECK(stand::still_true_late(l));
    l.sync_taken_t = 10.001;
    l.sync_waiting = true;
    l.stand_tx_waiting = true;
    CHECK(stand::still_true_late(l));
  }
}
