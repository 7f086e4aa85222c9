#include "turncal/run/sequencer.hpp"

#include <cmath>
#include <cstdio>
#include <numbers>

namespace turncal::run {

namespace {

/// What a fault found at a run's start needs: a person at the stand.
constexpr const char* kUnseenFault =
    ": turncal resets no fault whose cause it did not see; reset it at the stand, then start "
    "again";

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180;

/// Into [-pi, pi).
double wrap_pi(double a) {
  return a - 2 * kPi * std::floor((a + kPi) / (2 * kPi));
}

/// Seconds as a whole number when they are one (the usual timeouts), else
/// to a tenth.
std::string seconds(double s) {
  char b[32];
  if (std::abs(s - std::round(s)) < 1e-9)
    std::snprintf(b, sizeof b, "%.0f", s);
  else
    std::snprintf(b, sizeof b, "%.1f", s);
  return b;
}

std::string deg(double rad) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f deg", rad / kDeg);
  return buf;
}

/// "target 30000 deg does not fit TBL_Command.Target (-21474.83648 to 21474.83647 deg)"
std::string misfit(const char* what, double v, const char* unit, const SignalSpan& sig) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s %.10g %s", what, v, unit);
  return buf + (" does not fit " + sig.name + " (" + sig.range + ")");
}

// the events carry the codes as numbers
constexpr int code(TableState s) {
  return static_cast<int>(s);
}
constexpr int code(InsMode m) {
  return static_cast<int>(m);
}
constexpr int kHolding = code(TableState::Holding), kInPosition = code(TableState::InPosition),
              kFault = code(TableState::Fault), kQuickStopped = code(TableState::QuickStopped),
              kMoving = code(TableState::Moving);
constexpr int kAligning = code(InsMode::Aligning), kNavigating = code(InsMode::Navigating),
              kInsFault = code(InsMode::Fault);

}  // namespace

const char* to_string(Phase p) {
  switch (p) {
    case Phase::Idle:
      return "idle";
    case Phase::Prepare:
      return "prepare";
    case Phase::Align:
      return "align";
    case Phase::Hold:
      return "hold";
    case Phase::Turn:
      return "turn";
    case Phase::Estimate:
      return "estimate";
    case Phase::Report:
      return "report";
    case Phase::Done:
      return "done";
    case Phase::Aborted:
      return "aborted";
    case Phase::Failed:
      return "failed";
  }
  return "?";
}

Sequencer::Sequencer(SequencerSettings s)
    : s_(std::move(s)), seq_(s_.table_seq_base), ins_seq_(s_.ins_seq_base) {}

std::string check_plan(const SequencerSettings& s) {
  const StandLimits& l = s.limits;
  double angle = s.start_angle_rad;
  if (!l.contains(angle))
    return "start angle " + deg(angle) + " is outside the table's angle limits [" +
           deg(l.angle_min_rad) + ", " + deg(l.angle_max_rad) + "]";
  // what goes into the command signals: the move to the start angle (half
  // a turn at most, either way), the alignment, each turn's delta and rate
  const CommandSignals none;
  const CommandSignals& c = s.observe ? none : s.commands;
  const std::string prepare = "the move to the start angle: ";
  if (!c.target.holds(kPi) || !c.target.holds(-kPi))
    return prepare + misfit("target", 180, "deg", c.target);
  if (const double r = std::min(l.max_rate_rps, s.prepare_rate_rps); !c.rate_limit.holds(r))
    return prepare + misfit("rate", r / kDeg, "deg/s", c.rate_limit);
  if (!c.align_duration.holds(s.profile.align_s))
    return "the alignment: " + misfit("length", s.profile.align_s, "s", c.align_duration);
  double last_start = -1;
  for (std::size_t i = 0; i < s.profile.turns.size(); ++i) {
    const TurnSpec& t = s.profile.turns[i];
    const std::string name = "turn " + std::to_string(i + 1);
    if (!(t.max_rate_rps > 0) || t.max_rate_rps > l.max_rate_rps * (1 + 1e-9))
      return name + ": rate " + deg(t.max_rate_rps) + "/s is beyond the limit " +
             deg(l.max_rate_rps) + "/s";
    if (!(t.max_accel_rps2 > 0) || t.max_accel_rps2 > l.max_accel_rps2 * (1 + 1e-9))
      return name + ": acceleration " + deg(t.max_accel_rps2) + "/s^2 is beyond the limit " +
             deg(l.max_accel_rps2) + "/s^2";
    if (!c.target.holds(t.angle_rad))
      return name + ": " + misfit("target", t.angle_rad / kDeg, "deg", c.target);
    if (!c.rate_limit.holds(t.max_rate_rps))
      return name + ": " + misfit("rate", t.max_rate_rps / kDeg, "deg/s", c.rate_limit);
    angle += t.angle_rad;
    if (!l.contains(angle))
      return name + ": end angle " + deg(angle) + " is outside the table's angle limits [" +
             deg(l.angle_min_rad) + ", " + deg(l.angle_max_rad) + "]";
    if (t.start_s <= last_start) return name + ": starts before the turn before it";
    last_start = t.start_s;
  }
  if (!s.profile.turns.empty() && s.profile.turns.back().start_s >= s.profile.duration_s)
    return "the last turn starts after the end of the run";
  return {};
}

double Sequencer::remaining_s(double t_s) const {
  if (std::isnan(course_.t0_s)) return NAN;
  if (finished(phase_) || phase_ == Phase::Estimate || phase_ == Phase::Report) return 0;
  return std::max(0.0, course_.t0_s + s_.profile.duration_s - t_s);
}

int Sequencer::host_state() const {
  if (stopping_) return 2;
  if (phase_ == Phase::Idle || finished(phase_)) return 0;
  return 1;
}

void Sequencer::enter(Phase p, double t, int index) {
  phase_ = p;
  index_ = index;
  course_.marks.push_back({p, index, t});
}

void Sequencer::table(TableCode code, double t, std::vector<Command>& out, double target,
                      double rate) {
  ++seq_;
  commanded_ = true;
  out.emplace_back(TableCommand{code, seq_, target, rate});
  awaiting_ack_ = seq_;
  // the table's own time to answer, and the host's latency (in stand time)
  ack_deadline_ = t + ack_allowed_s();
  ack_set_s_ = t;
  unsent_at_ = t;
  if (code == TableCode::MoveAbsolute || code == TableCode::MoveRelative) may_move_ = true;
}

void Sequencer::fail(double t, const std::string& why, std::vector<Command>& out, bool aborted) {
  if (finished(phase_) || stopping_) return;
  course_.reason = why;
  const Phase then = aborted ? Phase::Aborted : Phase::Failed;
  // Command mode: the table has been heard (so a command may have gone or
  // be about to), or sent something: stop it now and finish when it says
  // so. A table never heard and never commanded is told to stop once, and
  // the run ends: there is nothing of ours for it to stop.
  const bool table_touched = !s_.observe && phase_ != Phase::Idle && (table_heard_ || commanded_);
  if (table_touched) {
    awaiting_what_ = "quick stop";
    table(TableCode::QuickStop, t, out);
    course_.quick_stop_sent = true;
    course_.quick_stops_sent = 1;
    stopping_ = true;
    stop_then_ = then;
    stop_first_seq_ = seq_;
    stop_sent_s_ = t;
    stop_deadline_ = t + s_.quick_stop_give_up_s + s_.real_time_floor_s;
    stop_repeat_at_ = t + s_.quick_stop_repeat_s;
    return;
  }
  if (!s_.observe && phase_ != Phase::Idle) {
    table(TableCode::QuickStop, t, out);
    course_.quick_stop_sent = true;
    course_.quick_stops_sent = 1;
  }
  may_move_ = false;
  enter(then, t);
}

void Sequencer::step(const Event& e, std::vector<Command>& out) {
  std::visit(
      [&](const auto& ev) {
        using E = std::decay_t<decltype(ev)>;
        if constexpr (std::is_same_v<E, Tick>) {
          on_tick(ev, out);
        } else if constexpr (std::is_same_v<E, TableStatusEvent>) {
          on_table(ev, out);
        } else if constexpr (std::is_same_v<E, InsModeEvent>) {
          on_ins(ev, out);
        } else if constexpr (std::is_same_v<E, EncoderEvent>) {
          on_encoder(ev, out);
        } else if constexpr (std::is_same_v<E, StartRequest>) {
          if (phase_ != Phase::Idle) return;
          if (const std::string bad = check_plan(s_); !bad.empty()) {
            enter(Phase::Prepare, ev.t_s);
            course_.reason = "refused before any command: " + bad;
            enter(Phase::Failed, ev.t_s);
            return;
          }
          enter(Phase::Prepare, ev.t_s);
          run_start_ = ev.t_s;
          // command mode: enable goes with the table's first status (a
          // drive that cannot be heard is not enabled blind)
          enable_pending_ = !s_.observe;
        } else if constexpr (std::is_same_v<E, AbortRequest>) {
          if (phase_ == Phase::Idle) return;
          fail(ev.t_s, ev.reason.empty() ? "aborted by the operator" : ev.reason, out, true);
        } else if constexpr (std::is_same_v<E, SignalEvent>) {
          if (finished(phase_) || stopping_) return;
          const std::string why = "stopped by " + ev.name;
          if (phase_ == Phase::Idle) return;
          if (phase_ == Phase::Estimate || phase_ == Phase::Report) {
            if (course_.signal_in_estimate.empty()) course_.signal_in_estimate = ev.name;
            return;
          }
          if (may_move_ && !s_.observe) {
            fail(ev.t_s, why + " while the table moved", out, true);
          } else {
            course_.reason = why;
            enter(Phase::Aborted, ev.t_s);
          }
        } else if constexpr (std::is_same_v<E, HostFault>) {
          if (phase_ == Phase::Idle || phase_ == Phase::Estimate || phase_ == Phase::Report) return;
          fail(ev.t_s, ev.what, out);
        } else if constexpr (std::is_same_v<E, EndOfInput>) {
          if (finished(phase_) || phase_ == Phase::Estimate || phase_ == Phase::Report) return;
          const bool last_hold =
              phase_ == Phase::Hold && index_ == static_cast<int>(s_.profile.turns.size()) + 1;
          const bool after_t0 = phase_ == Phase::Hold || phase_ == Phase::Turn;
          if (last_hold || (s_.estimate_partial && after_t0)) {
            // the recording ends in the last hold: estimate what there is
            enter(Phase::Estimate, ev.t_s);
            out.emplace_back(RunEstimation{});
            return;
          }
          fail(ev.t_s,
               std::string("the recording ended during ") + to_string(phase_) +
                   (index_ > 0 ? " " + std::to_string(index_) : ""),
               out);
        } else if constexpr (std::is_same_v<E, EstimationDone>) {
          if (outcome(Phase::Estimate, ev.t_s, ev.ok, "estimation failed: " + ev.error))
            out.emplace_back(WriteReport{});
        } else if constexpr (std::is_same_v<E, ReportWritten>) {
          outcome(Phase::Report, ev.t_s, ev.ok, "report not written: " + ev.error);
        }
      },
      e);
}

bool Sequencer::outcome(Phase in, double t, bool ok, const std::string& why) {
  if (phase_ != in) return false;
  if (!ok) {
    course_.reason = why;
    enter(Phase::Failed, t);
    return false;
  }
  enter(in == Phase::Estimate ? Phase::Report : Phase::Done, t);
  return true;
}

void Sequencer::held(double from_s, double to_s) {
  // a deadline set before the hold runs on by as long; one set after it
  // (on a frame read before the tick that ends it) by nothing
  if (!(to_s > from_s)) return;
  // (a microsecond's slack: the times of one frame, taken two ways)
  if (ack_set_s_ <= from_s + 1e-6) ack_deadline_ += to_s - from_s;
  if (phase_set_s_ <= from_s + 1e-6) phase_deadline_ += to_s - from_s;  // infinity stays
  // not the quick stop's give-up: what it does on running out (our
  // heartbeat withheld, so the table stops itself) is safe whenever
}

void Sequencer::sent(double t_s) {
  const double at = unsent_at_;
  unsent_at_ = NAN;
  if (!(t_s > at)) return;  // none waits (NaN), or sent when called for
  const double late = t_s - at;
  // only the deadlines set with those commands (the times are assigned,
  // so equal exactly); a deadline set since by a later event is its own
  if (ack_set_s_ == at) ack_deadline_ += late, ack_set_s_ = t_s;
  if (phase_set_s_ == at) phase_deadline_ += late, phase_set_s_ = t_s;  // infinity stays
  if (stopping_ && stop_sent_s_ == at) {
    stop_deadline_ += late;
    stop_repeat_at_ += late;
    stop_sent_s_ = t_s;
  }
}

void Sequencer::on_tick(const Tick& e, std::vector<Command>& out) {
  const double t = e.t_s;
  if (stopping_) {
    if (t > stop_deadline_) {
      stopping_ = false;
      char buf[160];
      std::snprintf(buf, sizeof buf,
                    "; THE TABLE DID NOT REPORT STOPPED within %.1f s of the quick stop (sent %d "
                    "times): check the table",
                    s_.quick_stop_give_up_s + s_.real_time_floor_s, course_.quick_stops_sent);
      course_.reason += buf;
      course_.quick_stop_gave_up = true;
      enter(stop_then_, t);
    } else if (t >= stop_repeat_at_) {
      // a quick stop may have been lost (a full queue, a bus down): again
      table(TableCode::QuickStop, t, out);
      ++course_.quick_stops_sent;
      stop_repeat_at_ = t + s_.quick_stop_repeat_s;
    }
    return;
  }
  if (finished(phase_) || phase_ == Phase::Idle || phase_ == Phase::Estimate ||
      phase_ == Phase::Report)
    return;
  // the ack's time, and the enable's, run from when the table's protocol is up
  if (awaiting_ack_ && e.table_starting)
    ack_deadline_ = std::max(ack_deadline_, t + ack_allowed_s()), ack_set_s_ = t;
  if (phase_ == Phase::Prepare && deadline_is_enable_ && e.table_starting)
    phase_deadline_ = std::max(phase_deadline_, t + enable_allowed_s()), phase_set_s_ = t;
  if (!s_.observe && awaiting_ack_ && t > ack_deadline_) {
    fail(t,
         "the table did not acknowledge " + awaiting_what_ + " within " +
             std::to_string(static_cast<int>(std::lround(ack_allowed_s() * 1000))) + " ms" +
             (last_fault_.empty() ? "" : " (table fault: " + last_fault_ + ")"),
         out);
    return;
  }
  // losing a device: the table's side at any time of a run, the INS once
  // it has been commanded
  // (never sooner than the host's latency floor: a stream not yet heard)
  const bool heard_time = t - run_start_ > std::max(s_.grace_s, s_.stale_floor_s);
  if (!s_.observe && heard_time) {
    if (e.table_status_stale)
      return fail(t,
                  table_heard_ ? "table status lost (no TBL_Status for 10 periods)"
                               : "the table not heard: no TBL_Status since the start of the run",
                  out);
    if (e.encoder_stale)
      return fail(t, "table encoder lost (no encoder frame for 10 periods)", out);
  }
  // the velocity first: what the estimate needs, and what an observer of
  // the log judges too. An INS silent as a whole is said so by its
  // velocity: its status (10 Hz) can be lost first, or with the latency
  // floor at once; while the velocity too is quiet, the status's loss waits
  // (at most the floor) for the velocity's, which an observer of the log
  // then sees as well.
  const bool in_run = phase_ == Phase::Hold || phase_ == Phase::Turn;
  const bool nav_time = t - course_.t0_s > s_.grace_s;
  const bool ins_silent = in_run && nav_time && e.velocity_quiet;
  if (in_run && nav_time && e.velocity_stale)
    return fail(t,
                std::string("INS velocity lost during ") + to_string(phase_) + " " +
                    std::to_string(index_) + " (no velocity frame for 10 periods)",
                out);
  if (phase_ == Phase::Align || in_run) {
    if (e.ins_status_stale && !s_.observe && heard_time && !ins_silent)
      return fail(t, "INS status lost (no status frame for 10 periods)", out);
  }
  if (in_run && nav_time && s_.observe && e.encoder_stale)
    return fail(t, "table encoder lost (no encoder frame for 10 periods)", out);

  // prepare, align and turn each wait on the stand until phase_deadline_
  if (!s_.observe && phase_ != Phase::Hold && t > phase_deadline_)
    return fail(t, "timeout: " + waiting_for_, out);
  switch (phase_) {
    case Phase::Hold: {
      const double rel = t - course_.t0_s;
      if (next_turn_ < s_.profile.turns.size()) {
        if (!s_.observe && rel >= s_.profile.turns[next_turn_].start_s) start_turn(t, out);
      } else if (rel >= s_.profile.duration_s) {
        may_move_ = false;
        enter(Phase::Estimate, t);
        out.emplace_back(RunEstimation{});
      }
      break;
    }
    case Phase::Turn:
      if (s_.observe) observe_motion(t);
      break;
    default:
      break;
  }
}

void Sequencer::start_turn(double t, std::vector<Command>& out) {
  const TurnSpec& turn = s_.profile.turns[next_turn_];
  const double target = angle_ + turn.angle_rad;
  if (!s_.limits.contains(target))
    return fail(t,
                "turn " + std::to_string(next_turn_ + 1) + ": target " + deg(target) +
                    " is outside the table's angle limits",
                out);
  ++next_turn_;
  enter(Phase::Turn, t, static_cast<int>(next_turn_));
  awaiting_what_ = "the move of turn " + std::to_string(next_turn_);
  move(t, out, turn.angle_rad, turn.max_rate_rps, turn.max_accel_rps2,
       "turn " + std::to_string(next_turn_) + " not in position");
  course_.turn_commanded_s.push_back(t);
}

void Sequencer::move(double t, std::vector<Command>& out, double delta, double rate, double accel,
                     const std::string& late) {
  table(TableCode::MoveRelative, t, out, delta, rate);
  target_ = angle_ + delta;
  move_delta_ = delta;
  TableMotion m;
  const double due =
      m.move_by(0, delta, rate, accel).t_end + s_.turn_margin_s + s_.real_time_floor_s;
  phase_deadline_ = t + due;
  phase_set_s_ = t;
  deadline_is_enable_ = false;
  waiting_for_ = late + " within " + std::to_string(static_cast<int>(std::lround(due))) + " s";
}

void Sequencer::on_table(const TableStatusEvent& e, std::vector<Command>& out) {
  const double t = e.t_s;
  last_fault_ = e.fault != 0 ? e.fault_name : std::string();
  const bool acked = awaiting_ack_ && e.ack == *awaiting_ack_;
  if (acked) awaiting_ack_.reset();
  if (stopping_) {
    // done when the table says it stopped: one of our quick stops
    // acknowledged, the table not moving, and its own rate at rest (an
    // acknowledgement alone is a table that has begun to stop); a rate not
    // known (NaN: a drive whose position data went quiet) is no rest
    const bool stop_acked = static_cast<std::uint8_t>(e.ack - stop_first_seq_) <=
                            static_cast<std::uint8_t>(seq_ - stop_first_seq_);
    const bool at_rest = std::abs(e.rate_rps) < kTableAtRestRps;
    if ((acked || stop_acked) && e.state != kMoving && at_rest) {
      course_.quick_stop_acked = true;
      stopping_ = false;
      may_move_ = false;
      enter(stop_then_, t);
    }
    return;
  }
  if (s_.observe || finished(phase_) || phase_ == Phase::Idle) return;
  table_heard_ = true;
  if (enable_pending_) {
    // the table as it is before we command it: a drive in fault or moving
    // is not enabled (a quick-stopped one is: enable clears it)
    if (e.state == kFault)
      return fail(t,
                  "table fault: " + (e.fault_name.empty() ? "unknown" : e.fault_name) +
                      ", found before the run commanded the table" + kUnseenFault,
                  out);
    if (e.state == kMoving)
      return fail(t, "the table is moving before the run commanded it: stop it at the stand", out);
    enable_pending_ = false;
    awaiting_what_ = "enable";
    table(TableCode::Enable, t, out);
    phase_deadline_ = t + enable_allowed_s();
    phase_set_s_ = t;
    deadline_is_enable_ = true;
    waiting_for_ = "the table not holding within " + seconds(enable_allowed_s()) + " s of enable";
    return;
  }
  const bool ours_acked = !awaiting_ack_ && e.ack == seq_;
  if (e.state == kFault)
    return fail(t,
                "table fault: " + (e.fault_name.empty() ? "unknown" : e.fault_name) +
                    // a drive first heard once enabled (a CANopen one starts
                    // up first) may show a fault from before the run
                    (deadline_is_enable_ ? std::string(", found while enabling it") + kUnseenFault
                                         : std::string()),
                out);
  if (e.state == kQuickStopped && ours_acked)
    return fail(t,
                "the table quick-stopped by itself" +
                    (e.fault != 0 ? " (" + e.fault_name + ")" : std::string()),
                out);
  if (!ours_acked) return;
  switch (phase_) {
    case Phase::Prepare:
      if (!enabled_) {
        if (e.state != kHolding && e.state != kInPosition) return;
        enabled_ = true;
        if (std::isnan(angle_)) {
          waiting_for_ = "no table encoder frame to start from";
          return;  // on_encoder goes on
        }
        prepare_move(t, out);
      } else if (prepare_moving_ && e.state == kInPosition) {
        if (const std::string off = off_target("the move to the start angle"); !off.empty())
          return fail(t, off, out);
        prepare_moving_ = false;
        may_move_ = false;
        rest_angle_ = target_;
        begin_align(t, out);
      }
      break;
    case Phase::Turn:
      if (e.state == kInPosition) {
        if (const std::string off = off_target(("turn " + std::to_string(index_)).c_str());
            !off.empty())
          return fail(t, off, out);
        may_move_ = false;
        rest_angle_ = target_;
        after_turn(t);
      }
      break;
    default:
      break;
  }
}

void Sequencer::prepare_move(double t, std::vector<Command>& out) {
  const double delta = wrap_pi(s_.start_angle_rad - angle_);
  if (std::abs(delta) < s_.start_tolerance_rad) return begin_align(t, out);
  const double target = angle_ + delta;
  if (!s_.limits.contains(target))
    return fail(t, "the start angle " + deg(s_.start_angle_rad) + " is outside the angle limits",
                out);
  prepare_moving_ = true;
  awaiting_what_ = "the move to the start angle";
  move(t, out, delta, std::min(s_.limits.max_rate_rps, s_.prepare_rate_rps),
       s_.limits.max_accel_rps2, "the table not at the start angle");
}

void Sequencer::begin_align(double t, std::vector<Command>& out) {
  enter(Phase::Align, t);
  if (s_.observe) return;
  double heading = std::fmod(s_.heading_offset_rad - angle_, 2 * kPi);
  if (heading < 0) heading += 2 * kPi;
  ++ins_seq_;
  out.emplace_back(
      InsCommand{InsCommandCode::StartAlignment, ins_seq_, s_.profile.align_s, heading});
  course_.heading_given_rad = heading;
  seen_aligning_ = false;
  const double allowed = s_.align_start_s + s_.real_time_floor_s;
  phase_deadline_ = t + allowed;
  phase_set_s_ = t;
  unsent_at_ = t;
  deadline_is_enable_ = false;
  waiting_for_ = "the INS not aligning within " + seconds(allowed) + " s of the command";
}

void Sequencer::on_ins(const InsModeEvent& e, std::vector<Command>& out) {
  const double t = e.t_s;
  const int was = ins_mode_;
  ins_mode_ = e.mode;
  if (stopping_ || finished(phase_) || phase_ == Phase::Idle) return;
  if (phase_ == Phase::Estimate || phase_ == Phase::Report) return;
  if (e.mode == kInsFault && phase_ != Phase::Prepare) return fail(t, "INS fault mode", out);
  switch (phase_) {
    case Phase::Prepare:
      // observe mode: the stand's own host starts the alignment
      if (s_.observe && e.mode == kAligning) enter(Phase::Align, t);
      if (s_.observe && e.mode == kNavigating && was == kAligning) {
        enter(Phase::Align, t);
        navigating(t);
      }
      break;
    case Phase::Align:
      if (e.mode == kAligning && !seen_aligning_) {
        seen_aligning_ = true;
        if (!s_.observe) {
          const double allowed = s_.profile.align_s + s_.align_margin_s + s_.real_time_floor_s;
          phase_deadline_ = t + allowed;
          phase_set_s_ = t;
          deadline_is_enable_ = false;
          waiting_for_ =
              "the INS not navigating within " + seconds(allowed) + " s of the alignment start";
        }
      }
      if (e.mode == kNavigating && (seen_aligning_ || s_.observe)) navigating(t);
      break;
    case Phase::Hold:
    case Phase::Turn:
      if (e.mode != kNavigating)
        return fail(t,
                    std::string("the INS left navigation (mode ") + std::to_string(e.mode) +
                        ") during " + to_string(phase_) + " " + std::to_string(index_),
                    out);
      break;
    default:
      break;
  }
}

void Sequencer::navigating(double t) {
  course_.t0_s = t;
  next_turn_ = 0;
  enter(Phase::Hold, t, 1);
  if (s_.observe) hold_angle_ = angle_;
}

void Sequencer::on_encoder(const EncoderEvent& e, std::vector<Command>& out) {
  angle_ = e.angle_rad;
  if (stopping_ || finished(phase_)) return;
  if (!s_.observe) {
    guard_encoder(e.t_s, out);
    if (stopping_ || finished(phase_)) return;
  }
  // enabled before the first encoder frame came: go on now
  if (!s_.observe && phase_ == Phase::Prepare && enabled_ && !prepare_moving_)
    return prepare_move(e.t_s, out);
  if (!s_.observe) return;
  if (phase_ == Phase::Hold) {
    if (std::isnan(hold_angle_)) hold_angle_ = angle_;
    if (std::abs(angle_ - hold_angle_) > s_.motion_threshold_rad) {
      ++next_turn_;
      enter(Phase::Turn, e.t_s, static_cast<int>(next_turn_));
      course_.turn_commanded_s.push_back(e.t_s);
      last_moving_t_ = e.t_s;
      moving_ref_ = angle_;
    }
  } else if (phase_ == Phase::Turn) {
    observe_motion(e.t_s);
  }
}

void Sequencer::guard_encoder(double t, std::vector<Command>& out) {
  if (phase_ == Phase::Idle || phase_ == Phase::Estimate || phase_ == Phase::Report) return;
  const double tol = s_.limits.position_tolerance_rad;
  if (!s_.limits.contains(angle_))
    return fail(t,
                "the table angle " + deg(angle_) + " is outside the angle limits (" +
                    deg(s_.limits.angle_min_rad) + " to " + deg(s_.limits.angle_max_rad) + ")",
                out);
  if (may_move_) {
    if (std::isnan(target_)) return;
    const double past = (move_delta_ >= 0 ? 1 : -1) * (angle_ - target_);
    if (past > tol)
      fail(t,
           (phase_ == Phase::Turn ? "turn " + std::to_string(index_)
                                  : std::string("the move to the start angle")) +
               ": overshoot, the table passed its target " + deg(target_) + " by " + deg(past),
           out);
    return;
  }
  if (!enabled_) return;
  if (std::isnan(rest_angle_)) rest_angle_ = angle_;  // at rest where it was enabled
  if (std::abs(angle_ - rest_angle_) > tol)
    fail(t,
         "the table moved " + deg(angle_ - rest_angle_) + " from " + deg(rest_angle_) +
             " with no move commanded",
         out);
}

std::string Sequencer::off_target(const char* what) const {
  if (std::isnan(target_) || std::isnan(angle_)) return {};
  const double off = angle_ - target_;
  if (std::abs(off) <= s_.limits.position_tolerance_rad) return {};
  return std::string(what) + ": the table reported in position " + deg(off) + " off its target " +
         deg(target_);
}

void Sequencer::observe_motion(double t) {
  if (std::isnan(angle_)) return;
  if (std::abs(angle_ - moving_ref_) > s_.motion_threshold_rad / 10) {
    moving_ref_ = angle_;
    last_moving_t_ = t;
    return;
  }
  if (t - last_moving_t_ >= s_.still_time_s) after_turn(last_moving_t_);
}

void Sequencer::after_turn(double t) {
  enter(Phase::Hold, t, static_cast<int>(next_turn_) + 1);
  hold_angle_ = angle_;
}

}  // namespace turncal::run
