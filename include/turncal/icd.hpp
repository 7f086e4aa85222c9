// The codes of the reference stand's frames (can-icd.md), one definition
// for the host (the sequencer) and the virtual stand alike.
#pragma once

#include <cstdint>

namespace turncal {

/// TBL_Status.State
enum class TableState : std::uint8_t {
  Disabled = 0,
  Holding = 1,
  Moving = 2,
  InPosition = 3,
  Fault = 4,
  QuickStopped = 5,
};

/// A table rate below this, rad/s (0.057 deg/s), is a table at rest.
inline constexpr double kTableAtRestRps = 1e-3;
/// The coarsest table position a rest test takes, counts per table turn:
/// two counts of dither over a second read under kTableAtRestRps.
inline constexpr double kMinCountsPerTableTurn = 16384;
/// A CiA 402 table's rate and rest come from its TPDO1 positions: their
/// period may be at most half the drive's heartbeat timeout (which bounds
/// how old a position may be), or both are unknown between two.
[[nodiscard]] inline bool tpdo_period_fits(double period_s, double drive_heartbeat_timeout_s) {
  return period_s > 0 && period_s <= drive_heartbeat_timeout_s / 2 + 1e-12;
}

/// TBL_Command.Command
enum class TableCommandCode : std::uint8_t {
  ControlledStop = 0,
  MoveAbsolute = 1,
  MoveRelative = 2,
  QuickStop = 3,
  Enable = 4,
  Disable = 5,
};

/// INS_Status.Mode
enum class InsMode : std::uint8_t { Idle = 0, Aligning = 1, Navigating = 2, Fault = 3 };

/// INS_Command.Command
enum class InsCommandCode : std::uint8_t { StartAlignment = 1, GoIdle = 2 };

}  // namespace turncal
