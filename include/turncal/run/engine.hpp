// One run of the experiment, pure: received frames and the passing of time
// in, frames to send out. It joins the ingest (frames into samples), the
// sequencer (the state machine), the record (what the estimator needs) and
// the command encoding; the daemon puts it on sockets and timers, the
// replay feeds it a log, the tests a virtual stand. Estimation and the
// report are left to the caller (a worker thread in the daemon), which
// hands back the outcome.
//
// Time: the stand's seconds. Kernel receive times (ns) are cut to
// microseconds, as a candump log keeps them, and then scaled about the
// run's epoch by `time_scale` (1 on a real stand; N for a virtual stand
// running N times faster than real time), so a replay of the log sees
// exactly the times the live run saw.
#pragma once

#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "turncal/can/frame.hpp"
#include "turncal/config.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/ingest.hpp"
#include "turncal/run/record.hpp"
#include "turncal/run/sequencer.hpp"

namespace turncal::run {

struct OutFrame {
  bool ins_side;  ///< for the INS interface (else the table's)
  can::Frame frame;
  /// Goes before anything waiting to be sent, and replaces what waits of
  /// its ID (a quick stop: no move queued before it may follow it).
  bool urgent = false;
};

/// std::llround(x), half away from zero, without the library call (a
/// frame's time is rounded so, millions of times a replay): for |x| < 2^52
/// the truncation and the fraction it leaves are exact; any other x (and
/// NaN) goes to std::llround.
inline std::int64_t round_half_away(double x) {
  if (!(std::abs(x) < 0x1p52)) return std::llround(x);
  auto i = static_cast<std::int64_t>(x);
  const double fraction = x - static_cast<double>(i);
  if (fraction >= 0.5)
    ++i;
  else if (fraction <= -0.5)
    --i;
  return i;
}

/// Kernel time into stand time.
struct TimeBase {
  std::int64_t epoch_us = 0;  ///< the run's origin, us since the Unix epoch
  double scale = 1;
  [[nodiscard]] double stand_s(std::int64_t time_ns) const {
    const std::int64_t us = time_ns / 1000;
    return static_cast<double>(epoch_us) * 1e-6 + static_cast<double>(us - epoch_us) * 1e-6 * scale;
  }
};

/// The last of what the operator wants to watch.
struct Live {
  double ve = NAN, vn = NAN;  ///< m/s
  double table_angle_rad = NAN;
  double table_rate_rps = NAN;
  int ins_mode = -1;
  int table_state = -1;
};

/// The ranges of the table's and the INS's command signals as the drivers
/// encode them, in SI units for the plan check.
CommandSignals command_signals(const InsDriver& ins, const TableDriver& table);
/// ... of the reference stand's devices through `roles`.
CommandSignals command_signals(const RoleMap& roles);

/// What the configuration says a frame's values can be: the INS velocity
/// bound, twice the stand's rate limit for the encoder's steps, and the
/// fraction of a stream's frames past which the run fails.
Plausibility plausibility_of(const Config& cfg);

/// SequencerSettings::real_time_floor_s for a stand: [stand]
/// real_time_floor_ms in stand seconds where the stand runs faster than
/// real time, and 0 on one that does not (a real stand's timeouts are as
/// given). The second form for a run at `time_scale` (a replay's, from
/// its log's report) under a floor of `floor_ms` of real time.
double real_time_floor_s(const StandConfig& stand);
double real_time_floor_s(double floor_ms, double time_scale);

class Engine {
 public:
  /// The reference stand's devices through `roles`; `db` and `roles` must
  /// outlive it. The plan is checked against the drivers' command signals
  /// at the start (`seq.commands` is set from them); a command that does
  /// not fit at run time fails the run.
  Engine(const can::Database& db, const RoleMap& roles, Plan plan, SequencerSettings seq,
         BuildSettings build, TimeBase time, Plausibility plausibility = {});
  /// The stand's own devices; `db` must outlive it.
  Engine(const can::Database& db, std::unique_ptr<InsDriver> ins,
         std::unique_ptr<TableDriver> table, Plan plan, SequencerSettings seq, BuildSettings build,
         TimeBase time, Plausibility plausibility = {});

  void start(std::int64_t now_ns, std::vector<OutFrame>& out);
  void abort(std::int64_t now_ns, const std::string& reason, std::vector<OutFrame>& out);
  void signal(std::int64_t now_ns, const std::string& name, std::vector<OutFrame>& out);
  /// A fault of the host (the log, a CAN interface): the run fails with `what`.
  void fault(std::int64_t now_ns, const std::string& what, std::vector<OutFrame>& out);
  void end_of_input(std::int64_t now_ns, std::vector<OutFrame>& out);
  /// A received frame (or one of ours, as a recording has it).
  void on_frame(const can::TimedFrame& f, std::vector<OutFrame>& out) {
    on_frame(f.frame, f.time_ns, out);
  }
  /// The same, the frame and its receive time apart (no copy of the frame).
  void on_frame(const can::Frame& frame, std::int64_t time_ns, std::vector<OutFrame>& out);
  /// Deadlines and lost streams; call often (10 Hz or more).
  /// `heard_until_ns`: every frame stamped before it has been given to
  /// on_frame or stamped() (a read that left frames, or lost some to a full
  /// queue, bounds it): no silence after it is known.
  void tick(std::int64_t now_ns, std::vector<OutFrame>& out,
            std::int64_t heard_until_ns = std::numeric_limits<std::int64_t>::max());
  /// What the last calls put in `out` went out at now_ns (the host's send):
  /// the deadlines set with it run from then (Sequencer::sent).
  void sent(std::int64_t now_ns) { seq_.sent(stand_s(now_ns)); }
  /// The host heartbeat's frames, rolling counter and host state.
  std::vector<OutFrame> heartbeat();

  /// The record is complete and estimation is due: the input, once. The
  /// record holds every sample received from the start up to t0 +
  /// duration + 1 s (host time), whatever the ticks: the first frame past
  /// that (or the end of the input, or 2 s of silence) completes it, so a
  /// replay of the log builds the very same input.
  [[nodiscard]] bool estimation_due() const { return estimation_due_ && record_complete_; }
  Result<BuiltInput> take_estimation_input();
  void estimation_done(std::int64_t now_ns, bool ok, const std::string& error,
                       std::vector<OutFrame>& out);
  [[nodiscard]] bool report_due() const { return report_due_; }
  void report_written(std::int64_t now_ns, bool ok, const std::string& error,
                      std::vector<OutFrame>& out);

  [[nodiscard]] const Sequencer& sequencer() const { return seq_; }
  [[nodiscard]] const Ingest& ingest() const { return ingest_; }
  [[nodiscard]] const Record& record() const { return record_; }
  [[nodiscard]] const Plausibility& plausibility() const { return plausible_; }
  [[nodiscard]] const Plan& plan() const { return plan_; }
  [[nodiscard]] const Live& live() const { return live_; }
  [[nodiscard]] const TimeBase& time_base() const { return time_; }
  [[nodiscard]] const BuildSettings& build_settings() const { return build_; }
  [[nodiscard]] double stand_s(std::int64_t ns) const { return time_.stand_s(ns); }
  /// A stretch (stand seconds, from and to) the host's machine was held as
  /// a whole: between two ticks of its loop, no frame stamped on any bus
  /// (the widest such stretch since the last tick), for longer than
  /// SequencerSettings::hold_s. No stream's silence counts the time in one
  /// (the host was not listening), nor does the time waited for a table's
  /// answer. Past half of kHoldWindowS held, a hold is not excused (a
  /// host that cannot keep up would leave a lost stream unnoticed as long).
  struct Hold {
    double from_s, to_s;
  };
  static constexpr std::size_t kMaxHolds = 10000;  ///< listed in the report
  static constexpr double kHoldWindowS = 10;
  /// The first kMaxHolds holds (hold_count() counts them all).
  [[nodiscard]] const std::vector<Hold>& holds() const { return holds_; }
  [[nodiscard]] std::uint64_t hold_count() const { return hold_count_; }
  [[nodiscard]] double longest_hold_s() const { return longest_hold_s_; }
  /// Holds not excused: past half of kHoldWindowS held.
  [[nodiscard]] std::uint64_t holds_unexcused() const { return holds_unexcused_; }
  /// The last hold (from and to NaN before any).
  [[nodiscard]] Hold last_hold() const { return last_hold_; }
  /// The time between from_s and to_s excused as held (the excused holds
  /// ending within kHoldKeptS of the last one: older ones, forgotten, and
  /// those not excused, are not).
  [[nodiscard]] double held_between(double from_s, double to_s) const;
  /// Stream `s` lost at t: silent for 10 of its periods and `floor_s`, in
  /// the time the loop ran (never heard: lost).
  [[nodiscard]] bool stale(Stream s, double t, double floor_s) const;
  /// A frame stamped on a bus that on_frame() does not see (one of ours,
  /// its transmission confirmed): the bus was not silent then.
  void stamped(std::int64_t time_ns);
  /// A replay: the live run's holds (sorted, apart, each from before to),
  /// each taken from the first tick past its start, as the live loop took
  /// it on its end.
  void replay_holds(std::vector<Hold> holds);
  /// A replay: the record's velocity on huge pages (Record::use_huge_pages).
  /// Call before the first frame: the record reserves its room at the
  /// 256th velocity sample, and asks for huge pages only then.
  void replaying() { record_.use_huge_pages(); }
  /// Tables of the commands we sent, counted.
  [[nodiscard]] std::uint64_t commands_sent() const { return commands_sent_; }

 private:
  void feed(const Event& e, std::vector<OutFrame>& out);
  /// A sample of the ingest: the record, the live view, the sequencer.
  void use(const Sample& s, double t, std::vector<OutFrame>& out);
  /// The table driver's own frames and held-back samples.
  void driver_output(double host_s, std::vector<OutFrame>& out);
  std::vector<can::Frame> driver_frames_;
  Plan plan_;
  BuildSettings build_;
  TimeBase time_;
  Ingest ingest_;
  Sequencer seq_;
  Record record_;
  Live live_;
  std::vector<Command> cmds_;
  bool ins_aligning_seen_ = false;  ///< the INS aligned in this run: its velocity is ours
  bool estimation_due_ = false;
  bool record_complete_ = false;
  bool clock_fault_fed_ = false;  ///< a device clock that jumped has failed the run
  bool implausible_fed_ = false;  ///< a stream of implausible frames has failed the run
  Plausibility plausible_;
  double last_frame_s_ = NAN;
  double prev_tick_s_ = NAN;
  /// When the frames since the last tick were stamped (the first
  /// kMaxStamps; past them no hold is looked for: a bus that busy was not
  /// silent, and the stamps left out could be anywhere).
  std::vector<double> stamps_;
  bool stamps_full_ = false;
  static constexpr std::size_t kMaxStamps = 100000;
  std::vector<Hold> holds_;
  std::uint64_t hold_count_ = 0;
  double longest_hold_s_ = 0;
  Hold last_hold_{NAN, NAN};
  static constexpr double kHoldKeptS = 60;
  std::deque<Hold> recent_holds_;  ///< excused, ending in the last kHoldKeptS
  std::deque<Hold> window_holds_;  ///< all, excused or not, of the last kHoldWindowS
  std::uint64_t holds_unexcused_ = 0;
  std::vector<Hold> replayed_holds_;
  std::size_t next_replayed_hold_ = 0;
  void note_hold(const Hold& h);
  [[nodiscard]] double record_end_s() const;
  void check_plausible(double t, std::vector<OutFrame>& out);
  bool report_due_ = false;
  std::uint8_t heartbeat_counter_ = 0;
  std::uint64_t commands_sent_ = 0;
};

}  // namespace turncal::run
