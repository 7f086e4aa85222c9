// The virtual stand's turntable (can-icd.md, turntable node): a state
// machine over decoded commands, in the stand's simulated time (seconds).
// It enables and disables, moves absolute and relative within rate,
// acceleration and soft angle limits, stops under control or quickly,
// acknowledges accepted commands by Seq, refuses what breaks a limit, and
// quick-stops by itself when the host heartbeat stops while it moves.
// Faults can be injected. No frames here: the stand maps it onto the DBC.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>

#include "turncal/icd.hpp"
#include "turncal/physics/profile.hpp"

namespace turncal::stand {

using turncal::TableCommandCode;
using turncal::TableState;

/// TBL_Status.Fault (the ICD fixes 1; the rest are the virtual table's).
enum class TableFault : std::uint8_t {
  None = 0,
  HeartbeatLost = 1,  ///< quick-stopped: no heartbeat for the timeout while moving
  Stall = 2,          ///< the drive stopped short of the target
  Drive = 3,          ///< a drive fault (injected)
  Refused = 4,        ///< the last command was refused (limit, state or unknown code)
};

struct TableLimits {
  double max_rate_rps = 30 * 0.017453292519943295;
  double max_accel_rps2 = 30 * 0.017453292519943295;
  double quick_decel_rps2 = 180 * 0.017453292519943295;             ///< quick stop deceleration
  double angle_min_rad = -std::numeric_limits<double>::infinity();  ///< soft limits, multi-turn
  double angle_max_rad = std::numeric_limits<double>::infinity();
  double heartbeat_timeout_s = 0.5;
};

/// Faults to inject, each at most once.
struct TableFaults {
  double stall_after_s = NAN;     ///< stall this long into the next move (decelerates, Fault 2)
  double overshoot_rad = 0;       ///< every move passes its target by this much, then comes back
  double drive_fault_at_s = NAN;  ///< stand time of a drive fault (quick stop, Fault 3)
  double off_target_rad =
      0;  ///< every move ends this much past (< 0: short of) its target, "in position"
  /// Once, at this stand time, the table at rest turns by drift_rad at 1 deg/s
  /// by itself (a slipping brake) and still reports holding.
  double drift_at_s = NAN;
  double drift_rad = 0;
};

struct TableCommand {
  TableCommandCode code;
  std::uint8_t seq = 0;
  double target_rad = 0;      ///< move absolute: angle; move relative: by this much
  double rate_limit_rps = 0;  ///< moves: rate limit, > 0, at most the table's
};

struct TableStatus {
  TableState state;
  std::uint8_t ack_seq;
  TableFault fault;
  double rate_rps;
};

class VirtualTable {
 public:
  explicit VirtualTable(const TableLimits& limits = {}, double angle0_rad = 0,
                        const TableFaults& faults = {});
  /// Handles a command received at t (after advance(t)). Returns false if
  /// it was refused.
  bool command(double t, const TableCommand& cmd);
  void heartbeat(double t);
  /// Runs the table's own events up to t: moves ending, the heartbeat
  /// watchdog, injected faults. Call with non-decreasing t.
  void advance(double t);
  [[nodiscard]] TableStatus status(double t) const;
  /// True multi-turn angle, rad (the encoder reads it).
  [[nodiscard]] double angle(double t) const { return motion_.at(t).angle; }
  [[nodiscard]] const TableMotion& motion() const { return motion_; }

 private:
  bool refuse();
  void accept(std::uint8_t seq);
  bool start_move(double t, double delta, double rate);
  void halt(double t, double decel, TableState then, TableFault why);

  TableLimits lim_;
  TableFaults faults_;
  TableMotion motion_;
  TableState state_ = TableState::Disabled;
  TableState after_rest_ = TableState::Disabled;  // the state once a stop comes to rest
  double rest_at_ = 0;                            // end of the current move or stop
  std::uint8_t ack_ = 0;
  TableFault fault_ = TableFault::None;
  double last_heartbeat_ = -std::numeric_limits<double>::infinity();
  double move_started_ = 0;
  double stall_at_ = NAN;
  double now_ = -std::numeric_limits<double>::infinity();
};

}  // namespace turncal::stand
