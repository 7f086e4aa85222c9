// The CiA 402 table driver (TableDriver over the CANopen master) against
// the virtual CiA 402 drive, with the shipped CiA 402 stand's configuration
// and DBC: what the ingest and the engine see of it.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/canopen.hpp"
#include "turncal/drivers/cia402.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/sim/virtual_drive402.hpp"

using namespace turncal;

namespace {

const std::string kSrc = turncal::build::source_dir;
constexpr double kDeg = std::numbers::pi / 180;

struct Stand402 {
  Config cfg;
  can::Database db;
  RoleMap roles;
};

const Stand402& stand402() {
  static const Stand402 s = [] {
    Stand402 x;
    auto cfg = load_config(kSrc + "/config/stands/cia402/turncal.toml");
    REQUIRE(cfg.ok());
    x.cfg = *cfg;
    auto db = load_databases(x.cfg.can);
    REQUIRE(db.ok());
    x.db = std::move(*db);
    return x;
  }();
  return s;
}

/// The driver and the drive on one bus; the driver sees the drive's frames
/// and its own (a bus echo), as the ingest hands them over.
struct Bus {
  explicit Bus(stand::Drive402Faults faults = {}, bool observer = false)
      : codec(stand402().db), drive(setup(), faults), observe(observer) {
    auto roles = resolve_roles(stand402().cfg.can, stand402().db);
    REQUIRE(roles.ok());
    roles_ = *roles;
    driver = drivers::make_cia402_table(stand402().cfg.can.table.cia402, roles_);
    values.resize(16);
  }
  static stand::Drive402Setup setup() {
    stand::Drive402Setup d;
    d.node_id = 1;
    d.counts_per_rev = 131072;
    return d;
  }

  can::FrameCodec codec;
  RoleMap roles_;
  std::unique_ptr<TableDriver> driver;
  stand::VirtualDrive402 drive;
  bool observe;
  double t = 0;
  std::vector<double> values;
  std::vector<can::Frame> to_drive;
  std::vector<stand::DriveFrame> from_drive;
  std::vector<EncoderSample> encoder;
  std::vector<TableStatusSample> status;
  std::uint64_t malformed = 0, own = 0;

  void see(const can::Frame& f, double at) {
    const can::Message* m = nullptr;
    const can::DecodeStatus st = codec.decode(f, values, &m);
    const FrameView v{f, at, m, st, values};
    Decoded d = driver->decode(v);
    if (d.verdict == Decoded::Verdict::Malformed) ++malformed;
    if (d.verdict == Decoded::Verdict::Taken && d.stream == kStreams) ++own;
    if (const auto* e = std::get_if<EncoderSample>(&d.sample)) encoder.push_back(*e);
    drain();
  }
  void drain() {
    if (!observe) driver->take_frames(to_drive);
    for (Decoded p = driver->pending(); p.verdict == Decoded::Verdict::Taken; p = driver->pending())
      status.push_back(std::get<TableStatusSample>(p.sample));
  }
  void deliver() {
    while (!to_drive.empty() || !from_drive.empty()) {
      std::vector<can::Frame> m;
      m.swap(to_drive);
      for (const can::Frame& f : m) {
        drive.receive(t, f, from_drive);
        see(f, t);  // our own frame, echoed
      }
      std::vector<stand::DriveFrame> d;
      d.swap(from_drive);
      for (const stand::DriveFrame& f : d) see(f.frame, f.t_s);
    }
  }
  void step(double dt = 1e-3) {
    t += dt;
    drive.advance(t, from_drive);
    deliver();
    if (!observe) {
      driver->tick(t, to_drive);
      // the daemon's heartbeat timer, 10 Hz
      if (std::fmod(t + 1e-9, 0.1) < dt)
        for (const can::Frame& f : driver->heartbeat(0, 1)) to_drive.push_back(f);
    }
    drain();
    deliver();
  }
  void start() {
    driver->start(t, to_drive);
    drain();
    deliver();
  }
  [[nodiscard]] std::optional<TableStatusSample> last() const {
    if (status.empty()) return std::nullopt;
    return status.back();
  }
  template <class Pred>
  bool run_until(Pred done, double timeout) {
    const double end = t + timeout;
    while (t < end) {
      if (done()) return true;
      step();
    }
    return done();
  }
  bool state_is(TableState s, int ack, double timeout = 3.0) {
    return run_until(
        [&] { return last() && last()->state == static_cast<int>(s) && last()->ack == ack; },
        timeout);
  }
  Status command(TableCommandCode c, std::uint8_t seq, double target = 0, double rate = 0) {
    auto f = driver->command(TableCommand{c, seq, target, rate});
    if (!f) return f.error();
    for (const can::Frame& x : *f) to_drive.push_back(x);
    drain();
    deliver();
    return Status{Ok{}};
  }
};

}  // namespace

TEST_SUITE("cia402 table driver") {
  TEST_CASE("enable and a move through the driver: encoder and status samples") {
    Bus b;
    b.start();
    REQUIRE(b.command(TableCommandCode::Enable, 1));
    REQUIRE(b.state_is(TableState::Holding, 1));
    CHECK(b.drive.state() == stand::facts::State::OperationEnabled);
    REQUIRE(b.command(TableCommandCode::MoveAbsolute, 2, 30 * kDeg, 10 * kDeg));
    REQUIRE(b.state_is(TableState::InPosition, 2, 10));
    REQUIRE_FALSE(b.encoder.empty());
    const double last = b.encoder.back().angle_rad;
    CHECK(last == doctest::Approx(30 * kDeg).epsilon(1e-4));
    CHECK(b.drive.angle(b.t) == doctest::Approx(30 * kDeg).epsilon(1e-4));
    // every TPDO1 is a status sample too: the status stream never goes quiet
    CHECK(b.status.size() >= b.encoder.size());
    // our own frames, echoed, are recognised and nothing else
    CHECK(b.own > 0);
    CHECK(b.malformed == 0);
    // encoder times: the TPDO's receive time (no SYNC), non-decreasing
    for (std::size_t i = 1; i < b.encoder.size(); ++i)
      CHECK(b.encoder[i].t_table_s >= b.encoder[i - 1].t_table_s);
  }

  TEST_CASE(
      "a drive fault with EMCY: the status is a fault named by the EMCY; a quick stop holds") {
    stand::Drive402Faults f;
    f.fault_at_s = 1.5;
    f.fault_code = 0x2310;
    Bus b(f);
    b.start();
    REQUIRE(b.command(TableCommandCode::Enable, 1));
    REQUIRE(b.state_is(TableState::Holding, 1));
    REQUIRE(
        b.run_until([&] { return b.last()->state == static_cast<int>(TableState::Fault); }, 3.0));
    CHECK(b.last()->fault_name.find("0x2310") != std::string::npos);
    REQUIRE(b.command(TableCommandCode::QuickStop, 2));
    b.run_until([] { return false; }, 0.3);
    CHECK(b.drive.state() != stand::facts::State::OperationEnabled);
    CHECK(b.last()->state == static_cast<int>(TableState::Fault));
  }

  TEST_CASE("one heartbeat, the master's; switched off, the drive loses us and stops the table") {
    Bus b;
    b.start();
    REQUIRE(b.command(TableCommandCode::Enable, 1));
    REQUIRE(b.state_is(TableState::Holding, 1));
    // started: the caller's heartbeat() gives nothing, the master's tick
    // sends ours at host_heartbeat_ms (100 ms): 10 in a second, not 20
    CHECK(b.driver->heartbeat(0, 1).empty());
    // `ms` of the driver's own ticks, no caller heartbeat: our heartbeats (0x77F) sent
    const auto beats_in = [&b](int ms) {
      std::size_t beats = 0;
      for (int i = 0; i < ms; ++i) {
        b.t += 1e-3;
        b.drive.advance(b.t, b.from_drive);
        std::vector<can::Frame> out;
        b.driver->tick(b.t, out);
        for (const can::Frame& f : out)
          if (f.id == 0x700u + 127u) ++beats;
        b.to_drive.insert(b.to_drive.end(), out.begin(), out.end());
        b.drain();
        b.deliver();
      }
      return beats;
    };
    std::size_t beats = beats_in(1000);
    CHECK(beats >= 9);
    CHECK(beats <= 11);
    REQUIRE(b.command(TableCommandCode::MoveRelative, 2, 90 * kDeg, 10 * kDeg));
    REQUIRE(b.run_until([&] { return std::abs(b.drive.angle(b.t)) > 5 * kDeg; }, 3.0));
    // the host gave up stopping the table: no more heartbeat from us, and
    // the drive's consumer (500 ms) acts per 0x6007 (3: quick stop)
    b.driver->set_heartbeat(false);
    beats = beats_in(1500);
    CHECK(beats == 0);
    CHECK(b.drive.counts().host_heartbeat_lost == 1);
    CHECK(b.drive.counts().quick_stops >= 1);
    CHECK(b.drive.state() != stand::facts::State::OperationEnabled);
  }

  TEST_CASE("a malformed TPDO1 is counted and skipped; another node's frames are not ours") {
    Bus b;
    can::Frame short_tpdo;
    short_tpdo.id = 0x181;
    short_tpdo.len = 2;
    b.see(short_tpdo, 0.01);
    CHECK(b.malformed == 1);
    CHECK(b.encoder.empty());
    can::Frame other;
    other.id = 0x182;  // node 2's TPDO1
    other.len = 6;
    std::vector<double> v(16);
    const FrameView view{other, 0.01, nullptr, can::DecodeStatus::UnknownId, v};
    CHECK(b.driver->decode(view).verdict == Decoded::Verdict::NotMine);
  }

  TEST_CASE("the table's geometry, as the report keeps it for a replay to check") {
    Bus b;
    const std::string ccw = b.driver->geometry();
    CHECK(ccw.find("counts increase counter-clockwise") != std::string::npos);
    CHECK(ccw.find("counts_per_revolution ") == 0);
    auto c = stand402().cfg.can.table.cia402;
    c.counts_clockwise = true;
    const std::string cw = drivers::make_cia402_table(c, b.roles_)->geometry();
    CHECK(cw.find("counts increase clockwise") != std::string::npos);
    CHECK(cw.substr(0, cw.find("counts increase")) == ccw.substr(0, ccw.find("counts increase")));
  }

  TEST_CASE("the table's streams are due from the drive's NMT start, not during its start-up") {
    Bus live;
    CHECK(std::isinf(live.driver->streams_due_s()));  // nothing started: as they come
    live.start();
    // reset, boot-up, configuration: due when the start-up's own timeouts
    // would all have run out (2 s boot-up, some 60 SDOs of 0.5 s), no later
    const double budget = live.driver->streams_due_s() - live.t;
    CHECK(std::isfinite(budget));
    CHECK(budget > 20);
    CHECK(budget < 60);
    // the NMT start, seen on the bus by an observer too (a replay of the log)
    Bus watcher({}, true);
    REQUIRE(live.run_until([&] { return live.driver->streams_due_s() <= live.t; }, 2.0));
    const double due = live.driver->streams_due_s();
    CHECK(due > 0.005);  // not before the drive's boot-up
    const auto see = [&](canopen::NmtCommand c, int node, double t) {
      can::Frame nmt = canopen::nmt_frame(c, static_cast<std::uint8_t>(node));
      watcher.see(nmt, t);
      return watcher.driver->streams_due_s();
    };
    using canopen::NmtCommand;
    // a reset: starting, for the same budget as the live master's
    CHECK(see(NmtCommand::ResetCommunication, 1, 1.0) == doctest::Approx(1.0 + budget));
    // pre-operational is part of the start-up (the configuration)
    CHECK(see(NmtCommand::EnterPreOperational, 1, 1.1) == doctest::Approx(1.0 + budget));
    CHECK(see(NmtCommand::Start, 1, 1.25) == 1.25);
    CHECK(see(NmtCommand::Start, 2, 1.5) == 1.25);  // another node's
    can::Frame odd = canopen::nmt_frame(NmtCommand::Start, 1);
    odd.data[0] = 0x7E;  // no command CiA 301 defines
    watcher.see(odd, 1.6);
    CHECK(watcher.driver->streams_due_s() == 1.25);
    // out of operational while it ran: its PDOs stop, due (and lost) at once
    CHECK(see(NmtCommand::EnterPreOperational, 1, 2.0) == 2.0);
    CHECK(see(NmtCommand::Start, 0, 2.5) == 2.5);  // all nodes
    CHECK(see(NmtCommand::Stop, 1, 3.0) == 3.0);
    CHECK(see(NmtCommand::ResetNode, 0, 4.0) == doctest::Approx(4.0 + budget));
  }

  TEST_CASE("observe mode: nothing sent, the status read from the statuswords") {
    // a relative move on a live pair, and an observer of the drive's frames
    Bus live;
    Bus watcher({}, true);
    live.start();
    REQUIRE(live.command(TableCommandCode::Enable, 1));
    REQUIRE(live.state_is(TableState::Holding, 1));
    REQUIRE(live.command(TableCommandCode::MoveRelative, 2, -20 * kDeg, 10 * kDeg));
    const std::size_t enc0 = live.encoder.size();
    REQUIRE(live.state_is(TableState::InPosition, 2, 10));
    CHECK(live.encoder.size() > enc0);
    std::vector<can::Frame> nothing;
    watcher.driver->tick(live.t, nothing);
    watcher.driver->take_frames(nothing);
    CHECK(nothing.empty());
    // a statusword of Operation enabled, target reached: in position
    can::Frame tpdo;
    tpdo.id = 0x181;
    tpdo.len = 6;
    const std::uint16_t sw = cia402::state_bits(cia402::State::OperationEnabled) |
                             cia402::sw::kTargetReached | cia402::sw::kVoltageEnabled |
                             cia402::sw::kQuickStop;
    tpdo.data[0] = static_cast<std::uint8_t>(sw & 0xFF);
    tpdo.data[1] = static_cast<std::uint8_t>(sw >> 8);
    watcher.see(tpdo, 0.5);
    REQUIRE(watcher.last());
    CHECK(watcher.last()->state == static_cast<int>(TableState::InPosition));
    REQUIRE(watcher.encoder.size() == 1);
    CHECK(watcher.encoder[0].angle_rad == 0);
    // an EMCY, then a statusword in fault: a fault named by the EMCY
    watcher.see(canopen::emcy_frame(1, 0x2310, 0x01, {}), 0.6);
    can::Frame fault = tpdo;
    const std::uint16_t fw = cia402::state_bits(cia402::State::Fault);
    fault.data[0] = static_cast<std::uint8_t>(fw & 0xFF);
    fault.data[1] = static_cast<std::uint8_t>(fw >> 8);
    watcher.see(fault, 0.61);
    CHECK(watcher.last()->state == static_cast<int>(TableState::Fault));
    CHECK(watcher.last()->fault_name.find("0x2310") != std::string::npos);
    watcher.driver->take_frames(nothing);
    CHECK(nothing.empty());
  }

  TEST_CASE("the protocol table: [table] protocol makes its own driver, checked by its own row") {
    const Stand402& s = stand402();
    auto roles = resolve_roles(s.cfg.can, s.db);
    REQUIRE(roles.ok());
    CHECK(drivers::check_table(s.cfg.can, *roles).ok());
    // the CiA 402 drive's table: its geometry is the drive's counts
    const drivers::Devices d = drivers::make_devices(s.cfg.can, *roles, Plausibility{}, 1);
    REQUIRE(d.table != nullptr);
    CHECK(d.table->geometry().find("counts_per_revolution ") == 0);
    // its check is the CiA 402 one: a layout that does not fit is refused
    Config bad = s.cfg;
    bad.can.roles[static_cast<std::size_t>(Role::TableTargetPosition)] =
        SignalRef{"DRV_RPDO1", "Controlword", {}};
    auto bad_roles = resolve_roles(bad.can, s.db);
    REQUIRE(bad_roles.ok());
    const Status st = drivers::check_table(bad.can, *bad_roles);
    REQUIRE_FALSE(st.ok());
    CHECK(st.error().message.find("can.roles.table_controlword") != std::string::npos);
    // the reference table (the shipped turncal.toml): its own driver, no
    // CiA 402 check
    auto ref = load_config(kSrc + "/config/turncal.toml");
    REQUIRE(ref.ok());
    auto ref_db = load_databases(ref->can);
    REQUIRE(ref_db.ok());
    auto ref_roles = resolve_roles(ref->can, *ref_db);
    REQUIRE(ref_roles.ok());
    CHECK(drivers::check_table(ref->can, *ref_roles).ok());
    const drivers::Devices r = drivers::make_devices(ref->can, *ref_roles, Plausibility{}, 1);
    REQUIRE(r.table != nullptr);
    CHECK(r.table->geometry().find("counts_per_revolution") == std::string::npos);
    // a name no row has (set past the configuration reader) is refused, not
    // taken for another protocol
    Config none = ref.value();
    none.can.table.name = "canopen";
    const Status no = drivers::check_table(none.can, *ref_roles);
    REQUIRE_FALSE(no.ok());
    CHECK(no.error().message == "[table] protocol = \"canopen\": no driver of that protocol");
    CHECK_THROWS_AS((void)drivers::make_devices(none.can, *ref_roles, Plausibility{}, 1),
                    std::invalid_argument);
  }

  TEST_CASE("settings the DBC's layout does not fit leave the driver inert with the reason") {
    Config cfg = stand402().cfg;
    cfg.can.roles[static_cast<std::size_t>(Role::TableTargetPosition)] =
        SignalRef{"DRV_RPDO1", "Controlword", {}};
    auto roles = resolve_roles(cfg.can, stand402().db);
    REQUIRE(roles.ok());
    const Status st = drivers::check_cia402_table(cfg.can, *roles);
    REQUIRE_FALSE(st.ok());
    // named at the key of the role whose message does not fit
    CHECK(st.error().message.find("can.roles.table_controlword") != std::string::npos);
    CHECK(st.error().message.find("cia402") != std::string::npos);
    CHECK(st.error().where.file.ends_with("stands/cia402/turncal.toml"));
    CHECK(st.error().where.line > 0);
    auto driver = drivers::make_cia402_table(cfg.can.table.cia402, *roles);
    std::vector<can::Frame> out;
    driver->start(0, out);
    CHECK(out.empty());
    auto cmd = driver->command(TableCommand{TableCommandCode::Enable, 1});
    REQUIRE_FALSE(cmd.ok());
    const Decoded d = driver->pending();
    REQUIRE(d.verdict == Decoded::Verdict::Taken);
    CHECK(std::get<TableStatusSample>(d.sample).state == static_cast<int>(TableState::Fault));
  }
}
