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

  TEST_CASE(
      "each IMU step's increments are the integrals of the table's motion, still or turning") {
    // The strapdown integrates a step at rest in closed form (the Earth
    // rate at a fixed azimuth, its sine and cosine kept while the table is
    // still) and any other step by Gauss-Legendre quadrature between the
    // times the acceleration jumps. Given a noise-free IMU with only the
    // proof-mass offsets r (so dv_2 carries int Omega^2 dt), two turns (one
    // starting on an IMU step's boundary, the other and its acceleration
    // jumps inside steps, off any round fraction of a step) and holds,
    // every step's increments must match a composite Simpson integral of
    // the same motion, taken piece by piece between the motion's
    // breakpoints (so the reference itself never straddles a jump), to
    // 1e-10 relative, each part against its own size: the horizontal angle
    // increment (the Earth rate alone, ~1e-7 rad a step), the vertical one
    // (Earth rate and table angle) and dv_2; dv_1, with a bias df0_1 and a
    // g-sensitivity G13 injected, is (df0_1 + G13 g) dt and dv_3 g dt, dt
    // being the step's own tb - ta. The match is to a few 1e-15. A closed form taken in a step
    // where the table moves misses the horizontal increment by 2e-7 (a turn that starts inside the
    // step) to 2e-3 (cruising) of itself, and dv_2 by 5e-7 to all of it (tried: the closed form
    // without the rest test's rate, or without its piece test, fails the horizontal and the dv_2
    // check; the vertical one holds, as the table angle's difference is exact).
    sim::Config c;
    c.latitude_rad = 55.75 * kDeg;
    c.height_m = 150;
    c.psi_start_rad = 30 * kDeg;
    c.imu_rate_hz = 400;
    c.profile.duration_s = 40;
    c.profile.align_s = 1;
    c.profile.turns = {{5, 180 * kDeg, 60 * kDeg, 40 * kDeg},
                       {20.0011, -450 * kDeg, 90 * kDeg, 60 * kDeg}};  // inside a step
    c.errors.r = Eigen::Vector2d(0.03, -0.02);
    c.errors.df0.x() = 2e-3;  // m/s^2, some 200 ug
    c.errors.g.x() = 3e-4;    // G13
    sim::Strapdown sd(c);
    const TableTrajectory table(c.profile);
    const std::vector<double> breaks = table.breakpoints();
    const double u2 = earth::kRate * std::cos(c.latitude_rad);
    const double u3 = earth::kRate * std::sin(c.latitude_rad);
    const double g = earth::normal_gravity(c.latitude_rad, c.height_m);
    const double dt = 1 / c.imu_rate_hz;
    // the worst of each relative error, and the errors that are NaN
    double worst_h = 0, worst_v = 0, worst_dv = 0, worst_other = 0;
    int nans = 0;
    const auto worsen = [&nans](double& worst, double e) {
      if (std::isnan(e))
        ++nans;
      else if (e > worst)
        worst = e;
    };
    int moving = 0, still = 0, split = 0;
    for (int k = 0; k * dt < c.profile.duration_s; ++k) {
      const double ta = k * dt, tb = (k + 1) * dt;
      const sim::Strapdown::Increments inc = sd.imu(ta, tb);
      // the step's smooth pieces
      std::vector<double> ends{ta};
      for (const double b : breaks)
        if (b > ta && b < tb) ends.push_back(b);
      ends.push_back(tb);
      split += ends.size() > 2;
      // Simpson, 64 panels a piece: the Earth rate in body axes and Omega^2
      Eigen::Vector3d earth_int = Eigen::Vector3d::Zero();
      double omega2 = 0;
      for (std::size_t j = 0; j + 1 < ends.size(); ++j) {
        constexpr int kPanels = 64;
        const double h = (ends[j + 1] - ends[j]) / kPanels;
        for (int i = 0; i <= kPanels; ++i) {
          const double w = (i == 0 || i == kPanels) ? 1 : (i % 2 == 1 ? 4 : 2);
          const double t = i == kPanels ? ends[j + 1] : ends[j] + i * h;
          const TableMotion::State st = table.at(t);
          const double psi = c.psi_start_rad + st.angle;
          earth_int += w * h / 3 * Eigen::Vector3d(u2 * std::sin(psi), u2 * std::cos(psi), u3);
          omega2 += w * h / 3 * st.rate * st.rate;
        }
      }
      const TableMotion::State sa = table.at(ta), sb = table.at(tb);
      (sa.rate == 0 && sb.rate == 0 && sa.angle == sb.angle ? still : moving) += 1;
      const double dtheta_z = earth_int.z() + (sb.angle - sa.angle);
      const double dv2 = c.errors.r.x() * (sb.rate - sa.rate) - c.errors.r.y() * omega2;
      // relative to its two terms' size (they may nearly cancel)
      const double dv2_size = std::abs(c.errors.r.x() * (sb.rate - sa.rate)) +
                              std::abs(c.errors.r.y() * omega2) + 1e-12 * g * dt;
      worsen(worst_h,
             (inc.dtheta.head<2>() - earth_int.head<2>()).norm() / earth_int.head<2>().norm());
      // relative to the Earth term's and the table angle's size
      worsen(worst_v, std::abs(inc.dtheta.z() - dtheta_z) /
                          (std::abs(earth_int.z()) + std::abs(sb.angle - sa.angle)));
      worsen(worst_dv, std::abs(inc.dv.y() - dv2) / dv2_size);
      const double step = tb - ta;  // as the strapdown takes it, 7e-15 off dt at 40 s
      const double dv1 = (c.errors.df0.x() + c.errors.g.x() * g) * step;
      worsen(worst_other, std::abs(inc.dv.x() - dv1) / std::abs(dv1));
      worsen(worst_other, std::abs(inc.dv.z() - g * step) / (g * step));
    }
    MESSAGE("worst relative error: horizontal angle increment "
            << worst_h << ", vertical " << worst_v << ", dv_2 " << worst_dv << ", dv_1 and dv_3 "
            << worst_other << "; " << moving << " steps moving (" << split
            << " with a jump inside), " << still << " still");
    // the steps that overlap a turn: 1800 and 2600, and one more as the
    // second starts inside a step; jumps inside a step: the second turn's
    // four
    double turning = 0;
    for (std::size_t i = 0; i < table.turns(); ++i)
      turning += (table.turn_end(i) - table.turn_start(i)) / dt;
    CHECK(moving == std::lround(turning) + 1);
    CHECK(split == 4);
    CHECK(nans == 0);
    CHECK(worst_h < 1e-10);
    CHECK(worst_v < 1e-10);
    CHECK(worst_dv < 1e-10);
    CHECK(worst_other < 1e-10);
  }

  TEST_CASE("a run that asks for no encoder samples gets none, and the same velocity") {
    const Scenario s = tactical();
    std::mt19937_64 rng(43);
    const est::XiVec xi = draw(s, rng);
    sim::Config with = sim_config(s, xi, 10 * kDeg, 9);
    with.profile.duration_s = 1900;
    sim::Config without = with;
    without.encoder_rate_hz = 0;
    const sim::Run a = sim::simulate(with);
    const sim::Run b = sim::simulate(without);
    CHECK(b.encoder.empty());
    CHECK(a.encoder.size() > 1000);
    REQUIRE(b.velocity.size() == a.velocity.size());
    std::size_t same = 0;
    for (std::size_t i = 0; i < a.velocity.size(); ++i)
      same += a.velocity[i].t_s == b.velocity[i].t_s && a.velocity[i].ve == b.velocity[i].ve &&
              a.velocity[i].vn == b.velocity[i].vn;
    CHECK(same == a.velocity.size());
  }
}

#include "turncal/sim/virtual_ins.hpp"
#include "turncal/sim/virtual_table.hpp"

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
