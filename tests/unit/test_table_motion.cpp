#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "turncal/physics/profile.hpp"

using namespace turncal;

namespace {
constexpr double kDeg = 3.14159265358979323846 / 180;

/// Angle and rate continuous, rate and acceleration within the limits,
/// sampled densely over [t1, t2].
void check_smooth(const TableMotion& m, double t1, double t2, double max_rate, double max_accel) {
  TableMotion::State prev = m.at(t1);
  const double h = 1e-4;
  double rate = 0, accel = 0, jump_angle = 0, jump_rate = 0;
  for (double t = t1 + h; t <= t2; t += h) {
    const TableMotion::State s = m.at(t);
    rate = std::max(rate, std::fabs(s.rate));
    accel = std::max(accel, std::fabs(s.accel));
    jump_angle = std::max(jump_angle, std::fabs(s.angle - prev.angle) - max_rate * h);
    jump_rate = std::max(jump_rate, std::fabs(s.rate - prev.rate) - max_accel * h);
    prev = s;
  }
  CHECK(rate <= max_rate * (1 + 1e-12));
  CHECK(accel <= max_accel * (1 + 1e-12));
  CHECK(jump_angle <= 1e-12);  // continuous angle
  CHECK(jump_rate <= 1e-12);   // continuous rate
}
}  // namespace

TEST_SUITE("table motion") {
  TEST_CASE("a trapezoidal move reaches its target at rest, within the limits") {
    TableMotion m(10 * kDeg);
    const auto mv = m.move_by(100, 180 * kDeg, 30 * kDeg, 30 * kDeg);
    CHECK(mv.t_start == 100);
    // 1 s up to 30 deg/s (15 deg), 5 s cruise (150 deg), 1 s down (15 deg)
    CHECK(mv.t_end == doctest::Approx(107));
    CHECK(mv.peak_rate == doctest::Approx(30 * kDeg));
    CHECK(m.at(99).angle == 10 * kDeg);
    CHECK(m.at(103).rate == doctest::Approx(30 * kDeg));
    CHECK(m.at(107).angle == doctest::Approx(190 * kDeg).epsilon(1e-15));
    CHECK(m.at(1000).rate == 0);
    CHECK(m.at(1000).angle == doctest::Approx(190 * kDeg).epsilon(1e-15));
    check_smooth(m, 99, 108, 30 * kDeg, 30 * kDeg);
    CHECK(m.breakpoints().size() == 4);
  }

  TEST_CASE("a short move never reaches the rate limit: triangular") {
    TableMotion m;
    const auto mv = m.move_by(0, -4 * kDeg, 30 * kDeg, 16 * kDeg);
    // 2 deg each way at 16 deg/s^2: 0.5 s each, peak 8 deg/s
    CHECK(mv.t_end == doctest::Approx(1.0));
    CHECK(mv.peak_rate == doctest::Approx(8 * kDeg));
    CHECK(m.at(0.5).rate == doctest::Approx(-8 * kDeg));
    CHECK(m.at(2).angle == doctest::Approx(-4 * kDeg));
    check_smooth(m, 0, 2, 30 * kDeg, 16 * kDeg);
  }

  TEST_CASE("stop mid-move: decelerates to rest, keeps the history before") {
    TableMotion m;
    m.move_by(0, 180 * kDeg, 30 * kDeg, 30 * kDeg);
    const TableMotion::State before = m.at(2.5);
    const double rest = m.stop(3, 90 * kDeg);
    CHECK(rest == doctest::Approx(3 + 30.0 / 90));
    CHECK(m.at(2.5).angle == before.angle);
    CHECK(m.at(rest).rate == doctest::Approx(0).epsilon(1e-12));
    CHECK(m.at(rest + 10).angle == doctest::Approx(m.at(rest).angle));
    // 15 deg + 2 s at 30 deg/s + 5 deg of braking
    CHECK(m.at(rest + 10).angle == doctest::Approx(80 * kDeg));
    check_smooth(m, 0, rest + 1, 30 * kDeg, 90 * kDeg);
    CHECK(m.stop(10, 90 * kDeg) == 10);  // already at rest: nothing to do
  }

  TEST_CASE("a move asked for while moving starts when the table is at rest") {
    TableMotion m;
    m.move_by(0, 90 * kDeg, 30 * kDeg, 30 * kDeg);  // ends at 4 s
    const auto second = m.move_by(2, -90 * kDeg, 30 * kDeg, 30 * kDeg);
    CHECK(second.t_start == doctest::Approx(4));
    CHECK(m.at(20).angle == doctest::Approx(0).epsilon(1e-12));
  }

  TEST_CASE("a profile's trajectory is its moves in experiment time") {
    Profile p;
    p.duration_s = 600;
    p.turns = {{100, 180 * kDeg, 30 * kDeg, 30 * kDeg}, {300, -90 * kDeg, 20 * kDeg, 10 * kDeg}};
    const TableTrajectory tr(p);
    REQUIRE(tr.turns() == 2);
    CHECK(tr.turn_end(0) == doctest::Approx(107));
    CHECK(tr.turn_start(1) == 300);
    CHECK(tr.peak_rate(1) == doctest::Approx(20 * kDeg));
    CHECK(tr.at(0).angle == 0);
    CHECK(tr.at(600).angle == doctest::Approx(90 * kDeg));
    CHECK(tr.duration() == 600);
  }

  TEST_CASE("a read with a hint gives the searched state, whatever the hint") {
    // an encoder-like motion of many pieces, read stepping forward, at the
    // same time again, back in time, from a hint past the end, and after
    // the plan was cut short: each state equal, bit for bit, to at(t)'s,
    // and the hint left at the number of pieces that start at or before t,
    // counted here from the breakpoints
    TableMotion m;
    for (int k = 0; k < 2000; ++k) m.append(0.01 * k, 0.001 * k * k, 0.2 * k, 0);
    std::size_t hint = 0;
    int differ = 0, checked = 0;
    const auto same = [&](double t) {
      const TableMotion::State a = m.at(t), b = m.at(t, hint);
      const std::vector<double> starts = m.breakpoints();
      const auto count = static_cast<std::size_t>(
          std::upper_bound(starts.begin(), starts.end(), t) - starts.begin());
      ++checked;
      if (a.angle != b.angle || a.rate != b.rate || a.accel != b.accel || hint != count) ++differ;
    };
    for (double t = -1; t < 21; t += 0.0037) same(t);  // before, through and past the pieces
    same(20.5);
    same(20.5);
    for (double t = 15; t > -0.5; t -= 0.71) same(t);  // backwards: a search each time
    hint = 1u << 20;                                   // nonsense: a search
    same(3.3);
    std::vector<double> cuts;
    m.breakpoints_in(4.999, 5.031, cuts, hint);  // from the hint at 3.3 s: a search
    CHECK(cuts == std::vector<double>{0.01 * 500, 0.01 * 501, 0.01 * 502, 0.01 * 503});
    cuts.clear();
    m.breakpoints_in(0.01 * 500, 0.01 * 502, cuts, hint);  // strictly inside: not its ends
    CHECK(cuts == std::vector<double>{0.01 * 501});
    for (double t = 18; t < 20.5; t += 0.01) same(t);    // the hint near the end
    for (int k = 0; k < 2000; ++k) same(0.01 * k);       // exactly on piece starts
    for (int k = 1990; k > 0; k -= 331) same(0.01 * k);  // and back
    // the hint past the piece that the plan, cut short next, ends with: at
    // 200 rad/s and 1e4 rad/s^2 it comes to rest at 10.025 s, so the hint
    // (after 10.02 s) is within the new plan's size but past a piece that
    // starts after the next read: stale
    same(10.027);
    const double rest = m.stop(10.005, 1e4);
    CHECK(rest == doctest::Approx(10.025));
    same(10.005);
    for (double t = 9.9; t < 12; t += 0.001) same(t);
    CHECK(checked > 6000);
    CHECK(differ == 0);
  }
}
