#include "turncal/physics/profile.hpp"

#include <algorithm>
#include <cmath>

namespace turncal {

Profile classic_profile(double duration_s, double turn_start_s, double angle_rad,
                        double max_rate_rps, double max_accel_rps2) {
  Profile p;
  p.duration_s = duration_s;
  p.turns.push_back(TurnSpec{turn_start_s, angle_rad, max_rate_rps, max_accel_rps2});
  return p;
}

std::size_t TableMotion::count_until(double t, std::size_t hint) const {
  const std::size_t n = pieces_.size();
  // a hint past a piece that starts after t (t went back, or the plan was
  // cut short) says nothing: search from the start
  if (hint > n || (hint > 0 && t < pieces_[hint - 1].t0)) hint = 0;
  // stepping through time, the piece is this one or one of the next few
  for (int step = 0; step < 4; ++step, ++hint)
    if (hint == n || t < pieces_[hint].t0) return hint;
  const auto it =
      std::upper_bound(pieces_.begin() + static_cast<std::ptrdiff_t>(hint), pieces_.end(), t,
                       [](double v, const Piece& p) { return v < p.t0; });
  return static_cast<std::size_t>(it - pieces_.begin());
}

TableMotion::State TableMotion::state_in(std::size_t count, double t) const {
  if (count == 0) return {angle0_, 0, 0};
  const Piece& p = pieces_[count - 1];
  const double dt = t - p.t0;
  return {p.angle0 + p.rate0 * dt + 0.5 * p.accel * dt * dt, p.rate0 + p.accel * dt, p.accel};
}

TableMotion::State TableMotion::at(double t) const {
  return state_in(count_until(t, 0), t);
}

TableMotion::State TableMotion::at(double t, std::size_t& hint) const {
  hint = count_until(t, hint);
  return state_in(hint, t);
}

void TableMotion::truncate(double t) {
  const State s = at(t);
  while (!pieces_.empty() && pieces_.back().t0 >= t) pieces_.pop_back();
  pieces_.push_back({t, s.angle, s.rate, 0});
}

void TableMotion::push(double t0, double accel) {
  const State s = at(t0);
  pieces_.push_back({t0, s.angle, s.rate, accel});
}

TableMotion::Move TableMotion::move_by(double t, double delta, double max_rate, double max_accel) {
  t = std::max(t, rest_time());
  truncate(t);
  const double start = pieces_.back().angle0;
  const double d = std::fabs(delta), sign = delta < 0 ? -1.0 : 1.0;
  double t_acc = max_rate / max_accel, t_cruise = 0, w = max_rate;
  if (d >= max_rate * t_acc) {
    t_cruise = (d - w * t_acc) / w;
  } else {  // triangular: the rate limit is never reached
    t_acc = std::sqrt(d / max_accel);
    w = max_accel * t_acc;
  }
  pieces_.back().accel = sign * max_accel;
  if (t_cruise > 0) push(t + t_acc, 0);
  push(t + t_acc + t_cruise, -sign * max_accel);
  const double t_end = t + 2 * t_acc + t_cruise;
  // rest exactly at the target: no round-off drift of the angle
  pieces_.push_back({t_end, start + delta, 0, 0});
  return {t, t_end, w};
}

double TableMotion::stop(double t, double decel) {
  truncate(t);
  const State s = at(t);
  if (s.rate == 0) return t;
  const double t_rest = t + std::fabs(s.rate) / decel;
  pieces_.back().accel = s.rate > 0 ? -decel : decel;
  const double angle = s.angle + 0.5 * s.rate * (t_rest - t);
  pieces_.push_back({t_rest, angle, 0, 0});
  return t_rest;
}

void TableMotion::breakpoints_in(double ta, double tb, std::vector<double>& out,
                                 std::size_t& hint) const {
  hint = count_until(ta, hint);
  for (std::size_t i = hint; i < pieces_.size() && pieces_[i].t0 < tb; ++i)
    out.push_back(pieces_[i].t0);
}

std::vector<double> TableMotion::breakpoints() const {
  std::vector<double> b;
  b.reserve(pieces_.size());
  for (const Piece& p : pieces_) b.push_back(p.t0);
  return b;
}

TableTrajectory::TableTrajectory(const Profile& profile) : duration_(profile.duration_s) {
  for (const TurnSpec& t : profile.turns)
    moves_.push_back(motion_.move_by(t.start_s, t.angle_rad, t.max_rate_rps, t.max_accel_rps2));
}

}  // namespace turncal
