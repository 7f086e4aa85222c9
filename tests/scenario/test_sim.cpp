// The nonlinear simulation driven as the virtual stand drives it: the table
// moved by commands on the stand's own clock, the heading given by a host.
#include <doctest/doctest.h>

#include "scenarios.hpp"

using namespace turncal;
using namespace scenario;

TEST_SUITE("simulation") {
  TEST_CASE("a commanded table on another clock gives the profile's run, sample for sample") {
    // Given the reference run with prior-drawn errors and noise (same seed),
    // once driven by its profile and once by a TableMotion whose clock reads
    // 500 s at t0 and which turns by command at 500 + 1800 s, with the
    // heading handed over as a host would, the velocity and encoder
    // samples must be the same to round-off.
    const Scenario s = tactical();
    std::mt19937_64 rng(42);
    const est::XiVec xi = draw(s, rng);
    const double psi_s = 25 * kDeg;
    sim::Config by_profile = sim_config(s, xi, psi_s, 9);
    by_profile.profile.duration_s = 2000;  // long enough to cover the turn
    const TableTrajectory table(by_profile.profile);

    TableMotion motion(1.25);  // the table's own angle at the start, rad
    const TurnSpec& turn = by_profile.profile.turns.at(0);
    motion.move_by(500 + turn.start_s, turn.angle_rad, turn.max_rate_rps, turn.max_accel_rps2);
    sim::Config by_command = by_profile;
    by_command.motion = &motion;
    by_command.motion_t0_s = 500;
    by_command.heading_given_rad = -psi_s;  // heading of z2 clockwise from North

    const sim::Run a = sim::simulate(by_profile);
    const sim::Run b = sim::simulate(by_command);
    REQUIRE(a.velocity.size() == b.velocity.size());
    REQUIRE(a.encoder.size() == b.encoder.size());
    double dv = 0, da = 0;
    for (std::size_t k = 0; k < a.velocity.size(); ++k)
      dv = std::max(
          dv, std::hypot(a.velocity[k].ve - b.velocity[k].ve, a.velocity[k].vn - b.velocity[k].vn));
    for (std::size_t k = 0; k < a.encoder.size(); ++k)
      da = std::max(da, std::fabs(a.encoder[k].angle_rad - b.encoder[k].angle_rad));
    MESSAGE("largest differences: velocity " << dv << " m/s, angle " << da << " rad");
    CHECK(dv < 1e-9);
    CHECK(da < 1e-12);
    // and the heading matters: a host that gives it 1 deg off moves the run
    by_command.heading_given_rad = -psi_s + kDeg;
    const sim::Run c = sim::simulate(by_command);
    double dc = 0;
    for (std::size_t k = 0; k < a.velocity.size(); ++k)
      dc = std::max(dc, std::fabs(a.velocity[k].ve - c.velocity[k].ve));
    CHECK(dc > 1e-3);
  }
}

#include "turncal/drivers/virtual_ins.hpp"
#include "turncal/drivers/virtual_table.hpp"

TEST_SUITE("simulation") {
  TEST_CASE("the virtual stand's INS and table, driven as a host would, give the batch run") {
    // Given a host that enables the table at 3 s, starts a 120 s alignment
    // at 10 s with the heading from the table (heading_offset - angle), and
    // moves the table +180 deg at t0 + 1800 s (30 deg/s), when the virtual
    // INS and table run in 5 ms ticks, then the INS's velocity samples
    // equal sim::simulate on the same profile, errors and seed.
    using namespace turncal::stand;
    const Scenario s = tactical();
    std::mt19937_64 rng(7);
    const est::XiVec xi = draw(s, rng);
    const double offset = 30 * kDeg, angle0 = 100 * kDeg;
    sim::Config batch = sim_config(s, xi, angle0 - offset, 3);
    batch.profile.duration_s = 2000;

    TableLimits lim;
    VirtualTable table(lim, angle0);
    InsSetup setup;
    setup.sim = batch;
    setup.heading_offset_rad = offset;
    VirtualIns ins(setup, table.motion());
    std::vector<InsVelocity> got;
    const double align = batch.profile.align_s;
    bool moved = false;
    for (long k = 0;; ++k) {
      const double t = static_cast<double>(k) * 0.005;
      table.advance(t);
      table.heartbeat(t);
      ins.advance(t, got);
      if (k == 600) REQUIRE(table.command(t, {TableCommandCode::Enable, 1, 0, 0}));
      if (k == 2000) {
        CHECK(ins.mode() == InsMode::Idle);
        REQUIRE(
            ins.command(t, {InsCommandCode::StartAlignment, align, offset - table.angle(t), 1}));
        CHECK(ins.mode() == InsMode::Aligning);
      }
      if (k == 2000 + 6000) CHECK(ins.align_remaining(t) == doctest::Approx(align - 30));
      if (!moved && !std::isnan(ins.t0()) && t >= ins.t0() + 1800) {
        const TurnSpec& turn = batch.profile.turns.at(0);
        REQUIRE(t == doctest::Approx(ins.t0() + turn.start_s));
        REQUIRE(table.command(
            t, {TableCommandCode::MoveRelative, 2, turn.angle_rad, turn.max_rate_rps}));
        moved = true;
      }
      if (!std::isnan(ins.t0()) && t >= ins.t0() + 2000) break;
    }
    CHECK(ins.mode() == InsMode::Navigating);
    CHECK(ins.t0() == doctest::Approx(10 + align));
    const sim::Run run = sim::simulate(batch);
    REQUIRE(got.size() >= run.velocity.size());
    double worst = 0;
    for (std::size_t k = 0; k < run.velocity.size(); ++k) {
      REQUIRE(got[k].t_s - ins.t0() == doctest::Approx(run.velocity[k].t_s));
      worst = std::max(worst,
                       std::hypot(got[k].ve - run.velocity[k].ve, got[k].vn - run.velocity[k].vn));
    }
    MESSAGE("largest velocity difference to the batch run: " << worst << " m/s");
    CHECK(worst < 1e-9);
  }

  TEST_CASE("the virtual INS: go idle, refusals, fault mode") {
    using namespace turncal::stand;
    TableMotion still(0);
    InsSetup setup;
    setup.sim = sim_config(est::XiVec::Zero(), 0);
    setup.fault_at_s = 100;
    VirtualIns ins(setup, still);
    std::vector<InsVelocity> v;
    CHECK_FALSE(ins.command(0, {InsCommandCode::StartAlignment, 0, 0, 1}));
    CHECK_FALSE(ins.command(0, {static_cast<InsCommandCode>(7), 60, 0, 1}));
    REQUIRE(ins.command(0, {InsCommandCode::StartAlignment, 30, 0, 1}));
    ins.advance(40, v);
    CHECK(ins.mode() == InsMode::Navigating);
    CHECK(v.size() == 1001);  // 100 Hz from t0 = 30 s to 40 s, both ends
    REQUIRE(ins.command(40, {InsCommandCode::GoIdle, 0, 0, 2}));
    v.clear();
    ins.advance(50, v);
    CHECK(v.empty());
    REQUIRE(ins.command(50, {InsCommandCode::StartAlignment, 30, 0, 3}));
    ins.advance(99, v);
    const std::size_t before = v.size();
    CHECK(before == 1901);  // t0 = 80 s
    ins.advance(120, v);
    CHECK(ins.mode() == InsMode::Fault);
    CHECK(v.size() == before + 100);  // up to the fault at 100 s, then silent
    CHECK(v.back().t_s == doctest::Approx(100));
    CHECK_FALSE(ins.command(120, {InsCommandCode::StartAlignment, 30, 0, 4}));
  }
}
