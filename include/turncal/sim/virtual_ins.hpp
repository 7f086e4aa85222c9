// The virtual stand's INS (can-icd.md, INS node): idle -> aligning ->
// navigating on INS_Command, in the stand's simulated time (seconds). When
// the alignment ends, the nonlinear strapdown simulation starts from it
// (level from its accelerometers, heading as commanded plus the injected
// error) over the table's commanded motion; while navigating it yields
// velocity samples at its output rate. An injected fault puts it in fault
// mode. No frames here: the stand maps it onto the DBC.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "turncal/icd.hpp"
#include "turncal/physics/profile.hpp"
#include "turncal/physics/strapdown.hpp"

namespace turncal::stand {

using turncal::InsCommandCode;
using turncal::InsMode;

struct InsCommand {
  InsCommandCode code;
  double align_duration_s = 120;
  double heading_rad = 0;  ///< heading of axis z2, clockwise from North
  std::uint8_t seq = 0;
};

struct InsSetup {
  /// Site, injected errors, noise and rates; its profile, psi_start_rad,
  /// motion and heading fields are set by the INS itself.
  sim::Config sim;
  /// Mounting: psi = table angle - heading_offset (can-icd.md).
  double heading_offset_rad = 0;
  double fault_at_s = NAN;  ///< injected fault (mode 3) at this stand time
};

/// A velocity sample in stand time.
struct InsVelocity {
  double t_s;  ///< stand time
  double ve;
  double vn;
};

class VirtualIns {
 public:
  /// `table` must outlive the INS.
  VirtualIns(const InsSetup& setup, const TableMotion& table);
  /// Returns false for a command it refuses (unknown code, zero alignment).
  bool command(double t, const InsCommand& cmd);
  /// Runs up to t; velocity samples due by then are appended to `out`.
  void advance(double t, std::vector<InsVelocity>& out);
  [[nodiscard]] InsMode mode() const { return mode_; }
  /// Alignment time left at t, s (0 unless aligning).
  [[nodiscard]] double align_remaining(double t) const;
  /// Stand time of t0 (end of alignment); NaN before.
  [[nodiscard]] double t0() const { return t0_; }

 private:
  InsSetup setup_;
  const TableMotion& table_;
  InsMode mode_ = InsMode::Idle;
  double align_end_ = NAN;
  double align_s_ = 0;
  double heading_ = 0;
  double t0_ = NAN;
  std::unique_ptr<sim::Strapdown> nav_;
  long out_every_ = 4;  // IMU periods per output sample
  long steps_ = 0;
};

}  // namespace turncal::stand
