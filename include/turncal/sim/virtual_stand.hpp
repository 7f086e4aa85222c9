// The virtual stand (can-icd.md): the virtual INS and table as CAN nodes of
// the configured DBC and roles, on two device clocks, with stand-level
// faults. Pure and deterministic: it is fed host frames with their stand
// time and emits its own frames in time order; turncal-sim puts it on
// SocketCAN (live, at any speed) or straight into a log (offline).
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <random>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/config.hpp"
#include "turncal/sim/virtual_drive402.hpp"
#include "turncal/sim/virtual_ins.hpp"
#include "turncal/sim/virtual_table.hpp"

namespace turncal::stand {

/// A device clock on the stand's simulated time: reads
/// offset + (1 + rate_ppm 1e-6) t, plus `jump_s` from `jump_at_s` on.
struct DeviceClock {
  double offset_s = 0;
  double rate_ppm = 0;
  double jump_at_s = NAN;
  double jump_s = 0;
  [[nodiscard]] double read(double t) const {
    return offset_s + (1 + rate_ppm * 1e-6) * t + (t >= jump_at_s ? jump_s : 0.0);
  }
  /// The ICD's time tag: microseconds, wrapping every 2^32.
  [[nodiscard]] std::uint32_t tag(double t) const;
  /// A time signal's value at t in its DBC unit, wrapping as the signal does.
  [[nodiscard]] double tag_value(double t, const TimeScale& scale, double factor) const;
};

/// Faults of the stand as a whole (the devices' own are in their setups).
struct StandFaults {
  double ins_drop_rate = 0;     ///< fraction of INS velocity frames dropped at random
  double ins_spike_rate = 0;    ///< fraction of INS velocity frames sent as 2000 m/s
  double ins_burst_at_s = NAN;  ///< every INS frame dropped in [at, at + length)
  double ins_burst_s = 0;
  double ins_silent_at_s = NAN;      ///< the INS sends nothing from then on
  double encoder_silent_at_s = NAN;  ///< no TBL_Encoder from then on
  /// The same two, this long after the table first turns (a fault in a
  /// turn whatever the host's start took); the earlier of the two times
  /// holds.
  double ins_silent_after_turn_s = NAN;
  double encoder_silent_after_turn_s = NAN;
  double garbage_rate_hz = 0;  ///< frames of a known ID with a wrong length, and of unknown IDs
  double flood_at_s = NAN;     ///< a flood of frames of an unknown ID
  double flood_s = 0;
  double flood_rate_hz = 5000;
};

struct StandSetup {
  InsSetup ins;
  TableLimits table_limits;
  TableFaults table_faults;
  double table_angle0_rad = 0;
  DeviceClock ins_clock;
  DeviceClock table_clock;
  StandFaults faults;
  /// The INS's output layout ([ins]): one frame or two, the signs, where
  /// the time is.
  InsLayout ins_layout;
  double ins_status_hz = 10;
  double encoder_hz = 200;
  double table_status_hz = 20;
  std::uint64_t seed = 1;  ///< for drops and garbage
  /// The table is a CiA 402 drive ([table] protocol = "cia402"): the INS
  /// turns with the drive's motion, the table side's frames are the
  /// drive's (CANopen), stepped at encoder_hz; the reference table, its
  /// limits and faults are not used.
  bool cia402 = false;
  Drive402Setup drive;  ///< its angle at power-on is table_angle0_rad
  Drive402Faults drive_faults;
};

struct StandFrame {
  double t_s;     ///< stand time it is sent
  bool ins_side;  ///< from the INS (else the table side)
  can::Frame frame;
};

struct StandCounts {
  std::uint64_t host_frames = 0;
  std::uint64_t host_undecodable = 0;  ///< unknown ID or wrong length: counted, skipped
  std::uint64_t ins_commands = 0;
  std::uint64_t table_commands = 0;
  std::uint64_t quick_stops = 0;  ///< table commands that were a quick stop
  std::uint64_t refused = 0;
  std::uint64_t heartbeats = 0;
  std::uint64_t dropped = 0;  ///< by the injected drop faults
};

class VirtualStand {
 public:
  /// `db` and `roles` must outlive the stand.
  VirtualStand(const StandSetup& setup, const can::Database& db, const RoleMap& roles);
  /// Emits, in time order, every frame due in (last t, t].
  void advance(double t, std::vector<StandFrame>& out);
  /// A frame from the host, received at stand time t (>= the last advance).
  void receive(double t, const can::Frame& frame);
  [[nodiscard]] const VirtualTable& table() const { return table_; }
  [[nodiscard]] const VirtualIns& ins() const { return ins_; }
  /// The CiA 402 drive, when the stand has one (else nullptr).
  [[nodiscard]] const VirtualDrive402* drive() const { return drive_ ? &*drive_ : nullptr; }
  [[nodiscard]] VirtualDrive402* drive() { return drive_ ? &*drive_ : nullptr; }
  [[nodiscard]] const StandCounts& counts() const { return counts_; }

 private:
  void emit_ins_status(double t, std::vector<StandFrame>& out);
  void emit_velocity(const InsVelocity& v, std::vector<StandFrame>& out);
  void emit_encoder(double t, std::vector<StandFrame>& out);
  void emit_table_status(double t, std::vector<StandFrame>& out);
  void emit_garbage(double t, std::vector<StandFrame>& out);
  can::Frame encode(Role any_role_of_message, std::span<const std::pair<Role, double>> values);
  [[nodiscard]] bool ins_quiet(double t) const;
  /// Sets the faults timed from the first turn once the table turns at t.
  void note_turn(double t);
  /// The INS clock's value at t for a time role, in its signal's unit (0: none).
  [[nodiscard]] double ins_tag(Role r, double t) const;
  [[nodiscard]] double role_value(Role r, std::span<const double> values) const;

  StandSetup setup_;
  const can::Database& db_;
  const RoleMap& roles_;
  can::FrameCodec codec_;
  VirtualTable table_;
  std::optional<VirtualDrive402> drive_;  // before ins_: the INS turns with its motion
  std::vector<DriveFrame> drive_out_;     // the drive's frames not yet emitted
  VirtualIns ins_;
  std::mt19937_64 rng_;
  double now_ = 0;
  bool turned_ = false;  // the table has turned
  long ins_status_k_ = 0, encoder_k_ = 0, table_status_k_ = 0, garbage_k_ = 0, flood_k_ = 0;
  std::uint8_t ins_counter_ = 0;
  std::vector<InsVelocity> vel_;
  std::vector<double> scratch_;
  StandCounts counts_;
};

}  // namespace turncal::stand
