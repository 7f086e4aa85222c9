// An experiment profile (holds and turns) and the table trajectory it
// implies: trapezoidal rate, within rate and acceleration limits. Used by
// the virtual stand to move the table and by planning; not by the linear
// model, which sees only encoder samples.
#pragma once

#include <cassert>
#include <cstddef>
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

/// Table angle, rate and acceleration of a table driven by commands: a
/// piecewise-quadratic angle history, each piece at a constant
/// acceleration. A new plan at time t replaces whatever was planned after
/// t; the history before t is kept, so the motion can be queried (and
/// integrated exactly, piece by piece) at any time. Times are of one clock,
/// any origin; before the first piece the table rests at the start angle.
class TableMotion {
 public:
  struct State {
    double angle;  ///< rad, counter-clockwise seen from above
    double rate;   ///< rad/s
    double accel;  ///< rad/s^2
  };
  /// One planned move, as it will happen if nothing interrupts it.
  struct Move {
    double t_start;
    double t_end;  ///< at rest again
    double peak_rate;
  };
  explicit TableMotion(double angle0 = 0) : angle0_(angle0) {}
  [[nodiscard]] State at(double t) const;
  /// The same, for a caller stepping through time: `hint` is where the last
  /// query left off (start it at 0) and is updated, so that a query at a
  /// time at or a little after the last one finds its piece without a
  /// search. Any hint gives the same state; a stale one (the plan changed,
  /// or t went back) only costs the search.
  [[nodiscard]] State at(double t, std::size_t& hint) const;
  /// A move from rest at t by `delta` rad: trapezoidal rate within the
  /// limits, triangular when the rate limit is not reached. If the table is
  /// not at rest at t, the move starts when the current plan comes to rest.
  Move move_by(double t, double delta, double max_rate, double max_accel);
  /// Decelerates from the state at t to rest at `decel` (rad/s^2); returns
  /// the time it is at rest.
  double stop(double t, double decel);
  /// Times where the acceleration may jump, ascending.
  [[nodiscard]] std::vector<double> breakpoints() const;
  /// Appends those strictly inside (ta, tb); `hint` as for at().
  void breakpoints_in(double ta, double tb, std::vector<double>& out, std::size_t& hint) const;
  /// Appends a piece from t0 (after every piece so far): angle, rate and
  /// acceleration at t0. A motion known by samples (an encoder's, linear
  /// between them) rather than planned.
  void append(double t0, double angle, double rate, double accel) {
    assert(pieces_.empty() || t0 >= pieces_.back().t0);  // at() searches them by t0
    pieces_.push_back({t0, angle, rate, accel});
  }
  /// The first time at or after t from which the plan stays at rest.
  [[nodiscard]] double rest_time() const { return pieces_.empty() ? 0 : pieces_.back().t0; }

 private:
  struct Piece {
    double t0, angle0, rate0, accel;  // valid from t0 to the next piece
  };
  void truncate(double t);  // drops the plan after t and starts a piece at t
  /// The number of pieces starting at or before t (the index of the first
  /// after it), searched from `hint` on.
  [[nodiscard]] std::size_t count_until(double t, std::size_t hint) const;
  [[nodiscard]] State state_in(std::size_t count, double t) const;
  void push(double t0, double accel);
  double angle0_;
  std::vector<Piece> pieces_;
};

/// The table motion of a profile, in experiment time (t0 = 0, the table at
/// angle 0 at t0).
class TableTrajectory {
 public:
  explicit TableTrajectory(const Profile& profile);
  using State = TableMotion::State;
  [[nodiscard]] State at(double t) const { return motion_.at(t); }
  /// Times where the acceleration jumps (segment boundaries), ascending.
  [[nodiscard]] std::vector<double> breakpoints() const { return motion_.breakpoints(); }
  /// Start and end time of turn i.
  [[nodiscard]] double turn_start(std::size_t i) const { return moves_[i].t_start; }
  [[nodiscard]] double turn_end(std::size_t i) const { return moves_[i].t_end; }
  [[nodiscard]] double peak_rate(std::size_t i) const { return moves_[i].peak_rate; }
  [[nodiscard]] std::size_t turns() const { return moves_.size(); }
  /// The profile's run length from t0, s.
  [[nodiscard]] double duration() const { return duration_; }
  [[nodiscard]] const TableMotion& motion() const { return motion_; }

 private:
  TableMotion motion_;
  std::vector<TableMotion::Move> moves_;
  double duration_ = 0;
};

}  // namespace turncal
