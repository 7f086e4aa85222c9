// The device side as the run sees it (design.md, data flow): typed samples
// in SI units with their device time, the sequencer's commands, and the two
// small interfaces every INS output layout and every turntable protocol
// implements. The engine, the ingest and the sequencer talk to these only,
// so they never know which protocol a stand speaks. Pure: no sockets, no
// clocks; drivers decode frames and encode commands.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/can/frame.hpp"
#include "turncal/config.hpp"
#include "turncal/icd.hpp"
#include "turncal/result.hpp"

namespace turncal {

// ---- samples (time: host seconds; device clocks unwrapped, s) ----

/// An INS velocity sample in navigation axes (East, North).
struct VelocitySample {
  double t_ins_s;  ///< INS clock, unwrapped
  double host_s;   ///< receive time (of the later frame, where it takes two)
  double ve, vn;   ///< m/s
};
struct InsStatusSample {
  double t_ins_s;
  double host_s;
  int mode;  ///< 0 idle, 1 aligning, 2 navigating, 3 fault
  double align_remaining_s;
};
struct EncoderSample {
  double t_table_s;  ///< table clock, unwrapped
  double host_s;
  double angle_rad;  ///< multi-turn, counter-clockwise seen from above
};
/// The table's state as the sequencer needs it, whatever the protocol.
struct TableStatusSample {
  double host_s;
  int state;  ///< TableState: 0 disabled .. 5 quick-stopped (can-icd.md)
  int ack;    ///< sequence number of the last command the table accepted
  int fault;
  std::string fault_name;  ///< from the DBC's value table, or "fault N"
  double rate_rps;
};
/// A host frame seen on the bus (ours in a recording, or another host's).
struct HostCommandSample {
  double host_s;
  Role role;  ///< InsCommand, TableCommand or HeartbeatCounter
  std::vector<double> values;
};
using Sample = std::variant<std::monostate, VelocitySample, InsStatusSample, EncoderSample,
                            TableStatusSample, HostCommandSample>;

/// The kinds of frame whose health the host watches.
enum Stream : std::uint8_t { kVelocity, kInsStatus, kEncoder, kTableStatus, kStreams };

// ---- commands (the sequencer's, in SI units) ----

struct TableCommand {
  TableCommandCode code;
  std::uint8_t seq;
  double target_rad = 0;
  double rate_rps = 0;
};
struct InsCommand {
  InsCommandCode code;
  std::uint8_t seq;
  double align_s = 0;
  double heading_rad = 0;  ///< of axis z2, clockwise from North, in [0, 2 pi)
};

/// What one command signal carries, in SI units, as its DBC gives it.
struct SignalSpan {
  std::string name;  ///< "TBL_Command.Target"; empty: not checked
  double lo = -INFINITY;
  double hi = INFINITY;
  std::string range;  ///< the DBC's, for people: "-21474.83648 to 21474.83647 deg"
  [[nodiscard]] bool holds(double v) const { return name.empty() || (v >= lo && v <= hi); }
};

/// What a frame's values can be; beyond it a frame is garbled, not data.
struct Plausibility {
  double max_velocity_mps = 1000;  ///< either INS velocity component, |v|
  double max_table_rate_rps = std::numeric_limits<double>::infinity();  ///< encoder steps
  /// An encoder step is judged on host receive times (a garbled device tag
  /// cannot stretch it) with this much more time allowed, host s: frames
  /// that queued and arrive together are steps of their device period
  /// with almost no host time between them.
  double step_slack_s = 0.05;
  /// Values outside their DBC signal's [min|max] are implausible.
  bool dbc_ranges = true;
  /// No check at all: what a run recorded before turncal checked frames
  /// did, for its replay.
  static Plausibility none();
  /// A stream with more than this fraction of its frames implausible (once
  /// it has 100), or 5 on end (before it is called lost for them), fails
  /// the run: the engine's check. In [0, 1].
  double max_fraction = 0.01;
  static constexpr std::uint64_t kMaxRun = 5;
  /// Within the DBC's [min|max] of `sig` ([0|0]: no range); always when
  /// dbc_ranges is off.
  [[nodiscard]] bool in_range(const can::Signal& sig, double value) const;
};

// ---- the driver interfaces ----

/// A received frame as the ingest hands it to the drivers: decoded once by
/// the stand's DBC (`msg` null and `status` UnknownId when the DBC does not
/// describe it).
struct FrameView {
  const can::Frame& frame;
  double host_s;  ///< receive time, s (microseconds, as a log keeps it)
  const can::Message* msg;
  can::DecodeStatus status;
  std::span<const double> values;  ///< msg's signals, physical (when status is Ok)
};

/// What a driver made of a frame.
/// Decoded::lost_before of the first sample of a stream that started over.
inline constexpr std::int64_t kStreamRestarted = -2;

struct Decoded {
  enum class Verdict : std::uint8_t {
    NotMine,      ///< not this device's frame
    Malformed,    ///< this device's, but its values are no numbers
    Implausible,  ///< this device's, values that cannot be (`stream` says whose)
    Pending,      ///< kept until another frame completes it
    Taken,        ///< a sample (`sample`, of `stream`; kStreams: no stream's)
  };
  Verdict verdict = Verdict::NotMine;
  Stream stream = kStreams;
  double device_s = NAN;  ///< the sample's device time (NaN: the device sends none)
  Sample sample;
  /// Samples of the stream lost just before this one, as the device's own
  /// sequence tells (a CiA 402 TPDO answers each SYNC); -1: not known, the
  /// gap in device time since the last sample says; kStreamRestarted: the
  /// first of a stream that started over, no loss and no gap.
  std::int64_t lost_before = -1;

  static Decoded malformed() { return of(Verdict::Malformed, kStreams); }
  static Decoded implausible(Stream s) { return of(Verdict::Implausible, s); }
  static Decoded pending() { return of(Verdict::Pending, kStreams); }
  static Decoded taken(Stream s, double device_s, Sample sample) {
    Decoded d = of(Verdict::Taken, s);
    d.device_s = device_s;
    d.sample = std::move(sample);
    return d;
  }

 private:
  static Decoded of(Verdict v, Stream s) {
    Decoded d;
    d.verdict = v;
    d.stream = s;
    return d;
  }
};

/// An INS output layout: frames into velocity and status samples; commands
/// into frames.
class InsDriver {
 public:
  virtual ~InsDriver() = default;
  virtual Decoded decode(const FrameView& v) = 0;
  /// Frames of the command; a value that does not fit its signal is an
  /// error naming it, never saturated.
  virtual Result<std::vector<can::Frame>> command(const InsCommand& c) const = 0;
  /// The alignment length the command can carry, s.
  [[nodiscard]] virtual SignalSpan align_duration() const = 0;
  /// IDs (with the extended flag) the host receives from the INS.
  [[nodiscard]] virtual std::vector<std::pair<std::uint32_t, bool>> receive_ids() const = 0;
  /// Velocity frames whose other half never came.
  [[nodiscard]] virtual std::uint64_t half_pairs() const { return 0; }
  /// Velocity frames left out for want of a time (no time frame before them).
  [[nodiscard]] virtual std::uint64_t untimed() const { return 0; }
};

/// A turntable protocol: frames into encoder and status samples; the
/// sequencer's commands and the host heartbeat into frames.
class TableDriver {
 public:
  virtual ~TableDriver() = default;
  /// An encoder sample is returned tentatively: the ingest checks its step
  /// and calls accept_encoder() when it keeps it (the unwrapping goes on
  /// from kept samples only).
  virtual Decoded decode(const FrameView& v) = 0;
  virtual void accept_encoder() {}
  /// The encoder's resolution, rad (a step check allows two of them).
  [[nodiscard]] virtual double angle_resolution_rad() const = 0;
  /// Frames of the command; a value that does not fit is an error naming
  /// it, never saturated.
  virtual Result<std::vector<can::Frame>> command(const TableCommand& c) = 0;
  /// The host heartbeat: rolling counter and host state (0 idle, 1
  /// running, 2 aborting). The host sends it from its main loop whenever it
  /// commands a stand, idle too: a table refuses to start a move without a
  /// recent heartbeat, and stops one it no longer hears.
  [[nodiscard]] virtual std::vector<can::Frame> heartbeat(std::uint8_t counter,
                                                          int host_state) const = 0;
  /// The move target and rate limit a command can carry, rad and rad/s.
  [[nodiscard]] virtual SignalSpan target() const = 0;
  [[nodiscard]] virtual SignalSpan rate_limit() const = 0;
  [[nodiscard]] virtual std::vector<std::pair<std::uint32_t, bool>> receive_ids() const = 0;

  // A protocol with machinery of its own (CANopen: NMT, configuration by
  // SDO, heartbeats, SYNC). The reference table needs none of it. Frames to
  // send go to `out`, and go out as command frames do.
  /// The run starts (not in observe mode: an observer sends nothing).
  virtual void start(double /*now_s*/, std::vector<can::Frame>& /*out*/) {}
  /// From when the table's streams (encoder, status) are due, stand s. A
  /// protocol that starts up first (CANopen: boot-up, configuration by
  /// SDO) sends none before it runs: while it starts, a time to come, the
  /// latest its start-up may end by its own timeouts (never NaN, never
  /// unbounded: a start-up that never ends loses the streams). Default:
  /// always due.
  [[nodiscard]] virtual double streams_due_s() const {
    return -std::numeric_limits<double>::infinity();
  }
  /// Timeouts and periodic frames; called from the main loop's tick.
  virtual void tick(double /*now_s*/, std::vector<can::Frame>& /*out*/) {}
  /// The host's machine was held from from_s to to_s (Engine::Hold): a
  /// timeout that waits on the device does not count that time, as the
  /// streams' silence does not. Called from the tick that finds it, before
  /// tick(); frames read before that tick came after to_s.
  virtual void held(double /*from_s*/, double /*to_s*/) {}
  /// Whether a heartbeat the protocol's own machinery sends from tick()
  /// (CANopen's) may go out: off once the host has given up stopping the
  /// table, so that the table stops itself on losing it. A protocol whose
  /// heartbeat is heartbeat()'s alone ignores it (the caller stops calling).
  virtual void set_heartbeat(bool /*on*/) {}
  /// Frames that answer frames decode() was given (a handshake's next
  /// step), moved to `out`.
  virtual void take_frames(std::vector<can::Frame>& /*out*/) {}
  /// How the table's counts become angles where the configuration says it
  /// (a CiA 402 drive: counts per revolution, gear ratio, the direction
  /// counts increase), as text; empty where the protocol's own DBC scaling
  /// says it. The report keeps it: a replay under another would scale or
  /// mirror every angle, and is refused.
  [[nodiscard]] virtual std::string geometry() const { return {}; }
  /// What the protocol has to tell the operator that is no fault (a drive
  /// that refused an optional object), each once, oldest first; the caller
  /// logs those past the ones it has logged.
  [[nodiscard]] virtual const std::vector<std::string>& notices() const {
    static const std::vector<std::string> none;
    return none;
  }
  /// A sample beyond the one decode() returned (a status change that came
  /// with an encoder sample, or from a timeout in tick()); NotMine: none.
  virtual Decoded pending() { return {}; }
};

}  // namespace turncal
