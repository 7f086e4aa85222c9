#include "turncal/run/engine.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

#include "turncal/drivers/reference.hpp"
#include "turncal/icd.hpp"

namespace turncal::run {

namespace {

SequencerSettings with_commands(SequencerSettings s, const Ingest& in) {
  s.commands = command_signals(in.ins(), in.table());
  return s;
}

}  // namespace

CommandSignals command_signals(const InsDriver& ins, const TableDriver& table) {
  return {table.target(), table.rate_limit(), ins.align_duration()};
}

CommandSignals command_signals(const RoleMap& roles) {
  const auto ins = drivers::make_reference_ins(roles, {});
  const auto table = drivers::make_reference_table(roles, {});
  return command_signals(*ins, *table);
}

double real_time_floor_s(double floor_ms, double time_scale) {
  return time_scale > 1 ? floor_ms * 1e-3 * time_scale : 0.0;
}

double real_time_floor_s(const StandConfig& stand) {
  return real_time_floor_s(stand.real_time_floor_ms, stand.time_scale);
}

Plausibility plausibility_of(const Config& cfg) {
  Plausibility p;
  p.max_velocity_mps = cfg.can.max_ins_velocity_mps;
  p.max_table_rate_rps = 2 * cfg.stand.limits.max_rate_rps;
  p.max_fraction = cfg.can.implausible_fraction;
  // the host's scheduling latency, as for staleness, in stand time
  p.step_slack_s = std::max(0.05, cfg.daemon.stale_floor_ms * 1e-3) * cfg.stand.time_scale;
  return p;
}

Engine::Engine(const can::Database& db, const RoleMap& roles, Plan plan, SequencerSettings seq,
               BuildSettings build, TimeBase time, Plausibility plausibility)
    : Engine(db, drivers::make_reference_ins(roles, plausibility),
             drivers::make_reference_table(roles, plausibility), std::move(plan), std::move(seq),
             build, time, plausibility) {}

Engine::Engine(const can::Database& db, std::unique_ptr<InsDriver> ins,
               std::unique_ptr<TableDriver> table, Plan plan, SequencerSettings seq,
               BuildSettings build, TimeBase time, Plausibility plausibility)
    : plan_(std::move(plan)),
      build_(build),
      time_(time),
      ingest_(db, std::move(ins), std::move(table), plausibility),
      seq_(with_commands(std::move(seq), ingest_)),
      plausible_(plausibility) {
  // the record runs from t0 (the first velocity sample) to t0 + duration + 1 s
  record_.expect_span(plan_.profile.duration_s + 1.0);
  record_.set_time_scale(time_.scale, seq_.settings().real_time_floor_s);
}

void Engine::feed(const Event& e, std::vector<OutFrame>& out) {
  cmds_.clear();
  seq_.step(e, cmds_);
  // Commands are encoded checked, never saturated: a value that does not
  // fit its signal (the plan check should have refused it) sends nothing
  // and fails the run, with a quick stop.
  std::string unsent;
  for (const Command& c : cmds_) {
    if (const auto* t = std::get_if<TableCommand>(&c)) {
      auto frames = ingest_.table().command(*t);
      if (!frames) {
        unsent = "table command not sent: " + frames.error().message;
        break;
      }
      for (const can::Frame& f : *frames)
        out.push_back({false, f, t->code == TableCode::QuickStop});
      ++commands_sent_;
    } else if (const auto* i = std::get_if<InsCommand>(&c)) {
      auto frames = ingest_.ins().command(*i);
      if (!frames) {
        unsent = "INS command not sent: " + frames.error().message;
        break;
      }
      for (const can::Frame& f : *frames) out.push_back({true, f});
      ++commands_sent_;
    } else if (std::holds_alternative<RunEstimation>(c)) {
      estimation_due_ = true;
    } else if (std::holds_alternative<WriteReport>(c)) {
      report_due_ = true;
    }
  }
  if (unsent.empty()) return;
  if (seq_.phase() == Phase::Turn) unsent = "turn " + std::to_string(seq_.index()) + ": " + unsent;
  // a fault of the host: the run fails with the reason and a quick stop
  const double t = std::visit([](const auto& ev) { return ev.t_s; }, e);
  feed(HostFault{t, unsent}, out);
}

void Engine::start(std::int64_t now_ns, std::vector<OutFrame>& out) {
  const double t = stand_s(now_ns);
  // a protocol's own start (CANopen: NMT reset, configuration); an
  // observer sends nothing
  if (!seq_.settings().observe) {
    driver_frames_.clear();
    ingest_.table().start(t, driver_frames_);
    for (const can::Frame& f : driver_frames_) out.push_back({false, f});
  }
  feed(StartRequest{t}, out);
  driver_output(t, out);
}

void Engine::abort(std::int64_t now_ns, const std::string& reason, std::vector<OutFrame>& out) {
  feed(AbortRequest{stand_s(now_ns), reason}, out);
}

void Engine::signal(std::int64_t now_ns, const std::string& name, std::vector<OutFrame>& out) {
  feed(SignalEvent{stand_s(now_ns), name}, out);
}

void Engine::fault(std::int64_t now_ns, const std::string& what, std::vector<OutFrame>& out) {
  feed(HostFault{stand_s(now_ns), what}, out);
}

void Engine::end_of_input(std::int64_t now_ns, std::vector<OutFrame>& out) {
  record_complete_ = true;
  feed(EndOfInput{stand_s(now_ns)}, out);
}

void Engine::on_frame(const can::Frame& frame, std::int64_t time_ns, std::vector<OutFrame>& out) {
  const double t = stand_s(time_ns);
  const std::int64_t scaled_ns = round_half_away(t * 1e6) * 1000;
  const Sample s = ingest_.on_frame(frame, scaled_ns);
  last_frame_s_ = t;
  stamped(time_ns);
  if (!implausible_fed_) check_plausible(t, out);
  if (t > record_end_s()) record_complete_ = true;
  use(s, t, out);
  // a protocol's answers to the frame, and the samples it held back
  driver_output(Ingest::host_seconds(scaled_ns), out);
}

void Engine::driver_output(double host_s, std::vector<OutFrame>& out) {
  driver_frames_.clear();
  ingest_.table().take_frames(driver_frames_);
  for (const can::Frame& f : driver_frames_) out.push_back({false, f});
  for (Sample p = ingest_.poll(host_s); !std::holds_alternative<std::monostate>(p);
       p = ingest_.poll(host_s))
    use(p, host_s, out);
}

void Engine::use(const Sample& s, double t, std::vector<OutFrame>& out) {
  if (std::holds_alternative<std::monostate>(s)) return;
  const Phase p = seq_.phase();
  const bool running = p == Phase::Prepare || p == Phase::Align || p == Phase::Hold ||
                       p == Phase::Turn || p == Phase::Estimate;
  // The INS sends velocity only while it navigates (can-icd.md): before it
  // is seen aligning in this run, velocity is a previous navigation's (a
  // run right after another), not this run's, and must not become its t0.
  if (const auto* m = std::get_if<InsStatusSample>(&s);
      m != nullptr && running && m->mode == static_cast<int>(InsMode::Aligning))
    ins_aligning_seen_ = true;
  const bool old_navigation = std::holds_alternative<VelocitySample>(s) && !ins_aligning_seen_;
  if (running && !record_complete_ && !old_navigation) {
    record_.add(s);
    // samples of a clock that jumped are dropped; one that stays jumped
    // would leave the estimate without them, or with them at the wrong time
    if (!clock_fault_fed_ && record_.clock_faulted()) {
      clock_fault_fed_ = true;
      feed(HostFault{t, record_.clock_fault()}, out);
    }
  }
  if (const auto* v = std::get_if<VelocitySample>(&s)) {
    live_.ve = v->ve;
    live_.vn = v->vn;
  } else if (const auto* m = std::get_if<InsStatusSample>(&s)) {
    live_.ins_mode = m->mode;
    feed(InsModeEvent{m->host_s, m->mode}, out);
  } else if (const auto* e = std::get_if<EncoderSample>(&s)) {
    live_.table_angle_rad = e->angle_rad;
    feed(EncoderEvent{e->host_s, e->angle_rad}, out);
  } else if (const auto* ts = std::get_if<TableStatusSample>(&s)) {
    live_.table_state = ts->state;
    live_.table_rate_rps = ts->rate_rps;
    feed(TableStatusEvent{ts->host_s, ts->state, ts->ack, ts->fault, ts->fault_name, ts->rate_rps},
         out);
  }
}

/// A stream with more implausible frames than the configured fraction (of
/// 100 or more) is a device or a bus that garbles: the run fails.
void Engine::check_plausible(double t, std::vector<OutFrame>& out) {
  // with no implausible frame yet, no stream can have failed (the fraction
  // allowed is in [0, 1]: the config's range, and check_report's for a
  // live report's bound in a replay)
  if (ingest_.implausible_total() == 0) return;
  for (const Stream st : {kVelocity, kInsStatus, kEncoder, kTableStatus}) {
    const StreamHealth& h = ingest_.health(st);
    const bool on_end = h.implausible_run >= Plausibility::kMaxRun;
    if (!on_end && (h.frames < 100 || !(static_cast<double>(h.implausible) >
                                        plausible_.max_fraction * static_cast<double>(h.frames))))
      continue;
    implausible_fed_ = true;
    const char* what = st == kVelocity  ? " or the velocity bound"
                       : st == kEncoder ? " or stepping faster than the table can"
                                        : "";
    char b[200];
    if (on_end)
      std::snprintf(b, sizeof b,
                    "%s frames implausible: the last %llu on end outside their DBC range%s",
                    h.name.c_str(), static_cast<unsigned long long>(h.implausible_run), what);
    else
      std::snprintf(b, sizeof b,
                    "%s frames implausible: %llu of %llu (over %g%%) outside their DBC range%s",
                    h.name.c_str(), static_cast<unsigned long long>(h.implausible),
                    static_cast<unsigned long long>(h.frames), plausible_.max_fraction * 100, what);
    feed(HostFault{t, b}, out);
    return;
  }
}

double Engine::record_end_s() const {
  const double t0 = seq_.course().t0_s;
  return std::isnan(t0) ? std::numeric_limits<double>::infinity()
                        : t0 + plan_.profile.duration_s + 1.0;
}

void Engine::tick(std::int64_t now_ns, std::vector<OutFrame>& out, std::int64_t heard_until_ns) {
  const double t = stand_s(now_ns);
  // the stand has gone quiet past the end: nothing more will come
  if (t > record_end_s() + 1.0 && !(last_frame_s_ > t - 1.0)) record_complete_ = true;
  // the loop not run, and no frame stamped on any bus meanwhile: the
  // machine was held as a whole, the kernel too (a paused machine, a
  // virtual stand's). Frames stamped while only this process was held say
  // what the bus did: nothing to excuse then.
  if (t - prev_tick_s_ > seq_.settings().hold_s && !stamps_full_) {
    std::ranges::sort(stamps_);
    // silence is known up to now only if nothing stamped before it is unread
    const double known = std::min(t, stand_s(heard_until_ns));
    Hold widest{prev_tick_s_, prev_tick_s_};
    double from = prev_tick_s_;
    for (const double at : stamps_) {
      if (at > known) break;
      if (at - from > widest.to_s - widest.from_s) widest = {from, at};
      from = std::max(from, at);
    }
    if (known - from > widest.to_s - widest.from_s) widest = {from, known};
    if (widest.to_s - widest.from_s > seq_.settings().hold_s) note_hold(widest);
  }
  stamps_.clear();
  stamps_full_ = false;
  if (!(t < prev_tick_s_)) prev_tick_s_ = t;
  // a replay: from the first tick past a live hold's start, as the live
  // loop took it on its end (the frames the log holds inside it were read
  // after it)
  for (; next_replayed_hold_ < replayed_holds_.size() &&
         replayed_holds_[next_replayed_hold_].from_s < t;
       ++next_replayed_hold_)
    note_hold(replayed_holds_[next_replayed_hold_]);
  Tick k{t};
  const double floor = seq_.settings().stale_floor_s;
  // a stream's silence is judged up to what has been read, never past it:
  // frames stamped after the host's last read (it was preempted between
  // the read and this tick, and the stand sent meanwhile) are no silence
  const double heard = std::min(t, stand_s(heard_until_ns));
  k.velocity_stale = stale(kVelocity, heard, floor);
  k.velocity_quiet = stale(kVelocity, heard, 0);
  k.ins_status_stale = stale(kInsStatus, heard, floor);
  // a table protocol still starting up (CANopen's configuration) sends no
  // stream yet; from when it runs, or when its start-up has run out of
  // time, its streams have the floor to come
  const double due = ingest_.table().streams_due_s();
  k.table_starting = !(t >= due);
  const bool table_due = t - due > floor;
  k.encoder_stale = table_due && stale(kEncoder, heard, floor);
  k.table_status_stale = table_due && stale(kTableStatus, heard, floor);
  feed(k, out);
  // a protocol's timeouts and periodic frames (CANopen heartbeat, SYNC);
  // no heartbeat once the stop could not be confirmed: the table stops
  // itself on losing it
  ingest_.table().set_heartbeat(!seq_.course().quick_stop_gave_up);
  driver_frames_.clear();
  ingest_.table().tick(t, driver_frames_);
  for (const can::Frame& f : driver_frames_) out.push_back({false, f});
  driver_output(t, out);
}

void Engine::stamped(std::int64_t time_ns) {
  // only a hold (tick()) reads them: none without a hold length (a replay)
  if (!(seq_.settings().hold_s < std::numeric_limits<double>::infinity())) return;
  const double t = stand_s(time_ns);
  if (t <= prev_tick_s_) return;
  if (stamps_.size() < kMaxStamps)
    stamps_.push_back(t);
  else
    stamps_full_ = true;
}

void Engine::replay_holds(std::vector<Hold> holds) {
  replayed_holds_ = std::move(holds);
  next_replayed_hold_ = 0;
}

void Engine::note_hold(const Hold& h) {
  const double length = h.to_s - h.from_s;
  ++hold_count_;
  longest_hold_s_ = std::max(longest_hold_s_, length);
  last_hold_ = h;
  if (holds_.size() < kMaxHolds) holds_.push_back(h);
  // a machine held more than half the time is excused no more: a lost
  // stream would go unnoticed for as long (its silence judged as it is)
  window_holds_.push_back(h);
  while (window_holds_.front().to_s < h.to_s - kHoldWindowS) window_holds_.pop_front();
  double held = 0;  // of the last kHoldWindowS, excused or not
  for (const Hold& w : window_holds_)
    held += std::max(0.0, w.to_s - std::max(w.from_s, h.to_s - kHoldWindowS));
  if (held > kHoldWindowS / 2) {
    ++holds_unexcused_;
    return;
  }
  recent_holds_.push_back(h);
  while (recent_holds_.front().to_s < h.to_s - kHoldKeptS) recent_holds_.pop_front();
  seq_.held(h.from_s, h.to_s);
  ingest_.table().held(h.from_s, h.to_s);
}

double Engine::held_between(double from_s, double to_s) const {
  double held = 0;
  for (const Hold& h : recent_holds_)
    held += std::max(0.0, std::min(h.to_s, to_s) - std::max(h.from_s, from_s));
  return held;
}

bool Engine::stale(Stream s, double t, double floor_s) const {
  const StreamHealth& h = ingest_.health(s);
  return h.stale(t, floor_s, std::isnan(h.last_host_s) ? 0.0 : held_between(h.last_host_s, t));
}

std::vector<OutFrame> Engine::heartbeat() {
  std::vector<OutFrame> out;
  for (const can::Frame& f : ingest_.table().heartbeat(heartbeat_counter_++, seq_.host_state()))
    out.push_back({false, f});
  return out;
}

Result<BuiltInput> Engine::take_estimation_input() {
  estimation_due_ = false;
  record_.close();
  BuildSettings b = build_;
  const double hz = ingest_.health(kVelocity).nominal_hz;
  if (hz > 0) b.sample_rate_hz = hz;
  return build_input(record_, plan_, b);
}

void Engine::estimation_done(std::int64_t now_ns, bool ok, const std::string& error,
                             std::vector<OutFrame>& out) {
  feed(EstimationDone{stand_s(now_ns), ok, error}, out);
}

void Engine::report_written(std::int64_t now_ns, bool ok, const std::string& error,
                            std::vector<OutFrame>& out) {
  report_due_ = false;
  feed(ReportWritten{stand_s(now_ns), ok, error}, out);
}

}  // namespace turncal::run
