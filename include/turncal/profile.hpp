// An experiment profile (holds and turns) and the table trajectory it
// implies: trapezoidal rate, within rate and acceleration limits. Used by
// the virtual stand to move the table and by planning; not by the linear
// model, which sees only encoder samples.
#pragma once

#include <vector>

namespace turncal {

struct TurnSpec {
  double start_s = 0;         ///< experiment time the turn starts (t0 = 0), s
  double angle_rad = 0;       ///< signed, counter-clockwise seen from above
  double max_rate_rps = 0;    ///< rad/s
  double max_accel_rps2 = 0;  ///< rad/s^2
};

struct Profile {
  double duration_s = 3600;     ///< navigation time from t0 to the end, s
  double align_s = 120;         ///< alignment before t0, s
  std::vector<TurnSpec> turns;  ///< in time order, not overlapping
};

/// The classic profile: one turn of `angle_rad` at `turn_start_s`.
Profile classic_profile(double duration_s, double turn_start_s, double angle_rad,
                        double max_rate_rps, double max_accel_rps2);

/// Table angle, rate and acceleration as functions of experiment time;
/// piecewise quadratic in angle.
class TableTrajectory {
 public:
  explicit TableTrajectory(const Profile& profile);
  struct State {
    double angle;  ///< rad, relative to the angle at t0
    double rate;   ///< rad/s
    double accel;  ///< rad/s^2
  };
  [[nodiscard]] State at(double t) const;
  /// Times where the acceleration jumps (segment boundaries), ascending.
  [[nodiscard]] const std::vector<double>& breakpoints() const { return breaks_; }
  /// Start and end time of turn i.
  [[nodiscard]] double turn_start(std::size_t i) const { return segs_[i].t0; }
  [[nodiscard]] double turn_end(std::size_t i) const { return segs_[i].t3; }
  [[nodiscard]] double peak_rate(std::size_t i) const { return segs_[i].w; }
  [[nodiscard]] std::size_t turns() const { return segs_.size(); }
  /// The profile's run length from t0, s.
  [[nodiscard]] double duration() const { return duration_; }

 private:
  struct Seg {
    double t0, t1, t2, t3;  // accel, cruise, decel boundaries
    double a, w, sign, angle0;
  };
  std::vector<Seg> segs_;
  std::vector<double> breaks_;
  double duration_ = 0;
};

}  // namespace turncal
