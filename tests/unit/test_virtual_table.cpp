#include <doctest/doctest.h>

#include <cmath>

#include "turncal/sim/virtual_table.hpp"

using namespace turncal::stand;

namespace {
constexpr double kDeg = 0.017453292519943295;

TableCommand cmd(TableCommandCode c, std::uint8_t seq, double target = 0, double rate = 0) {
  return TableCommand{c, seq, target, rate};
}

/// Drives the table with a heartbeat every 0.1 s up to t_end.
void run_with_heartbeat(VirtualTable& tb, double from, double to) {
  for (double t = from; t <= to + 1e-9; t += 0.1) {
    tb.advance(t);
    tb.heartbeat(t);
  }
}
}  // namespace

TEST_SUITE("virtual table") {
  TEST_CASE("enable, move relative, in position, acknowledged by Seq") {
    VirtualTable tb;
    CHECK(tb.status(0).state == TableState::Disabled);
    // a move while disabled is refused: no ack, fault 4
    CHECK_FALSE(tb.command(0, cmd(TableCommandCode::MoveRelative, 7, 90 * kDeg, 30 * kDeg)));
    CHECK(tb.status(0).ack_seq == 0);
    CHECK(tb.status(0).fault == TableFault::Refused);
    CHECK(tb.command(0, cmd(TableCommandCode::Enable, 8)));
    CHECK(tb.status(0).ack_seq == 8);
    CHECK(tb.status(0).fault == TableFault::None);
    CHECK(tb.status(0).state == TableState::Holding);
    tb.heartbeat(0);
    CHECK(tb.command(0, cmd(TableCommandCode::MoveRelative, 9, 180 * kDeg, 30 * kDeg)));
    run_with_heartbeat(tb, 0, 3);
    CHECK(tb.status(3).state == TableState::Moving);
    CHECK(tb.status(3).rate_rps == doctest::Approx(30 * kDeg));
    run_with_heartbeat(tb, 3, 8);
    CHECK(tb.status(8).state == TableState::InPosition);
    CHECK(tb.status(8).ack_seq == 9);
    CHECK(tb.angle(8) == doctest::Approx(180 * kDeg));
    // absolute back to 10 deg at a lower rate limit
    CHECK(tb.command(8, cmd(TableCommandCode::MoveAbsolute, 10, 10 * kDeg, 20 * kDeg)));
    run_with_heartbeat(tb, 8, 30);
    CHECK(tb.angle(30) == doctest::Approx(10 * kDeg));
    double peak = 0;
    for (double t = 8; t < 30; t += 0.01) peak = std::max(peak, std::fabs(tb.status(t).rate_rps));
    CHECK(peak == doctest::Approx(20 * kDeg));
  }

  TEST_CASE(
      "limits are refused: rate above the table's, target beyond a soft limit, move while moving") {
    TableLimits lim;
    lim.angle_min_rad = -200 * kDeg;
    lim.angle_max_rad = 200 * kDeg;
    VirtualTable tb(lim);
    REQUIRE(tb.command(0, cmd(TableCommandCode::Enable, 1)));
    tb.heartbeat(0);
    CHECK_FALSE(tb.command(0, cmd(TableCommandCode::MoveRelative, 2, 90 * kDeg, 31 * kDeg)));
    CHECK_FALSE(tb.command(0, cmd(TableCommandCode::MoveRelative, 3, 90 * kDeg, 0)));
    CHECK_FALSE(tb.command(0, cmd(TableCommandCode::MoveAbsolute, 4, 201 * kDeg, 30 * kDeg)));
    CHECK(tb.status(0).ack_seq == 1);
    CHECK(tb.status(0).fault == TableFault::Refused);
    CHECK(tb.command(0, cmd(TableCommandCode::MoveRelative, 5, 150 * kDeg, 30 * kDeg)));
    CHECK(tb.status(0).fault == TableFault::None);
    run_with_heartbeat(tb, 0, 1);
    REQUIRE(tb.status(1).state == TableState::Moving);
    CHECK_FALSE(tb.command(1, cmd(TableCommandCode::MoveRelative, 6, 10 * kDeg, 30 * kDeg)));
    CHECK_FALSE(tb.command(1, cmd(TableCommandCode::Disable, 7)));
    CHECK_FALSE(tb.command(1, cmd(static_cast<TableCommandCode>(9), 8)));
    CHECK(tb.status(1).ack_seq == 5);
    // relative moves count on the multi-turn angle: 150 + 100 > 200
    run_with_heartbeat(tb, 1, 10);
    CHECK_FALSE(tb.command(10, cmd(TableCommandCode::MoveRelative, 9, 100 * kDeg, 30 * kDeg)));
  }

  TEST_CASE("controlled stop and quick stop") {
    VirtualTable tb;
    REQUIRE(tb.command(0, cmd(TableCommandCode::Enable, 1)));
    tb.heartbeat(0);
    REQUIRE(tb.command(0, cmd(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg)));
    run_with_heartbeat(tb, 0, 3);
    CHECK(tb.command(3, cmd(TableCommandCode::ControlledStop, 3)));
    tb.advance(3.5);
    CHECK(tb.status(3.5).state == TableState::Moving);  // braking at 30 deg/s^2 for 1 s
    run_with_heartbeat(tb, 3.5, 5);
    CHECK(tb.status(5).state == TableState::InPosition);
    CHECK(tb.angle(5) == doctest::Approx((15 + 60 + 15) * kDeg));
    REQUIRE(tb.command(5, cmd(TableCommandCode::MoveRelative, 4, 180 * kDeg, 30 * kDeg)));
    run_with_heartbeat(tb, 5, 8);
    CHECK(tb.command(8, cmd(TableCommandCode::QuickStop, 5)));
    CHECK(tb.status(8).state == TableState::QuickStopped);
    CHECK(tb.status(8).ack_seq == 5);
    // 30 deg/s at 180 deg/s^2: at rest after 1/6 s
    CHECK(tb.status(8 + 1.0 / 6 + 1e-9).rate_rps == doctest::Approx(0));
    CHECK(tb.status(8.1).rate_rps > 0);
    CHECK_FALSE(tb.command(8.1, cmd(TableCommandCode::Enable, 6)));  // still braking
    CHECK(tb.command(9, cmd(TableCommandCode::Enable, 7)));
    CHECK(tb.status(9).state == TableState::Holding);
  }

  TEST_CASE("heartbeat loss while moving quick-stops the table by itself, 500 ms after the last") {
    VirtualTable tb;
    REQUIRE(tb.command(0, cmd(TableCommandCode::Enable, 1)));
    run_with_heartbeat(tb, 0, 1);
    REQUIRE(tb.command(1, cmd(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg)));
    run_with_heartbeat(tb, 1, 2.0);  // last heartbeat at 2.0
    tb.advance(2.49);
    CHECK(tb.status(2.49).state == TableState::Moving);
    tb.advance(3.0);
    CHECK(tb.status(3.0).state == TableState::QuickStopped);
    CHECK(tb.status(3.0).fault == TableFault::HeartbeatLost);
    // braking started at 2.5 s exactly: at rest 1/6 s later
    CHECK(std::fabs(tb.status(2.5).rate_rps) == doctest::Approx(30 * kDeg));
    CHECK(tb.status(2.5 + 1.0 / 6 + 1e-9).rate_rps == doctest::Approx(0));
    // at rest and holding, a silent host is no danger: no fault
    VirtualTable still;
    REQUIRE(still.command(0, cmd(TableCommandCode::Enable, 1)));
    still.advance(100);
    CHECK(still.status(100).state == TableState::Holding);
    CHECK(still.status(100).fault == TableFault::None);
  }

  TEST_CASE("injected faults: stall, overshoot, drive fault") {
    TableFaults f;
    f.stall_after_s = 2;
    VirtualTable stall({}, 0, f);
    REQUIRE(stall.command(0, cmd(TableCommandCode::Enable, 1)));
    stall.heartbeat(0);
    REQUIRE(stall.command(0, cmd(TableCommandCode::MoveRelative, 2, 180 * kDeg, 30 * kDeg)));
    run_with_heartbeat(stall, 0, 10);
    CHECK(stall.status(10).state == TableState::Fault);
    CHECK(stall.status(10).fault == TableFault::Stall);
    CHECK(stall.angle(10) < 180 * kDeg);

    TableFaults o;
    o.overshoot_rad = 2 * kDeg;
    VirtualTable over({}, 0, o);
    REQUIRE(over.command(0, cmd(TableCommandCode::Enable, 1)));
    over.heartbeat(0);
    REQUIRE(over.command(0, cmd(TableCommandCode::MoveRelative, 2, 90 * kDeg, 30 * kDeg)));
    double most = 0;
    for (double t = 0; t <= 10; t += 0.005) {
      over.advance(t);
      over.heartbeat(t);
      most = std::max(most, over.angle(t));
    }
    CHECK(most == doctest::Approx(92 * kDeg));
    CHECK(over.angle(10) == doctest::Approx(90 * kDeg));
    CHECK(over.status(10).state == TableState::InPosition);

    TableFaults d;
    d.drive_fault_at_s = 5;
    VirtualTable drive({}, 0, d);
    REQUIRE(drive.command(0, cmd(TableCommandCode::Enable, 1)));
    drive.advance(4.9);
    CHECK(drive.status(4.9).state == TableState::Holding);
    drive.advance(5.1);
    CHECK(drive.status(5.1).state == TableState::Fault);
    CHECK(drive.status(5.1).fault == TableFault::Drive);
    CHECK(drive.command(6, cmd(TableCommandCode::Enable, 2)));  // reset
    CHECK(drive.status(6).fault == TableFault::None);
  }
}
