#include "turncal/profile.hpp"

#include <cmath>

namespace turncal {

Profile classic_profile(double duration_s, double turn_start_s, double angle_rad,
                        double max_rate_rps, double max_accel_rps2) {
  Profile p;
  p.duration_s = duration_s;
  p.turns.push_back(TurnSpec{turn_start_s, angle_rad, max_rate_rps, max_accel_rps2});
  return p;
}

TableTrajectory::TableTrajectory(const Profile& profile) : duration_(profile.duration_s) {
  double angle = 0;
  for (const TurnSpec& t : profile.turns) {
    Seg s{};
    const double d = std::fabs(t.angle_rad);
    s.sign = t.angle_rad < 0 ? -1.0 : 1.0;
    s.a = t.max_accel_rps2;
    s.angle0 = angle;
    double t_acc = t.max_rate_rps / s.a;
    double t_cruise = 0;
    if (d >= t.max_rate_rps * t_acc) {
      s.w = t.max_rate_rps;
      t_cruise = (d - s.w * t_acc) / s.w;
    } else {  // triangular: the rate limit is never reached
      t_acc = std::sqrt(d / s.a);
      s.w = s.a * t_acc;
    }
    s.t0 = t.start_s;
    s.t1 = s.t0 + t_acc;
    s.t2 = s.t1 + t_cruise;
    s.t3 = s.t2 + t_acc;
    segs_.push_back(s);
    for (double b : {s.t0, s.t1, s.t2, s.t3}) breaks_.push_back(b);
    angle += t.angle_rad;
  }
}

TableTrajectory::State TableTrajectory::at(double t) const {
  double angle = 0;
  for (const Seg& s : segs_) {
    if (t <= s.t0) return {s.angle0, 0, 0};
    const double a_acc = 0.5 * s.a * (s.t1 - s.t0) * (s.t1 - s.t0);
    if (t < s.t1) {
      const double dt = t - s.t0;
      return {s.angle0 + s.sign * 0.5 * s.a * dt * dt, s.sign * s.a * dt, s.sign * s.a};
    }
    if (t < s.t2) {
      const double dt = t - s.t1;
      return {s.angle0 + s.sign * (a_acc + s.w * dt), s.sign * s.w, 0};
    }
    const double total = 2 * a_acc + s.w * (s.t2 - s.t1);
    if (t < s.t3) {
      const double dt = s.t3 - t;
      return {s.angle0 + s.sign * (total - 0.5 * s.a * dt * dt), s.sign * s.a * dt, -s.sign * s.a};
    }
    angle = s.angle0 + s.sign * total;
  }
  return {angle, 0, 0};
}

}  // namespace turncal
