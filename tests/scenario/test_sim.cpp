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
