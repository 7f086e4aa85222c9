// A CANopen master for one CiA 402 servo drive, pure (style.md, 2 and 7):
// frames in, frames out, time injected as seconds; every timeout comes from
// tick(now_s), nothing blocks. What belongs to the mode of operation (its
// objects, what is read back, the moves and their handshake) sits behind
// OperationMode; the state machine, the fault latch and its reset, NMT,
// SDO, the heartbeats and the encoder are the master's, shared by every
// mode. Profile position (drivers/table/cia402_profile_position.cpp) is
// the one a stand uses today.
//
// What it does, in order:
//   NMT reset communication -> the drive's boot-up (0x700+node, 0x00) ->
//   NMT enter pre-operational -> configuration by SDO (0x6060 = the mode,
//   the mode's objects (profile position: 0x6081), 0x6083,
//   0x6084, 0x6085, 0x605A, 0x605B, 0x605C, 0x6007, 0x1016:01, 0x1017, then
//   the PDO mappings 0x1600 / 0x1A00 [/ 0x1A01] when the settings ask; then
//   the mode's objects read back (profile position: 0x60F2, if it has it),
//   and 0x6061 read
//   until the drive shows the mode) -> NMT start.
//
// Moves (profile position) are absolute targets; a relative move's is
// computed from the position the master tracks, so that nothing depends on
// 0x60F2 (positioning option code: optional in CiA 402, its relative
// option's default differs between drives). Where the drive has it, it is
// read, never written, and refused only when it would move the table
// otherwise than planned (its request-response or rotary axis options).
// From then on RPDO1 (controlword + target position) goes out, TPDO1
// (statusword + position actual) and, when asked, TPDO2 (velocity actual)
// come in, the drive's heartbeat is watched, its EMCYs are decoded and
// kept, and the master produces its own heartbeat (and SYNC when asked)
// from tick().
//
// The sequencer's table (include/turncal/icd.hpp) is what status() shows:
//
//   CiA 402 state (statusword)        | TableState
//   ----------------------------------+-----------------------------------------
//   not configured / NMT not started  | Disabled
//   Not ready to switch on,           | Disabled
//   Switch on disabled, Ready to      |
//   switch on, Switched on            |   (QuickStopped after our quick stop)
//   Operation enabled, no move yet    | Holding
//   Operation enabled, set-point      | Moving (until target reached, bit 10)
//   acknowledged (bit 12), or halted  |
//   and still decelerating            |
//   Operation enabled, target reached | InPosition
//   Quick stop active                 | QuickStopped
//   Fault reaction active, Fault      | Fault
//   any, with a latched fault (EMCY   | Fault, until an Enable's fault reset is
//   of a fault's code, a warning's    | followed by a statusword without fault
//   whose statusword read after it    |
//   shows a fault, heartbeat lost,    |
//   following error, SDO abort during |
//   configuration, ...)               |
//
// The acknowledgement (status().ack) is the seq of the last command the
// drive accepted: Enable when Operation enabled is reached, Disable when
// Ready to switch on (or Switch on disabled) is, a move when the drive
// acknowledges its set-point (statusword bit 12; bit 4 is held until then,
// and a fault latches after set_point_timeout_s), ControlledStop at the
// first statusword after the halt bit went out, QuickStop at a statusword
// received after it that shows Quick stop active, Fault or not enabled (an
// EMCY is no proof: many only warn), or, outside Running, on the drive's
// answer to the SDO write of 0x6040 (refused while the drive boots).
// Disable is Shutdown (transition 8: the drive stops on its ramp), refused
// while a move is under way; Quick stop active is left (transition 12)
// only once the quick stop is complete (bit 10, or the table at rest by
// its positions: not every drive sets bit 10 there).
//
// The stale-PDO trap: a drive in fault may keep (or stop sending) a last
// TPDO that says Operation enabled. The master judges by the freshest
// information: an EMCY of a fault's code (a warning's: the statusword read
// by SDO after it, at once and 0.1 s later), the drive's heartbeat lost, or
// its NMT state leaving operational latches a fault whatever the last
// statusword said, and only Switch on disabled (transition 15), in a
// statusword received after the fault reset that an Enable sends, can
// clear it. The reset is a rising edge of bit 7 in an overwrite buffer the
// drive samples once a cycle: 0x0000 first, 0x0080 at the next statusword.
// After a lost heartbeat (or a drive that left operational or rebooted)
// the Enable first resets the drive's communication (NMT) and configures
// it again; a drive whose first statusword then shows no fault is not
// reset at all (the fault was the bus's, and 0x0000 would let it coast).
//
// Wiring (the daemon, the replay, a test):
//   auto m = Master::create(settings);           // an error names the misfit
//   m->start(now_s, out);                         // send `out`
//   every frame of the table's bus: m->on_frame(frame, t_s, out), and the
//     echoes of our own SYNC and NMT frames, in the order the bus had them;
//   the main loop, at least every heartbeat period: m->tick(now_s, out);
//   a sequencer TableCommand: m->command(code, seq, target_rad, rate_rps,
//     now_s, out) -- an error means nothing was sent;
//   after each: m->take_samples(samples) -> EncoderEvents (t_s, angle_rad),
//     and m->status() -> a TableStatusEvent when it changed
//     (state, ack, int(fault), fault_name, rate_rps).
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/can/frame.hpp"
#include "turncal/drivers/canopen.hpp"
#include "turncal/icd.hpp"
#include "turncal/result.hpp"

namespace turncal::cia402 {

// ---- CiA 402 objects ----
namespace obj {
inline constexpr std::uint16_t kAbortConnectionOption = 0x6007;
inline constexpr std::uint16_t kErrorCode = 0x603F;
inline constexpr std::uint16_t kControlword = 0x6040;
inline constexpr std::uint16_t kStatusword = 0x6041;
inline constexpr std::uint16_t kQuickStopOption = 0x605A;
inline constexpr std::uint16_t kShutdownOption = 0x605B;
inline constexpr std::uint16_t kDisableOperationOption = 0x605C;
inline constexpr std::uint16_t kModesOfOperation = 0x6060;
inline constexpr std::uint16_t kModesDisplay = 0x6061;
inline constexpr std::uint16_t kPositionActual = 0x6064;
inline constexpr std::uint16_t kVelocityActual = 0x606C;
inline constexpr std::uint16_t kTargetPosition = 0x607A;
inline constexpr std::uint16_t kMaxProfileVelocity = 0x607F;
inline constexpr std::uint16_t kProfileVelocity = 0x6081;
inline constexpr std::uint16_t kProfileAcceleration = 0x6083;
inline constexpr std::uint16_t kProfileDeceleration = 0x6084;
inline constexpr std::uint16_t kQuickStopDeceleration = 0x6085;
inline constexpr std::uint16_t kPositioningOption = 0x60F2;
inline constexpr std::uint16_t kDeviceName = 0x1008;
inline constexpr std::uint16_t kConsumerHeartbeat = 0x1016;
inline constexpr std::uint16_t kProducerHeartbeat = 0x1017;
inline constexpr std::uint16_t kRpdo1Comm = 0x1400;
inline constexpr std::uint16_t kRpdo1Map = 0x1600;
inline constexpr std::uint16_t kTpdo1Comm = 0x1800;
inline constexpr std::uint16_t kTpdo1Map = 0x1A00;
inline constexpr std::uint16_t kTpdo2Comm = 0x1801;
inline constexpr std::uint16_t kTpdo2Map = 0x1A01;
}  // namespace obj
/// A name for the objects above ("profile velocity"), nullptr for others.
[[nodiscard]] const char* object_name(std::uint16_t index);

/// Statusword 0x6041 bits.
namespace sw {
inline constexpr std::uint16_t kReadyToSwitchOn = 1u << 0;
inline constexpr std::uint16_t kSwitchedOn = 1u << 1;
inline constexpr std::uint16_t kOperationEnabled = 1u << 2;
inline constexpr std::uint16_t kFault = 1u << 3;
inline constexpr std::uint16_t kVoltageEnabled = 1u << 4;
inline constexpr std::uint16_t kQuickStop = 1u << 5;  ///< 0: quick stop active
inline constexpr std::uint16_t kSwitchOnDisabled = 1u << 6;
inline constexpr std::uint16_t kWarning = 1u << 7;
inline constexpr std::uint16_t kRemote = 1u << 9;
inline constexpr std::uint16_t kTargetReached = 1u << 10;
inline constexpr std::uint16_t kInternalLimit = 1u << 11;
inline constexpr std::uint16_t kSetPointAcknowledge = 1u << 12;  ///< profile position
inline constexpr std::uint16_t kFollowingError = 1u << 13;       ///< profile position
}  // namespace sw

/// Controlword 0x6040 bits and the standard's commands.
namespace cw {
inline constexpr std::uint16_t kSwitchOn = 1u << 0;
inline constexpr std::uint16_t kEnableVoltage = 1u << 1;
inline constexpr std::uint16_t kQuickStop = 1u << 2;  ///< 0: quick stop
inline constexpr std::uint16_t kEnableOperation = 1u << 3;
inline constexpr std::uint16_t kNewSetPoint = 1u << 4;        ///< profile position
inline constexpr std::uint16_t kChangeImmediately = 1u << 5;  ///< profile position
inline constexpr std::uint16_t kRelative = 1u << 6;           ///< profile position
inline constexpr std::uint16_t kFaultReset = 1u << 7;
inline constexpr std::uint16_t kHalt = 1u << 8;
/// The low byte of the standard's device control commands.
inline constexpr std::uint16_t kCmdShutdown = 0x06;
inline constexpr std::uint16_t kCmdSwitchOn = 0x07;
inline constexpr std::uint16_t kCmdDisableOperation = 0x07;
inline constexpr std::uint16_t kCmdEnableOperation = 0x0F;
inline constexpr std::uint16_t kCmdDisableVoltage = 0x00;
inline constexpr std::uint16_t kCmdQuickStop = 0x02;
inline constexpr std::uint16_t kCmdFaultReset = 0x80;
/// The bits a device control command occupies (0..3 and 7).
inline constexpr std::uint16_t kCommandMask = 0x8F;
}  // namespace cw

/// The drive's states (CiA 402 figure "state machine").
enum class State : std::uint8_t {
  NotReadyToSwitchOn,
  SwitchOnDisabled,
  ReadyToSwitchOn,
  SwitchedOn,
  OperationEnabled,
  QuickStopActive,
  FaultReactionActive,
  Fault,
  Unknown,  ///< a statusword matching no state
};
const char* to_string(State s);
/// The state a statusword shows (masks 0x4F and 0x6F, CiA 402 table).
[[nodiscard]] State decode_state(std::uint16_t statusword);
/// The state's bits (the 0x6F part) as a drive sets them.
[[nodiscard]] std::uint16_t state_bits(State s);

/// A controlword's device control command, as the drive decodes it
/// (CiA 402 table "command coding"); the fault reset is a rising edge of
/// bit 7, so the previous controlword is needed.
enum class Command : std::uint8_t {
  Shutdown,
  SwitchOn,  ///< also "disable operation" from Operation enabled
  EnableOperation,
  DisableVoltage,
  QuickStop,
  FaultReset,
  None,  ///< bit 7 held high: no command
};
const char* to_string(Command c);
[[nodiscard]] Command decode_command(std::uint16_t controlword, std::uint16_t previous);

// ---- PDO layouts ----

/// Where one object sits in a PDO: a byte offset and a length in bytes
/// (0: not in the PDO). CANopen PDOs carry objects little-endian.
struct PdoField {
  std::uint8_t offset = 0;
  std::uint8_t length = 0;
  [[nodiscard]] bool present() const { return length != 0; }
};

/// RPDO1: what the master sends.
struct RpdoLayout {
  std::uint32_t cob_id = 0;  ///< 11-bit identifier
  std::uint8_t size = 6;     ///< payload bytes
  PdoField controlword{0, 2};
  PdoField target_position{2, 4};
  /// CiA 402's: 0x200 + node, controlword u16 then target position s32.
  [[nodiscard]] static RpdoLayout defaults(std::uint8_t node);
  /// From the stand's DBC: the message's ID and length, and where the named
  /// signals are. They must be little-endian, byte aligned, unscaled, of
  /// the object's size (16 and 32 bits).
  [[nodiscard]] static Result<RpdoLayout> from_dbc(const can::Message& msg,
                                                   std::string_view controlword,
                                                   std::string_view target_position);
  /// Fields inside the payload, not overlapping, of the objects' sizes.
  [[nodiscard]] Status check() const;
  /// The mapping entries (index << 16 | sub << 8 | bits), by offset; an
  /// error when the fields leave gaps (a mapping cannot say that).
  [[nodiscard]] Result<std::vector<std::uint32_t>> mapping() const;
};

/// TPDO1: what the drive sends. Velocity actual (s32) does not fit beside
/// the statusword and position actual in 8 bytes: it goes in TPDO2
/// (VelocityPdoLayout) when the settings ask.
struct TpdoLayout {
  std::uint32_t cob_id = 0;
  std::uint8_t size = 6;
  PdoField statusword{0, 2};
  PdoField position_actual{2, 4};
  /// 0x180 + node, statusword u16 then position actual s32.
  [[nodiscard]] static TpdoLayout defaults(std::uint8_t node);
  /// From the DBC, as RpdoLayout::from_dbc.
  [[nodiscard]] static Result<TpdoLayout> from_dbc(const can::Message& msg,
                                                   std::string_view statusword,
                                                   std::string_view position_actual);
  [[nodiscard]] Status check() const;
  [[nodiscard]] Result<std::vector<std::uint32_t>> mapping() const;
};

/// TPDO2, optional: velocity actual (0x606C, s32).
struct VelocityPdoLayout {
  std::uint32_t cob_id = 0;
  std::uint8_t size = 4;
  PdoField velocity_actual{0, 4};
  /// 0x280 + node, velocity actual s32.
  [[nodiscard]] static VelocityPdoLayout defaults(std::uint8_t node);
  [[nodiscard]] static Result<VelocityPdoLayout> from_dbc(const can::Message& msg,
                                                          std::string_view velocity_actual);
  [[nodiscard]] Status check() const;
  [[nodiscard]] Result<std::vector<std::uint32_t>> mapping() const;
};

// ---- the master ----

/// The EMCY codes that warn by default. CiA 301's table 21 groups codes by
/// subject, not into warnings and faults, and a drive's manual says which
/// of its own only warn (temperature codes are trips on some drives,
/// warnings on others): by default only the CAN controller's reports of
/// the bus, which say nothing of the drive's power stage and which the
/// frames that follow tell better: overrun (0x8110), error passive
/// (0x8120), recovered from bus off (0x8140). Every other code is a fault
/// until the stand's configuration lists it (table.cia402.emcy_warnings).
inline const std::vector<std::pair<std::uint16_t, std::uint16_t>> kDefaultEmcyWarnings = {
    {0x8110, 0x8110}, {0x8120, 0x8120}, {0x8140, 0x8140}};

/// Whether an EMCY code only warns, by these ranges.
[[nodiscard]] bool emcy_warns(std::uint16_t code,
                              const std::vector<std::pair<std::uint16_t, std::uint16_t>>& warnings);

struct MasterSettings {
  std::uint8_t node_id = 1;         ///< the drive's
  std::uint8_t host_node_id = 127;  ///< ours, for our heartbeat (0x700 + host)
  double host_heartbeat_period_s = 0.1;
  /// The drive watches our heartbeat (0x1016:01) with this timeout.
  double host_heartbeat_timeout_s = 0.5;
  /// The drive's own heartbeat (0x1017), and how long we wait for it.
  double drive_heartbeat_period_s = 0.1;
  double drive_heartbeat_timeout_s = 0.3;
  double sdo_timeout_s = 0.5;
  double boot_timeout_s = 2.0;  ///< from NMT reset to the boot-up message
  /// Scale: encoder counts per motor revolution, motor turns per table turn.
  double counts_per_rev = 131072;
  double gear_ratio = 1;
  /// The drive's counts rise clockwise seen from above: positions, targets
  /// and velocities are negated between the drive and the table angle
  /// (counter-clockwise).
  bool counts_clockwise = false;
  /// The profile written at configuration, table rad/s and rad/s^2.
  double profile_velocity_rps = 10 * 0.017453292519943295;
  double profile_acceleration_rps2 = 10 * 0.017453292519943295;
  double profile_deceleration_rps2 = 10 * 0.017453292519943295;
  double quick_stop_deceleration_rps2 = 90 * 0.017453292519943295;
  /// 0x605A: 6 = stop on the quick stop ramp and stay in Quick stop active.
  std::int16_t quick_stop_option = 6;
  /// 0x6007 on a lost host heartbeat: 1 fault, 2 disable voltage, 3 quick stop.
  std::int16_t abort_connection_option = 3;
  /// EMCY codes that only warn (ranges, both ends in): told as a notice,
  /// the run goes on. Any other code is a fault. The statusword's fault bit
  /// is a fault whatever the EMCY before it said.
  std::vector<std::pair<std::uint16_t, std::uint16_t>> emcy_warnings = kDefaultEmcyWarnings;
  /// Controlword bit 5 with every set-point.
  bool change_set_immediately = false;
  /// Write the PDO mappings (0x1600, 0x1A00) and TPDO1's transmission;
  /// otherwise the drive's own mapping must be the layouts below.
  bool configure_mapping = false;
  /// The layouts; empty: CiA 402's defaults for node_id (velocity not mapped).
  std::optional<RpdoLayout> rpdo;
  std::optional<TpdoLayout> tpdo;
  /// Velocity actual from TPDO2 (written with the mappings when
  /// configure_mapping): the table's rate in status() is then the drive's
  /// own; otherwise it comes from the position samples.
  bool velocity_pdo = false;
  std::optional<VelocityPdoLayout> tpdo2;  ///< empty: defaults for node_id
  /// > 0: we produce SYNC at this period, TPDO1 is synchronous (transmission
  /// type 1, written) and an encoder sample's time is its SYNC's.
  double sync_period_s = 0;
  /// TPDO1's event timer when the mapping is written without SYNC.
  double tpdo_event_timer_s = 0.01;
  /// A set-point (controlword bit 4, held) not acknowledged (statusword
  /// bit 12) within this latches a fault.
  double set_point_timeout_s = 0.5;
  /// A fault reset is a rising edge of bit 7 and RPDO1 an overwrite buffer
  /// the drive samples once a cycle: 0x0000 goes first and 0x0080 follows
  /// at the next statusword, or after this when none comes.
  double fault_reset_low_s = 0.05;
  /// How long 0x6061 may take to show the mode written to 0x6060.
  double mode_switch_timeout_s = 0.2;

  [[nodiscard]] double counts_per_rad() const {
    return counts_per_rev * gear_ratio / (2 * 3.14159265358979323846);
  }
  [[nodiscard]] RpdoLayout rpdo_layout() const {
    return rpdo ? *rpdo : RpdoLayout::defaults(node_id);
  }
  [[nodiscard]] TpdoLayout tpdo_layout() const {
    return tpdo ? *tpdo : TpdoLayout::defaults(node_id);
  }
  [[nodiscard]] VelocityPdoLayout velocity_layout() const {
    return tpdo2 ? *tpdo2 : VelocityPdoLayout::defaults(node_id);
  }
  /// Every value in range and every configured value fits its object
  /// (u32 counts/s and counts/s^2, u16 ms), or why not.
  [[nodiscard]] Status check() const;
};

/// Why the master is in fault (status().fault).
enum class FaultCode : std::uint8_t {
  None = 0,
  Emcy = 1,                ///< an EMCY of a fault (MasterSettings::emcy_warnings)
  DriveHeartbeatLost = 2,  ///< "drive heartbeat lost"
  DriveNmtState = 3,       ///< the drive left operational, or booted again
  FollowingError = 4,      ///< statusword bit 13
  DriveFault = 5,          ///< statusword Fault without an EMCY of a fault
  Configuration = 6,       ///< an SDO abort (or timeout) during configuration
  NoBootUp = 7,            ///< no boot-up message after the NMT reset
  Sdo = 8,                 ///< the SDO a move needed (profile velocity) failed
  SetPointTimeout = 9,     ///< no set-point acknowledge (bit 12) in time
  /// The drive left operation enabled, or quick-stopped, by itself while
  /// asked to stay enabled (safe torque off, another node's controlword).
  LeftEnabled = 10,
  /// The table turned when the drive was to be enabled (transition 4 would
  /// brake it at full torque).
  TurningAtEnable = 11,
};

/// What the sequencer's TableStatusEvent carries (icd.hpp, can-icd.md).
struct TableView {
  TableState state = TableState::Disabled;
  std::uint8_t ack = 0;  ///< seq of the last command the drive accepted
  FaultCode fault = FaultCode::None;
  std::string fault_name;
  /// The table's, from velocity actual (TPDO2) or else encoder steps;
  /// NaN: unknown, or older than the drive heartbeat timeout.
  double rate_rps = NAN;
};

/// One position actual from TPDO1, as a table angle.
struct EncoderSample {
  /// Its SYNC's time on our bus, the SYNC's echo's receive time (for a CAN
  /// driver with IFF_ECHO, when it left on the bus; else, as for vcan, when
  /// the kernel queued it to the device); without a SYNC, or with no SYNC
  /// of its own just before it (none since the last TPDO1 or a start, the
  /// last one more than half a period away, or its echo read after it),
  /// the TPDO's own receive time.
  double t_s = 0;
  /// The first TPDO1 since an NMT command: the SYNCs before it are no losses.
  static constexpr std::int64_t kRestarted = -2;
  /// With SYNC: the SYNCs since the last TPDO1 that none answered (a TPDO
  /// lost, or a drive that skipped a cycle; an answer more than half a
  /// period late counts its SYNC so), or kRestarted for the first TPDO1
  /// since a start; -1 without SYNC (sync_period_s 0): not counted.
  std::int64_t lost_before = -1;
  double angle_rad = 0;     ///< multi-turn (the drive's s32 unwrapped)
  std::int64_t counts = 0;  ///< the unwrapped position actual
  std::uint16_t statusword = 0;
};

/// Frames the master could not use (counted and skipped) and what it saw.
struct MasterCounts {
  std::uint64_t tpdo = 0;
  std::uint64_t velocity_pdo = 0;
  std::uint64_t emcy = 0;
  std::uint64_t emcy_warnings = 0;  ///< of them, codes that only warn (MasterSettings)
  std::uint64_t heartbeats = 0;
  std::uint64_t malformed = 0;  ///< a TPDO, EMCY, heartbeat or SYNC of a wrong length
  /// With SYNC: TPDO1s with no SYNC of their own within half a period
  /// before (dated by receipt; said in the notices)
  std::uint64_t tpdo_unsynced = 0;
  std::uint64_t nmt_resets = 0;          ///< reset communication sent
  std::uint64_t configurations = 0;      ///< configurations completed
  std::uint64_t unknown_nmt_states = 0;  ///< drive heartbeats with a state byte CiA 301 lacks
  std::uint64_t position_resets = 0;     ///< the position unwrap restarted (the drive rebooted)
  /// 0x605B/0x605C the drive does not have or refused the value 1: its
  /// shutdown may let go at once (turncal sends none while the table turns)
  std::uint64_t ramp_options_refused = 0;
};

// ---- the seam of a mode of operation ----

/// One SDO write of the drive's configuration.
struct ConfigWrite {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::vector<std::uint8_t> data;
  /// The drive may lack it (CiA 402 optional): a refusal is a notice, not
  /// a failed configuration.
  bool optional = false;
};

/// An object read back once the configuration is written, and the verdict
/// on its answer: empty when the drive keeps what the mode needs, otherwise
/// why not (the configuration fails with that text).
struct ConfigCheck {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::function<std::string(const canopen::SdoResult&)> verdict;
  /// The drive may lack it (CiA 402 optional): its answer that it does
  /// not exist is a notice, and the verdict is asked of that answer too;
  /// any other refusal fails the configuration.
  bool optional = false;
};

/// What a mode of operation may ask of the master it belongs to.
class ModeHost {
 public:
  /// The drive's SDO server (a mode's own objects, such as a move's rate).
  virtual canopen::SdoClient& mode_sdo() = 0;
  /// Latches a fault of the mode's (the first cause stays).
  virtual void mode_fault(FaultCode code, std::string name) = 0;
  /// Empty when the drive is enabled and free of faults for a move;
  /// otherwise why a move is refused.
  [[nodiscard]] virtual std::string why_no_move() const = 0;
  /// The unwrapped position actual, counts; empty before the first TPDO1.
  [[nodiscard]] virtual std::optional<std::int64_t> position_counts() const = 0;

 protected:
  virtual ~ModeHost() = default;
};

/// What the drive shows of the mode's handshake at one statusword.
struct ModeProgress {
  std::optional<std::uint8_t> acked;  ///< the seq of a move the drive accepted
  std::string fault;                  ///< not empty: the handshake timed out, why
};

/// The part of the master that is one mode of operation's (CiA 402 0x6060):
/// its configuration, what it reads back, its commands and its set-point
/// handshake. The state machine, the fault latch and its reset, NMT, SDO,
/// the heartbeats and the encoder are the master's, shared by every mode.
/// Profile position (cia402_profile_position.cpp) is the first; homing,
/// profile velocity and cyclic synchronous position are each one more.
class OperationMode {
 public:
  virtual ~OperationMode() = default;
  /// The value of 0x6060 written and of 0x6061 awaited.
  [[nodiscard]] virtual std::int8_t code() const = 0;
  [[nodiscard]] virtual const char* name() const = 0;
  /// The mode's writes, after 0x6060 and before the ramps and heartbeats.
  virtual void configuration(std::vector<ConfigWrite>& writes) const = 0;
  /// The configuration's last write is done: what the drive holds now.
  virtual void configured() = 0;
  /// What is read back after the configuration, in order, before 0x6061.
  [[nodiscard]] virtual std::vector<ConfigCheck> checks() const = 0;
  /// The statusword bit that is an error of the mode in operation enabled,
  /// and what it is called (profile position: bit 13, "following error").
  [[nodiscard]] virtual std::uint16_t error_bits() const = 0;
  [[nodiscard]] virtual const char* error_name() const = 0;

  /// No move any more (a communication reset, an Enable, a Disable, a
  /// quick stop).
  virtual void reset() = 0;
  /// The drive is no longer in operation enabled: a move under way ended.
  virtual void left_enabled() = 0;
  /// A move is asked, or under way.
  [[nodiscard]] virtual bool moving() const = 0;
  /// A sequencer move (MoveAbsolute: to target_rad; MoveRelative: by it).
  /// An error, and nothing sent or changed, when it cannot be made.
  virtual Status move(TableCommandCode code, std::uint8_t seq, double target_rad, double rate_rps,
                      double now_s, std::vector<can::Frame>& out) = 0;
  /// A controlled stop (controlword bit 8) began.
  virtual void halt() = 0;
  /// The handshake at a statusword in operation enabled; `fresh_after_halt`:
  /// received after the halt went out. `timeouts`: judged now (from tick()).
  virtual ModeProgress on_status(std::uint16_t word, std::uint64_t sw_seq, bool fresh_after_halt,
                                 double now_s, bool timeouts) = 0;
  /// The mode's controlword bits besides the halt (profile position: 5, 6).
  [[nodiscard]] virtual std::uint16_t controlword_bits() const = 0;
  /// The set-point bits for the next controlword in operation enabled;
  /// `starts`: this word begins a new set-point (set_point_sent follows).
  [[nodiscard]] virtual std::uint16_t set_point_bits(std::uint16_t word, bool& starts) const = 0;
  /// The target position the set-point carries in RPDO1.
  [[nodiscard]] virtual std::int32_t set_point_target() const = 0;
  virtual void set_point_sent(std::uint64_t sw_seq, double now_s) = 0;
  /// The table's state in operation enabled, without a fault.
  [[nodiscard]] virtual TableState enabled_state() const = 0;
  /// The caller's loop was held: what the mode awaits does not count it.
  virtual void held(double from_s, double to_s) = 0;
};

/// Profile position (0x6060 = 1), the mode a stand turns its table in.
[[nodiscard]] std::unique_ptr<OperationMode> make_profile_position(const MasterSettings& s,
                                                                   ModeHost& host);

/// The master's own progress through NMT and configuration.
enum class CommPhase : std::uint8_t {
  Idle,         ///< start() not called
  WaitBootUp,   ///< reset communication sent
  Configuring,  ///< SDOs under way
  Running,      ///< configured, NMT start sent
  Failed,       ///< configuration failed; an Enable starts again
};
const char* to_string(CommPhase p);

class Master final : private ModeHost {
 public:
  /// Settings that fail check() leave the master inert: start() latches a
  /// configuration fault with the reason and sends nothing, command()
  /// returns it (create() refuses them up front).
  explicit Master(MasterSettings s);
  /// Makes the master's mode of operation (profile position by default).
  using ModeFactory =
      std::function<std::unique_ptr<OperationMode>(const MasterSettings&, ModeHost&)>;
  /// A master in another mode of operation: `mode` is called once, here.
  Master(MasterSettings s, const ModeFactory& mode);
  [[nodiscard]] static Result<std::unique_ptr<Master>> create(MasterSettings s);
  Master(const Master&) = delete;
  Master& operator=(const Master&) = delete;

  /// Resets the drive's communication and goes through boot-up,
  /// configuration and start; the heartbeat (and SYNC) begin.
  void start(double now_s, std::vector<can::Frame>& out);
  /// Timeouts, our heartbeat and SYNC. Call often (at least every
  /// heartbeat period), with non-decreasing time.
  void tick(double now_s, std::vector<can::Frame>& out);
  /// The caller's loop was held from from_s to to_s (it did not run): the
  /// timeouts that wait on the drive (its heartbeat, boot-up, an SDO, the
  /// set-point's acknowledgement, the mode switch) do not count that time.
  void held(double from_s, double to_s);
  /// A frame from the bus at t_s. Frames of other nodes are ignored; ours
  /// of a wrong length are counted and skipped. A SYNC (ours, echoed, or
  /// another producer's) is the time of the TPDO1s that answer it: the
  /// time it was on the bus, not the time it was queued.
  void on_frame(const can::Frame& f, double t_s, std::vector<can::Frame>& out);

  /// A sequencer command. target_rad: MoveAbsolute's angle, MoveRelative's
  /// delta; rate_rps: a move's profile velocity (written by SDO first when
  /// it differs from the last written). An error, and no frame, when it
  /// cannot be sent: a target or rate that does not fit the drive's s32/u32
  /// counts, a non-positive rate, a move while the drive is not enabled.
  Status command(TableCommandCode code, std::uint8_t seq, double target_rad, double rate_rps,
                 double now_s, std::vector<can::Frame>& out);

  [[nodiscard]] TableView status() const;
  /// The drive's 402 state as its last statusword showed it.
  [[nodiscard]] State drive_state() const { return state_; }
  [[nodiscard]] std::optional<std::uint16_t> statusword() const { return sw_; }
  [[nodiscard]] CommPhase phase() const { return phase_; }
  /// When NMT start went out, while running; NaN otherwise.
  [[nodiscard]] double running_since_s() const {
    return phase_ == CommPhase::Running ? started_at_ : std::nan("");
  }
  /// When the last communication reset went out (the start-up began).
  [[nodiscard]] double starting_since_s() const { return starting_since_; }
  /// The longest a start-up can take before the master has given up on it
  /// by its own timeouts: the boot-up, each configuration step's SDO, the
  /// mode switch. The streams are due from then whatever it says.
  [[nodiscard]] double start_up_budget_s() const;
  /// True when the configuration wrote the PDO mappings.
  [[nodiscard]] bool configured_mapping() const { return configured_mapping_; }
  /// The EMCYs received, with their time and text: the first kEmcyKept,
  /// the last of them always the newest (counts().emcy counts them all).
  [[nodiscard]] const std::vector<canopen::Emcy>& emergencies() const { return emcy_; }
  static constexpr std::size_t kEmcyKept = 64;
  /// After an EMCY that only warns, the drive's statusword is read at once
  /// and again this much later, for a drive that sends its EMCY before its
  /// statusword shows the fault.
  static constexpr double kWarningRecheckS = 0.1;
  /// Reads whose state a later TPDO did not confirm, before a fault
  /// reset gives up.
  static constexpr int kConfirmReads = 20;
  /// What the operator should hear that is no fault (an optional object
  /// the drive refused), each once, in the order they came.
  [[nodiscard]] const std::vector<std::string>& notices() const { return notices_; }
  /// Moves the encoder samples received since the last call to `out`.
  void take_samples(std::vector<EncoderSample>& out);
  /// The last position actual, as a table angle (NaN before any).
  [[nodiscard]] double angle_rad() const { return angle_; }
  /// The last velocity actual (TPDO2) as a table rate, rad/s; NaN before any.
  [[nodiscard]] double velocity_rps() const { return velocity_; }
  [[nodiscard]] const MasterCounts& counts() const { return counts_; }
  [[nodiscard]] const canopen::SdoCounts& sdo_counts() const { return sdo_.counts(); }
  [[nodiscard]] const MasterSettings& settings() const { return s_; }

  /// Our heartbeat allowed or not (allowed unless said; it goes out from
  /// start() on). Off: the drive's consumer times out and it acts per
  /// 0x6007; a later start() or communication reset does not turn it on.
  void set_host_heartbeat(bool on) { host_hb_allowed_ = on; }
  /// Whether tick() sends our heartbeat (started, and allowed).
  [[nodiscard]] bool sends_host_heartbeat() const {
    return host_hb_on_ && host_hb_allowed_ && phase_ != CommPhase::Idle;
  }
  /// Any SDO access, queued behind the others; `done` gets its outcome.
  void read(std::uint16_t index, std::uint8_t sub, canopen::SdoClient::Callback done);
  void write(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
             canopen::SdoClient::Callback done);

 private:
  enum class Goal : std::uint8_t { Disabled, Enabled, QuickStop };
  /// The way out of a latched fault, started by Enable: AfterComm (a
  /// communication reset and reconfiguration first), SendReset (the
  /// statusword to be read), ReadStatus (0x6041 read by SDO, its answer
  /// awaited), Confirm (not in fault by that answer: a TPDO after it must
  /// show the same state before anything is sent), ResetLow (controlword
  /// 0x0000 sent, bit 7 low), WaitFresh (0x0080 sent, a statusword after it
  /// awaited).
  enum class Recovery : std::uint8_t {
    None,
    AfterComm,
    SendReset,
    ReadStatus,
    Confirm,
    ResetLow,
    WaitFresh
  };
  enum class AckOn : std::uint8_t { None, Enabled, Disabled, Stopped, Halted };

  // ModeHost
  canopen::SdoClient& mode_sdo() override { return sdo_; }
  void mode_fault(FaultCode code, std::string name) override { latch(code, std::move(name)); }
  [[nodiscard]] std::string why_no_move() const override;
  [[nodiscard]] std::optional<std::int64_t> position_counts() const override {
    return have_pos_ ? std::optional<std::int64_t>(pos_counts_) : std::nullopt;
  }

  void reset_comm(double now_s, std::vector<can::Frame>& out);
  void configure(double now_s, std::vector<can::Frame>& out);
  void config_done(double now_s, std::vector<can::Frame>& out);
  void config_failed(const canopen::SdoResult& r, const std::string& why);
  void notice(std::string text);
  /// A statusword read of a fault reset to be made again (`why`: what is
  /// said if this is one too many).
  void read_again(const std::string& why);
  static constexpr const char* kEmcysKeptComing = "EMCYs kept coming while its statusword was read";
  /// Where the drive's own configuration sends TPDO1 (the mapping not
  /// written, no SYNC): reads its transmission type and event timer back,
  /// which must fit the drive heartbeat timeout; then check_options.
  void check_tpdo(std::uint64_t gen);
  /// Reads back the mode's objects from the i-th on, then check_mode.
  void check_options(std::uint64_t gen, std::shared_ptr<const std::vector<ConfigCheck>> checks,
                     std::size_t i);
  /// Reads 0x6061 until it shows the mode written to 0x6060, then completes.
  void check_mode(std::uint64_t gen);
  void latch(FaultCode code, std::string name, bool needs_comm_reset = false);
  /// A fault reset under way ends, nothing more sent for it.
  void abandon_recovery();
  void on_tpdo(const can::Frame& f, double t_s, std::vector<can::Frame>& out);
  void on_heartbeat(const can::Frame& f, double t_s, std::vector<can::Frame>& out);
  void on_emcy(const can::Frame& f, double t_s);
  /// A quick stop complete: the table at rest, by bit 10 or by its positions.
  [[nodiscard]] bool quick_stop_done(std::uint16_t word) const;
  /// The drive's statusword read after an EMCY that only warns: in fault
  /// (its fault bit, the mode's error bits, or no state of CiA 402's), the
  /// EMCY is the fault; not read, taken for one.
  void warning_checked(const canopen::SdoResult& r, const std::string& emcy);
  /// Sends the read a warning asked for, when due (tick), one at a time.
  void read_after_warning(double now_s);
  /// Acks, the set-point handshake, the fault latch and the controlword
  /// towards the goal, from what is known now.
  /// `timeouts`: from tick() (the set-point's time judged only there,
  /// after the caller has said whether its loop was held).
  void evaluate(double now_s, std::vector<can::Frame>& out, bool timeouts = false);
  /// A fault reset's step (recovery_): false when evaluate() goes no further.
  bool recover(double now_s, std::vector<can::Frame>& out);
  /// The fault reset's statusword read answered (Recovery::ReadStatus).
  void on_status_read(double now_s, std::vector<can::Frame>& out);
  /// The acks the last statusword gives, and the mode's handshake; false
  /// when evaluate() goes no further.
  bool acknowledge(double now_s, std::vector<can::Frame>& out, bool timeouts);
  /// The controlword towards the goal (CiA 402 transitions); empty when
  /// nothing is to be sent (a fault latched on the way).
  std::optional<std::uint16_t> towards_goal(bool& set_point);
  Status enable(std::uint8_t seq, double now_s, std::vector<can::Frame>& out);
  Status disable(std::uint8_t seq);
  Status quick_stop(std::uint8_t seq, double now_s, std::vector<can::Frame>& out);
  Status controlled_stop(std::uint8_t seq, double now_s, std::vector<can::Frame>& out);
  void send_rpdo(std::uint16_t controlword, std::vector<can::Frame>& out);
  /// +1, or -1 when the drive counts clockwise: table angle = sense * counts / cpr.
  [[nodiscard]] double sense() const { return s_.counts_clockwise ? -1.0 : 1.0; }
  [[nodiscard]] std::uint16_t motion_bits() const;

  MasterSettings s_;
  std::string invalid_;  // why the settings fail check(); empty: they pass
  RpdoLayout rpdo_;
  TpdoLayout tpdo_;
  VelocityPdoLayout tpdo2_;
  double cpr_;  // counts per table rad
  canopen::SdoClient sdo_;
  CommPhase phase_ = CommPhase::Idle;
  double now_ = 0;
  double boot_deadline_ = 0;
  std::uint64_t config_generation_ = 0;
  bool configured_mapping_ = false;
  // heartbeats
  bool host_hb_on_ = false;
  bool host_hb_allowed_ = true;
  double next_host_hb_ = 0;
  double last_drive_hb_ = 0;
  double started_at_ = 0;  // NMT start sent
  /// Whether the table is at rest, from TPDO1's positions since the NMT
  /// start over at least kRestWindowS.
  struct Rest {
    enum State : std::uint8_t { Unknown, AtRest, Turning } state = Unknown;
    double rate_rps = NAN;
  };
  [[nodiscard]] Rest rest_since_running() const;
  static constexpr double kRestWindowS = 0.1;
  static constexpr double kRestDitherCounts = 2;
  double starting_since_ = 0;       // NMT reset communication sent
  std::uint64_t tpdo_running_ = 0;  // TPDO1s since then
  bool drive_seen_operational_ = false;
  double next_sync_ = 0;
  // TPDO1 against SYNC (on_sync, on_tpdo): which SYNC a TPDO1 answers;
  // forgotten (a new one) when the drive's stream starts over
  struct SyncPairing {
    double last = NAN;        // the last SYNC seen on the bus; NaN: none since a start
    bool answered = false;    // a TPDO1 was taken as its answer
    std::int64_t missed = 0;  // SYNCs before it that none answered
    bool restarted = true;    // no TPDO1 since a start: earlier SYNCs are no losses
    double ahead_t = NAN;     // a TPDO1 read before its SYNC's echo: its receipt
  };
  SyncPairing sync_;
  void on_sync(double t_s);
  // a TPDO1 answers a SYNC within this many SYNC periods after it
  // (turncal-sim's within 0.4; a real drive's within its cycle)
  static constexpr double kSyncAnswerWindow = 0.5;
  // a SYNC's echo read after its answer may be stamped this many periods
  // after that answer's receipt and still be its SYNC
  static constexpr double kEchoLateStamp = 0.1;
  // the drive
  std::optional<std::uint16_t> sw_;
  std::uint64_t sw_seq_ = 0;  // statuswords received
  State state_ = State::Unknown;
  std::uint16_t cw_ = 0;
  bool cw_sent_ = false;
  std::int32_t target_ = 0;
  // fault latch
  FaultCode fault_ = FaultCode::None;
  std::string fault_name_;
  std::string fault_base_;  // fault_name_ as latched, before what recovery added
  [[nodiscard]] const std::string& base_fault_name() const { return fault_base_; }
  /// Reads of a drive in fault reaction active before recovery gives up.
  static constexpr int kFaultReactionReads = 100;
  bool needs_comm_reset_ = false;
  Recovery recovery_ = Recovery::None;
  std::uint64_t reset_seq_ = 0;                    // sw_seq_ when the fault reset went out
  std::uint64_t status_read_gen_ = 0;              // the statusword read that counts
  std::optional<canopen::SdoResult> status_read_;  // its answer, for evaluate()
  double status_read_at_ = 0;                      // not before: a drive still in fault reaction
  std::uint64_t read_sw_seq_ = 0;                  // sw_seq_ when the read went out
  std::uint64_t emcy_errors_ = 0;      // EMCYs of a fault (a code that is no warning, or a warning
                                       // whose statusword read showed a fault or failed)
  std::uint64_t read_emcy_ = 0;        // emcy_errors_ then
  State read_state_ = State::Unknown;  // what the read said
  int fault_reaction_reads_ = 0;       // reads that found fault reaction active
  int confirm_reads_ = 0;              // reads a TPDO then disagreed with
  // sw_seq_ of the last statusword in operation enabled, and the count a
  // controlword other than enable operation went out after (the drive's
  // way out of operation enabled was then ours)
  std::uint64_t last_enabled_seq_ = 0;
  std::uint64_t other_cw_after_ = 0;
  // commands
  Goal goal_ = Goal::Disabled;
  bool quick_stopped_ = false;  // our quick stop is the last command
  std::uint8_t ack_ = 0;
  AckOn ack_on_ = AckOn::None;
  std::uint8_t ack_seq_ = 0;
  std::uint64_t ack_after_ = 0;  // a statusword after this one
  std::unique_ptr<OperationMode> mode_;
  std::uint64_t low_seq_ = 0;  // sw_seq_ when 0x0000 went out before a fault reset
  double low_t_ = 0;
  double mode_since_ = 0;  // the mode check began
  double mode_poll_at_ = INFINITY;
  int mode_read_ = 0;             // 0x6061 as last read, not yet the mode
  bool halted_ = false;           // controlword bit 8 (controlled stop)
  bool config_complete_ = false;  // the last configuration SDO is done
  bool drive_hb_lost_ = false;
  // encoder
  bool have_pos_ = false;
  std::int32_t last_raw_ = 0;
  std::int64_t pos_counts_ = 0;
  double angle_ = NAN;
  double last_sample_t_ = NAN;
  double last_tpdo_t_ = -1e300;
  double velocity_ = NAN;
  double velocity_t_ = -1e300;
  /// The table's rate from TPDO1's positions over a window (rate_win_),
  /// not from two samples.
  double rate_ = NAN;
  struct PosRef {
    double t = NAN;
    std::int64_t counts = 0;
  };
  /// TPDO1's positions over rate_window_s() to twice it, or over the
  /// period of TPDOs sent more rarely: two reference samples, the older
  /// one the base. It starts again after the drive's heartbeat timeout
  /// without a position.
  struct PosWindow {
    PosRef base, next;
    double last_t = NAN;
  };
  PosWindow rate_win_;  // since the position's count started
  PosWindow rest_win_;  // since the NMT start
  /// The window: kRestWindowS, or longer where kRestDitherCounts over it
  /// would read as kTableAtRestRps (a coarse encoder).
  [[nodiscard]] double rate_window_s() const;
  void add_position(PosWindow& w, double t, std::int64_t counts) const;
  /// The latest position against `w`: the rate (NaN before a window, 0
  /// within the dither) and whether that is rest.
  [[nodiscard]] Rest over(const PosWindow& w) const;
  std::vector<EncoderSample> samples_;
  std::vector<canopen::Emcy> emcy_;
  std::string last_warning_;  // the last EMCY that only warned, its text; empty: none
  // the statusword's reads after a warning EMCY: one at a time, their own generation
  std::string warning_text_;
  int warning_reads_left_ = 0;
  double warning_read_at_ = INFINITY;
  bool warning_in_flight_ = false;
  bool warning_again_ = false;  // another warning came while a read was under way
  std::uint64_t warning_gen_ = 0;
  std::vector<std::string> notices_;
  MasterCounts counts_;
};

}  // namespace turncal::cia402
