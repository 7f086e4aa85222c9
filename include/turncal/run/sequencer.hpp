// The experiment as a pure state machine (style.md, 7): events in (time,
// device states, health, operator requests), commands out. Time is the
// host's, injected in every event; timers, sockets and the heartbeat live
// in the daemon. Two modes: command (drives the table and the INS through
// the profile) and observe (follows a stand that someone else drives, or a
// recording: phases from the INS mode and the encoder).
//
//   idle -> prepare -> align -> hold 1 -> turn 1 -> hold 2 ... -> estimate -> report -> done
//
// and from every state: aborted (operator, signal) or failed (a fault, a
// timeout), each with its reason. In command mode the table is sent a quick
// stop on abort, on every fault and on a signal while it moves.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "turncal/config.hpp"
#include "turncal/device.hpp"
#include "turncal/icd.hpp"
#include "turncal/physics/profile.hpp"

namespace turncal::run {

enum class Phase : std::uint8_t {
  Idle,
  Prepare,  ///< table enabled, moved to the start angle
  Align,    ///< INS aligning
  Hold,     ///< still, navigating
  Turn,
  Estimate,  ///< the record is complete; estimation runs
  Report,    ///< estimation done; the report is written
  Done,
  Aborted,
  Failed,
};
const char* to_string(Phase p);
[[nodiscard]] inline bool finished(Phase p) {
  return p == Phase::Done || p == Phase::Aborted || p == Phase::Failed;
}

using turncal::SignalSpan;

/// The stand's command signals a plan's values go into.
struct CommandSignals {
  SignalSpan target;          ///< the table's move target (a relative move's delta), rad
  SignalSpan rate_limit;      ///< the table's move rate limit, rad/s
  SignalSpan align_duration;  ///< the INS alignment length, s
};

struct SequencerSettings {
  Profile profile;             ///< holds and turns, times from t0
  double start_angle_rad = 0;  ///< table angle at t0
  double heading_offset_rad = 0;
  StandLimits limits;  ///< turncal.toml [stand]
  /// In command mode every move and the alignment must fit these (the
  /// engine sets them from the DBC), or the plan is refused.
  CommandSignals commands;
  bool observe = false;
  /// A recording that ends anywhere after t0 (a damaged log) is estimated
  /// over what there is; otherwise only one that ends in the last hold.
  bool estimate_partial = false;
  double ack_timeout_s = 1.0;  ///< a table command unacknowledged this long is a fault
  /// A quick stop is sent again this often until the table reports it
  /// stopped, and given up on (loudly, in the reason) after quick_stop_give_up_s.
  double quick_stop_repeat_s = 0.25;
  double quick_stop_give_up_s = 5.0;
  double enable_timeout_s = 5.0;        ///< from enable to the table holding
  double align_start_s = 3.0;           ///< from the INS command to the INS aligning
  double align_margin_s = 30.0;         ///< beyond the alignment length, to navigating
  double turn_margin_s = 10.0;          ///< beyond the planned turn time, to in position
  double start_tolerance_rad = 1.7e-4;  ///< closer than this to the start angle: no move (0.01 deg)
  double prepare_rate_rps = 10 * 0.017453292519943295;  ///< rate of the move to the start angle
  double grace_s = 1.0;  ///< after the start and after t0: a stream not yet heard is not lost
  /// A stream is lost after 10 periods unseen, and never sooner than this
  /// (stand seconds): the host's scheduling latency, which a virtual stand
  /// running N times faster stretches N times in stand time. The table's
  /// acknowledgement timeout has it added for the same reason.
  double stale_floor_s = 0;
  /// Added to every wait for the stand's answer (an acknowledgement, the
  /// enable, the INS aligning and navigating, a move in position, the quick
  /// stop's give-up), in stand seconds: 0 on a real stand (time scale 1),
  /// where every timeout is as given. On a virtual stand run N times faster
  /// than real time ([stand] real_time_floor_ms times N) a stall of the
  /// host's machine, which the time scale stretches N times in stand time,
  /// is not taken for a device that did not answer.
  double real_time_floor_s = 0;
  /// The host's machine was held (a paused machine, a virtual stand's
  /// whole machine stopped) when its loop did not run and no frame was
  /// stamped on any bus for longer than this (stand seconds): the time in
  /// between does not count in a stream's silence, since the host was
  /// deaf, not the bus silent (Engine::Hold). Infinity: never (a replay,
  /// which takes the live run's holds from its report).
  double hold_s = std::numeric_limits<double>::infinity();
  /// Observe mode: the table has left its hold when it is this far from
  /// it (0.05 deg), and is at rest again after still_time_s within a tenth.
  double motion_threshold_rad = 8.7e-4;
  double still_time_s = 1.0;
  /// Sequence numbers go on from these (the last ones the devices saw), so
  /// a stale acknowledgement of an earlier run is never taken for ours.
  std::uint8_t table_seq_base = 0;
  std::uint8_t ins_seq_base = 0;
};

/// Checks the profile against the limits, and in command mode against the
/// command signals, before any command goes out; empty when it fits, else
/// why not.
std::string check_plan(const SequencerSettings& s);

// ---- events (host time t_s on each) ----
struct Tick {
  double t_s;
  bool velocity_stale = false;  ///< INS velocity not seen for 10 periods
  /// ... for 10 of its periods, without the host's latency floor: with its
  /// status lost too, the INS is silent as a whole
  bool velocity_quiet = false;
  bool ins_status_stale = false;
  bool encoder_stale = false;
  bool table_status_stale = false;
  /// The table's protocol still starts up (CANopen: boot-up, configuration
  /// by SDO, bounded by its own timeouts): a command's ack is not yet due.
  bool table_starting = false;
};
struct InsModeEvent {
  double t_s;
  int mode;  ///< 0 idle, 1 aligning, 2 navigating, 3 fault
};
struct TableStatusEvent {
  double t_s;
  int state;  ///< 0 disabled, 1 holding, 2 moving, 3 in position, 4 fault, 5 quick-stopped
  int ack;
  int fault;
  std::string fault_name;
  double rate_rps = NAN;  ///< the table's own rate; NaN: not known
};

struct EncoderEvent {
  double t_s;
  double angle_rad;  ///< multi-turn
};
struct StartRequest {
  double t_s;
};
struct AbortRequest {
  double t_s;
  std::string reason;
};
/// SIGTERM or SIGINT: stop the table if it moves, then finish.
struct SignalEvent {
  double t_s;
  std::string name;
};
/// A fault of the host itself, not of a device: the log cannot be written,
/// a CAN interface went down, a frame could not be sent. Fails the run with
/// `what` (and a quick stop in command mode).
struct HostFault {
  double t_s;
  std::string what;
};
/// The recording ended (observe mode on a log).
struct EndOfInput {
  double t_s;
};
struct EstimationDone {
  double t_s;
  bool ok;
  std::string error;
};
struct ReportWritten {
  double t_s;
  bool ok;
  std::string error;
};
using Event =
    std::variant<Tick, InsModeEvent, TableStatusEvent, EncoderEvent, StartRequest, AbortRequest,
                 SignalEvent, HostFault, EndOfInput, EstimationDone, ReportWritten>;

// ---- commands ----
using TableCode = TableCommandCode;
using turncal::InsCommand;
using turncal::TableCommand;
struct RunEstimation {};
struct WriteReport {};
using Command = std::variant<TableCommand, InsCommand, RunEstimation, WriteReport>;

/// What the report says about the run's course.
struct PhaseMark {
  Phase phase;
  int index;  ///< hold or turn number, from 1; 0 otherwise
  double t_s;
};
struct Course {
  std::vector<PhaseMark> marks;
  double t0_s = NAN;   ///< host time the INS was first seen navigating
  std::string reason;  ///< why it aborted or failed
  bool quick_stop_sent = false;
  bool quick_stop_acked = false;
  int quick_stops_sent = 0;  ///< the first and its repetitions
  /// The table never reported stopped: the host stops its heartbeat, so a
  /// table still moving stops itself on losing it.
  bool quick_stop_gave_up = false;
  std::vector<double> turn_commanded_s;  ///< host time of each turn command (observe: its start)
  double heading_given_rad = NAN;        ///< in the INS command
  /// A stop signal that came while the estimate was computed: the table at
  /// rest and the record whole, the estimate is finished and reported first.
  std::string signal_in_estimate;
};

class Sequencer {
 public:
  explicit Sequencer(SequencerSettings s);
  /// Feeds one event; the commands it calls for are appended to `out`.
  void step(const Event& e, std::vector<Command>& out);
  [[nodiscard]] Phase phase() const { return phase_; }
  /// Hold or turn number, from 1.
  [[nodiscard]] int index() const { return index_; }
  [[nodiscard]] const Course& course() const { return course_; }
  [[nodiscard]] const SequencerSettings& settings() const { return s_; }
  /// Planned time left to the end of the record, s (NaN before t0).
  [[nodiscard]] double remaining_s(double t_s) const;
  /// The host state for the heartbeat: 0 idle, 1 running, 2 aborting.
  [[nodiscard]] int host_state() const;
  /// True while a table motion this sequencer asked for may be under way.
  [[nodiscard]] bool table_may_move() const { return may_move_; }
  /// The host's machine was held from from_s to to_s (Engine::Hold): the
  /// acknowledgement and phase deadlines set before it run on by its
  /// length, since neither the host nor a device sharing its machine was
  /// running to answer. The quick stop's give-up does not.
  void held(double from_s, double to_s);
  /// The commands of the steps since the last call went out at t_s: each
  /// deadline set with them runs from then. The host sends what an event
  /// called for when it has read that event, and an event read late (a
  /// backlog the host's loop had not reached: a busy machine) dates them
  /// earlier than the bus saw them; a deadline from the event would count
  /// the host's own delay as the stand's.
  void sent(double t_s);
  /// The last table angle seen (multi-turn), NaN before any.
  [[nodiscard]] double table_angle() const { return angle_; }

 private:
  void enter(Phase p, double t, int index = 0);
  void fail(double t, const std::string& why, std::vector<Command>& out, bool aborted = false);
  void table(TableCode code, double t, std::vector<Command>& out, double target = 0,
             double rate = 0);
  void on_tick(const Tick& e, std::vector<Command>& out);
  void on_table(const TableStatusEvent& e, std::vector<Command>& out);
  void on_ins(const InsModeEvent& e, std::vector<Command>& out);
  void on_encoder(const EncoderEvent& e, std::vector<Command>& out);
  /// The host's own checks of the encoder (command mode): the soft limits,
  /// a move past its target, motion with none commanded.
  void guard_encoder(double t, std::vector<Command>& out);
  /// Where the table was sent, or where it is to stay; NaN: not known yet.
  [[nodiscard]] std::string off_target(const char* what) const;
  void observe_motion(double t);
  void start_turn(double t, std::vector<Command>& out);
  void after_turn(double t);
  void prepare_move(double t, std::vector<Command>& out);
  void begin_align(double t, std::vector<Command>& out);
  void navigating(double t);
  /// A relative move, and the deadline by which it must be in position.
  void move(double t, std::vector<Command>& out, double delta, double rate, double accel,
            const std::string& late);
  /// Estimation or report (`in`) came back: on to the next phase, or failed
  /// with `why`; true when it went on.
  bool outcome(Phase in, double t, bool ok, const std::string& why);

  /// How long a table command may go unacknowledged: the table's time,
  /// the host's latency and, on an accelerated stand, the real-time floor.
  [[nodiscard]] double ack_allowed_s() const {
    return s_.ack_timeout_s + s_.stale_floor_s + s_.real_time_floor_s;
  }
  [[nodiscard]] double enable_allowed_s() const {
    return s_.enable_timeout_s + s_.real_time_floor_s;
  }

  SequencerSettings s_;
  Phase phase_ = Phase::Idle;
  int index_ = 0;
  Course course_;
  double run_start_ = NAN;
  std::uint8_t seq_ = 0, ins_seq_ = 0;
  std::optional<std::uint8_t> awaiting_ack_;
  double ack_deadline_ = 0;
  double ack_set_s_ = -INFINITY;  ///< when ack_deadline_ was set
  /// The time of the event whose commands have not been said sent yet
  /// (sent()); NaN when none waits.
  double unsent_at_ = NAN;
  std::string awaiting_what_;
  double phase_deadline_ = INFINITY;
  double phase_set_s_ = -INFINITY;   ///< when phase_deadline_ was set
  std::string waiting_for_;          ///< what the phase deadline is for
  bool deadline_is_enable_ = false;  ///< the phase deadline is the enable's
  std::string last_fault_;           ///< the table's fault name, empty for none
  bool may_move_ = false;
  bool enabled_ = false;
  /// Command mode: the run has started but the table has not been heard
  /// yet; enable goes out with its first status, never blind.
  bool enable_pending_ = false;
  bool table_heard_ = false;
  bool commanded_ = false;  ///< a table command has gone out this run
  bool prepare_moving_ = false;
  bool seen_aligning_ = false;
  bool stopping_ = false;  ///< a quick stop is out; finish when it is acknowledged
  Phase stop_then_ = Phase::Failed;
  double stop_deadline_ = 0;   ///< give up on the quick stop
  double stop_repeat_at_ = 0;  ///< send it again
  double stop_sent_s_ = NAN;   ///< when the first quick stop was called for (sent())
  std::uint8_t stop_first_seq_ = 0;
  int ins_mode_ = -1;
  double angle_ = NAN;
  double target_ = NAN;      ///< where the move under way ends (may_move_)
  double move_delta_ = 0;    ///< its signed length
  double rest_angle_ = NAN;  ///< where the table is to stay while no move is under way
  // observe mode
  double last_moving_t_ = NAN;
  double hold_angle_ = NAN;
  double moving_ref_ = NAN;
  std::size_t next_turn_ = 0;
};

}  // namespace turncal::run
