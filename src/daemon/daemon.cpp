// turncald's daemon (daemon.hpp): its run, the CAN ports, the report, the
// timer and the signals, and its setup.
#include "daemon.hpp"

#include <fcntl.h>
#include <grp.h>
#include <sys/ioctl.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <systemd/sd-daemon.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <numbers>
#include <sstream>
#include <system_error>
#include <utility>

#include "clients.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/html.hpp"
#include "turncal/run/report.hpp"

namespace turncal::daemon {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {
bool g_journal = false;  // under systemd: structured journal entries
}  // namespace

void log_to_journal(bool on) {
  g_journal = on;
}

void say(int priority, const std::string& run_id, const char* phase, const std::string& msg) {
  if (g_journal) {
    sd_journal_send("MESSAGE=%s", msg.c_str(), "PRIORITY=%d", priority, "RUN_ID=%s", run_id.c_str(),
                    "PHASE=%s", phase, "SYSLOG_IDENTIFIER=turncald", nullptr);
    return;
  }
  std::fprintf(stderr, "turncald: %s%s%s\n", run_id.empty() ? "" : run_id.c_str(),
               run_id.empty() ? "" : ": ", msg.c_str());
}

std::uint64_t monotonic_us() {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::uint64_t>(ts.tv_sec) * 1000000 +
         static_cast<std::uint64_t>(ts.tv_nsec) / 1000;
}

namespace {

/// recvmmsg calls of one socket per wakeup, kBatchFrames each: the budget
/// that lets the timers run under any flood
constexpr std::size_t kRxBatches = 4;
constexpr std::uint64_t kTxRetryUs = 5000;           ///< retry of a full device queue (ENOBUFS)
constexpr std::uint64_t kReportSlowUs = 10'000'000;  ///< a report's writing said to be slow after
constexpr int64_t kPrioTimers = SD_EVENT_PRIORITY_IMPORTANT;

/// The estimate's thread's nice value: below the loop's (0; the unit's -5).
constexpr int kEstimateNice = 10;

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string utc_id(std::int64_t ns) {
  const std::time_t s = static_cast<std::time_t>(ns / 1'000'000'000);
  std::tm tm{};
  gmtime_r(&s, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y%m%dT%H%M%SZ", &tm);
  return buf;
}

/// A run's planned length in real seconds: alignment and navigation, and a
/// minute for the INS to answer and the estimate.
double run_real_s(const Plan& plan, double time_scale) {
  constexpr double kMarginS = 60;
  return (plan.profile.align_s + plan.profile.duration_s + kMarginS) / time_scale;
}

std::size_t max_interface_chars(const CanConfig& c) {
  return std::max(c.ins_interface.size(), c.table_interface.size());
}

const char* link_name(socketcan::LinkState l) {
  switch (l) {
    case socketcan::LinkState::Up:
      return "up";
    case socketcan::LinkState::Down:
      return "down";
    case socketcan::LinkState::Gone:
      return "gone";
  }
  return "?";
}

}  // namespace

/// A step of the realtime clock is said once, with how far it stands from
/// the daemon's clock; nothing of the run moves with it.
void Daemon::tell_clock_steps() {
  clock.observe();
  if (clock.steps() == clock_steps_told) return;
  clock_steps_told = clock.steps();
  char b[160];
  std::snprintf(b, sizeof b,
                "the realtime clock stepped: it is now %+.3f s from the daemon's clock, which "
                "goes on with the monotonic clock (anchored again when a run starts)",
                static_cast<double>(clock.realtime_offset_ns()) * 1e-9);
  warn(b);
}

/// The holds of the host's machine since `before` (the engine's count), in
/// the journal: one line every 10 s at most, saying how many it stands for
/// (a machine held often would flood it); `flush`: the ones not yet said,
/// now (the run ends). The report lists them all.
void Daemon::tell_holds(std::uint64_t before, bool flush) {
  const std::uint64_t n = engine->hold_count();
  if (n != before) {
    holds_untold += n - before;
    const run::Engine::Hold h = engine->last_hold();
    holds_untold_longest_s = std::max(holds_untold_longest_s, h.to_s - h.from_s);
  }
  if (holds_untold == 0) return;
  const std::uint64_t now = monotonic_us();
  if (!flush && holds_told_us != 0 && now - holds_told_us < 10'000'000) return;
  const std::string what =
      holds_untold > 1 ? std::to_string(holds_untold) + " times since the last such line, at most"
                       : "for";
  char b[300];
  std::snprintf(b, sizeof b,
                "the machine was held %s %.0f ms (its loop not run, no frame stamped on any bus): "
                "no stream's silence counts that time",
                what.c_str(), holds_untold_longest_s / cfg.stand.time_scale * 1000);
  warn(b);
  holds_untold = 0;
  holds_untold_longest_s = 0;
  holds_told_us = now;
}

// ---- the log ----

void Daemon::log_record(const can::LogRecord& r) {
  if (!log) return;
  if (auto st = log->write(r); !st) log_fault(st.error().describe());
}

/// The log handed to the kernel, and its fsync asked of the syncer: the
/// loop goes on (a failure comes back on the timer, take_syncer_error).
void Daemon::log_sync() {
  if (!log) return;
  if (auto st = log->flush(); !st) return log_fault(st.error().describe());
  syncer.request(log->fd(), log->records_written());
}

/// A failed fsync: the lines handed to the kernel since the last good one
/// may never reach the disk, and the reason says which are sure.
void Daemon::take_syncer_error() {
  if (const int e = syncer.take_error(); e != 0) log_fault(fsync_fault(e, syncer.synced()));
}

/// A fault of the host fails the run with the reason (and a quick stop);
/// the log goes on.
void Daemon::host_fault(const std::string& what) {
  if (!running()) return;
  error("run failed: " + what);
  engine->fault(clock.now_ns(), what, out);
}

/// The log cannot be written: it is closed where it stands, so what it
/// holds replays, and the run fails; nothing of it is called done.
void Daemon::log_fault(const std::string& what) {
  if (!log_error.empty() || !engine) return;
  const std::string why = retire_log(what, log, retired_log);
  log_error = why;
  host_fault(why);
}

void Daemon::internal_error(const char* where, const char* what) {
  error(std::string("internal error in ") + where + ": " + what);
  if (running()) {
    try {
      engine->fault(clock.now_ns(), std::string("internal error in ") + where + ": " + what, out);
      send_out();
    } catch (...) {  // nothing more to do than to keep the loop
    }
  }
}

// ---- CAN ----

/// Our frames are logged when the kernel echoes them (on_can), never when
/// only queued; a dropped frame is counted, not logged.
void Daemon::send_out() {
  const bool any = !out.empty();
  // before the first write: no echo of ours is stamped earlier, so a hold
  // that starts at one still finds the waits set before it (Sequencer::held)
  const std::int64_t sending_at = any ? clock.now_ns() : 0;
  for (const run::OutFrame& o : out) {
    Port& p = port(o.ins_side);
    auto r = o.urgent ? p.sock->send_urgent(o.frame) : p.sock->send(o.frame);
    if (!r) {
      warn(r.error().describe());
    } else if (*r == socketcan::TxOutcome::Dropped) {
      warn(p.sock->interface() + ": a frame was dropped (" + link_name(p.sock->link()) +
           ", queue " + std::to_string(p.sock->tx_queue_depth()) + ")");
    }
  }
  out.clear();
  // the waits for what was sent run from now, not from the frames that
  // called for it: a backlog read late (a busy host) is the host's delay
  if (any && engine) engine->sent(sending_at);
  for (Port& p : ports)
    if (p.sock) update_io(p);
}

void Daemon::flush_port(Port& p) {
  if (!p.sock || !p.sock->tx_pending()) return;
  p.sock->flush();  // what goes out is logged on its echo
  update_io(p);
}

/// An interface usable again (re-opened, or up again): what waits goes out.
void Daemon::link_back(Port& p) {
  info(p.sock->interface() + " is back; " + std::to_string(p.sock->tx_queue_depth()) +
       " frame(s) waiting go out");
  flush_port(p);
}

/// EPOLLOUT while the socket's buffer holds frames back; the retry timer
/// while the device's queue does (ENOBUFS shows in no poll).
void Daemon::update_io(Port& p) {
  // frames that cannot be sent when the socket or the device takes them
  // again wait for ever: the run fails (and the table, unheard from, stops)
  const auto cannot = [&](const char* what, int rc) {
    if (p.io_fault_told) return;  // said once, until a call succeeds again
    p.io_fault_told = true;
    const std::string why = p.sock->interface() + ": cannot " + what +
                            " (sd-event: " + std::strerror(-rc) + "); frames to send would wait";
    if (running())
      host_fault(why);
    else
      error(why);
  };
  if (p.src) {
    const int rc = p.src.set_io_events(
        EPOLLIN | (p.sock->tx_wait() == socketcan::TxWait::Writable ? EPOLLOUT : 0U));
    if (rc < 0) return cannot("watch the socket for room to send", rc);
  }
  if (p.sock->tx_wait() == socketcan::TxWait::Retry && tx_retry) {
    int enabled = SD_EVENT_OFF;
    if (const int rc = tx_retry.enabled(enabled); rc < 0) return cannot("read the retry timer", rc);
    if (enabled == SD_EVENT_OFF) {
      std::uint64_t now = 0;
      int rc = sd_event_now(ev, CLOCK_MONOTONIC, &now);
      if (rc >= 0) rc = tx_retry.set_time(now + kTxRetryUs);
      if (rc >= 0) rc = tx_retry.set_enabled(SD_EVENT_ONESHOT);
      if (rc < 0) return cannot("arm the retry of a full device queue", rc);
    }
  }
  p.io_fault_told = false;
}

int on_can_io(sd_event_source*, int, uint32_t revents, void* u);

/// A socket re-opened by try_recover() has a new descriptor: a new source.
void Daemon::recover_ports() {
  for (Port& p : ports) {
    if (!p.sock || p.sock->link() == socketcan::LinkState::Up) continue;
    rx.clear();
    const bool up = p.sock->try_recover(rx);
    for (const auto& e : rx.events) warn(p.sock->interface() + ": " + can::describe(e));
    if (p.sock->fd() != p.registered_fd || p.sock->stats().recoveries != p.registered_generation) {
      p.registered_generation = p.sock->stats().recoveries;
      p.src.reset();
      p.registered_fd = p.sock->fd();
      if (p.registered_fd >= 0 &&
          sd_event_add_io(ev, p.src.out(), p.registered_fd, EPOLLIN, on_can_io, &p) < 0) {
        warn(p.sock->interface() + ": cannot watch the re-opened socket; trying again");
        p.src.reset();
        p.registered_fd = -1;  // tried again on the next tick
        continue;
      }
    }
    if (up) link_back(p);
  }
}

void Daemon::on_can(Port& p) {
  rx.clear();
  const std::uint64_t dropped = p.sock->stats().rx_dropped;
  // a read that drains the socket has heard every frame stamped before it
  // began, and none after: the host may be preempted between this read and
  // the tick that judges silence, while the stand sends
  const std::int64_t read_at = clock.now_ns();
  auto n = p.sock->receive(rx, kRxBatches);
  p.heard_until_ns = read_at;
  if (!n || !p.sock->drained() || p.sock->stats().rx_dropped != dropped) {
    std::int64_t last = std::numeric_limits<std::int64_t>::min();
    for (const can::TimedFrame& f : rx.frames) last = std::max(last, f.time_ns);
    for (const can::TimedFrame& f : rx.confirmed) last = std::max(last, f.time_ns);
    // a read that failed with nothing read says nothing of the bus: heard
    // up to its start, so a stream that has gone is found lost (never
    // frozen in the past, which would leave every loss unnoticed)
    p.heard_until_ns = last == std::numeric_limits<std::int64_t>::min() ? read_at : last;
  }
  if (!n) {
    warn(n.error().describe());
    return;
  }
  const std::string& iface = p.sock->interface();
  for (const auto& e : rx.events) {
    warn(iface + ": " + can::describe(e));
    if (e.kind == can::BusEventKind::InterfaceBack) link_back(p);
    if ((e.kind == can::BusEventKind::InterfaceDown ||
         e.kind == can::BusEventKind::InterfaceGone) &&
        running())
      host_fault("CAN interface " + iface + " " +
                 (e.kind == can::BusEventKind::InterfaceDown ? "went down" : "disappeared"));
  }
  // Our own frames' echoes too, in the order read: the log holds them so,
  // and a replay reads that log, so the engine sees what a replay will (a
  // SYNC dates the encoder samples that answer it by its echo).
  rx.in_order([&](const can::TimedFrame& f, bool /*echoed*/) {
    log_record({f.time_ns, iface, f.frame});
    if (engine) engine->on_frame(f, out);
  });
  if (log) {
    if (auto st = log->flush(); !st) log_fault(st.error().describe());
  }
  if (p.sock->link() != socketcan::LinkState::Up && p.src && p.sock->fd() < 0) {
    p.src.reset();  // gone: recovered on the timer
    p.registered_fd = -1;
  }
  after_engine();
}

json Daemon::can_json(bool since_run_start) const {
  json can = json::object();
  for (const Port& p : ports) {
    if (!p.sock) continue;
    const socketcan::Stats& s = p.sock->stats();
    const socketcan::Stats z = since_run_start ? p.at_run_start : socketcan::Stats{};
    can[p.sock->interface()] = {
        {"link", link_name(p.sock->link())},
        {"rx_frames", s.rx_frames - z.rx_frames},
        {"rx_dropped", s.rx_dropped - z.rx_dropped},
        {"tx_frames", s.tx_frames - z.tx_frames},
        {"tx_confirmed", s.tx_confirmed - z.tx_confirmed},
        {"tx_queue_depth", p.sock->tx_queue_depth()},
        {"tx_queued", s.tx_queued - z.tx_queued},
        {"tx_dropped", (s.tx_overflow - z.tx_overflow) + (s.tx_failed - z.tx_failed)},
        {"tx_superseded", s.tx_superseded - z.tx_superseded},
        {"recoveries", s.recoveries - z.recoveries}};
  }
  return can;
}

// ---- the run ----

void Daemon::after_engine() {
  send_out();  // the heartbeat goes out between runs too
  if (!engine) return;
  const std::vector<std::string>& notices = engine->ingest().table().notices();
  for (; table_notices_logged < notices.size(); ++table_notices_logged)
    warn("table: " + notices[table_notices_logged]);
  const run::Phase p = engine->sequencer().phase();
  if (p != last_phase) {
    last_phase = p;
    const int idx = engine->sequencer().index();
    info(std::string("phase ") + run::to_string(p) + (idx > 0 ? " " + std::to_string(idx) : "") +
         (engine->sequencer().course().reason.empty()
              ? ""
              : " (" + engine->sequencer().course().reason + ")"));
    sd_notifyf(0, "STATUS=%s %s", run_id.c_str(), run::to_string(p));
    log_sync();  // each phase end is on disk
    // a run that ended has its report on disk before a watcher hears it
    // ended (broadcast_watch waits for the report being written)
    if (run::finished(p) && !report_done) write_report(false);
    broadcast_watch();
  }
  if (engine->estimation_due() && !worker_busy) {
    auto in = engine->take_estimation_input();
    if (!in) {
      engine->estimation_done(clock.now_ns(), false, in.error().describe(), out);
      return after_engine();
    }
    input = std::move(*in);
    if (worker.joinable()) worker.join();
    worker_busy = true;  // before the thread starts: it reads input from its first line
    try {
      worker = std::thread([this] {
        // below the loop: on a stand PC of one core the heartbeat, the
        // watchdog and a quick stop go before the estimate (a thread's
        // nice value is its own on Linux; raising it needs no privilege)
        estimate_nice_errno =
            ::setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), kEstimateNice) != 0 ? errno
                                                                                           : 0;
        try {
          auto r = est::estimate(input->input);
          if (r) {
            result = std::move(*r);
          } else {
            est_error = r.error().describe();
          }
        } catch (const std::exception& e) {
          est_error = std::string("internal error: ") + e.what();
        }
        const char c = 1;
        while (::write(done_pipe[1], &c, 1) < 0 && errno == EINTR) {
        }
      });
    } catch (const std::exception& e) {  // no thread (TasksMax, memory)
      worker_busy = false;
      engine->estimation_done(clock.now_ns(), false,
                              std::string("cannot start the estimation: ") + e.what(), out);
      return after_engine();
    }
  }
  if (engine->report_due() && !report_done) write_report(true);  // report_written() goes on
  if (run::finished(p) && !report_done) write_report(false);
}

/// The report, on disk before the run is called done: a report that cannot
/// be written leaves log_error set, and the run ends failed with it. What
/// needs the run is taken here, on the loop; the disk's part is the report
/// thread's (report_writer.hpp), and report_written() ends it.
void Daemon::write_report(bool with_estimates) {
  report_done = true;
  report_busy = true;  // until report_written(), whatever happens here
  report_since_us = monotonic_us();
  report_slow_told = false;
  const auto inline_or_none = [&](const char* what) {
    try {
      error(std::string("the report: ") + what +
            (report_job ? "; it is written on the loop" : "; no report is written"));
    } catch (...) {  // no memory to say it: the report still ends the run
    }
    if (report_job) write_report_job(*report_job, syncer, *state);  // noexcept
    report_written();
  };
  try {
    start_report(with_estimates);
  } catch (const std::exception& e) {  // no thread (TasksMax, memory), or no memory
    inline_or_none(e.what());
  } catch (...) {
    inline_or_none("unknown exception");
  }
}

void Daemon::start_report(bool with_estimates) {
  tell_holds(engine->hold_count(), true);  // the run's last ones, said before its end
  state->release(run_id);                  // the space the report was kept
  auto job = std::make_unique<ReportJob>();
  run::ReportContext ctx;
  ctx.run_id = run_id;
  ctx.start_unix_s = static_cast<double>(run_start_ns) * 1e-9;
  ctx.end_unix_s = static_cast<double>(clock.now_ns()) * 1e-9;
  ctx.software_version = run::software_version();
  ctx.config_file = cfg.source.string();
  ctx.config_sha256 = config_sha256;
  ctx.log_file = log_path.filename().string();
  ctx.tolerances = cfg.tolerances;
  ctx.mode = engine->sequencer().settings().observe ? "observe" : "command";
  ctx.unit = unit;
  ctx.can = can_json(true);
  // the estimate is done when the report is due after it
  const bool est = with_estimates && result && input && log_error.empty();
  if (est) job->with = run::report_json(ctx, *engine, &*input, &*result);
  job->without = run::report_json(ctx, *engine, nullptr, nullptr);
  // the run's times are the realtime clock at its start plus monotonic time
  job->host_clock = {{"realtime_steps", clock.steps()},
                     {"realtime_offset_s", static_cast<double>(clock.realtime_offset_ns()) * 1e-9},
                     {"unknown_stamps", clock.unknown_stamps()}};
  job->run_id = run_id;
  job->log_path = log_path.string();
  job->with_estimates = with_estimates;
  job->log_error = log_error;
  job->log = std::move(log);  // no more of the run goes into it
  log.reset();
  job->retired_log = std::move(retired_log);
  retired_log.reset();
  if (est) {  // the job's now: the HTML report draws them
    job->input = std::move(input);
    job->result = std::move(result);
    input.reset();
    result.reset();
  }
  report_job = std::move(job);
  report_thread = std::thread([this, job = report_job.get()] {
    write_report_job(*job, syncer, *state);
    const char c = 1;
    while (::write(report_pipe[1], &c, 1) < 0 && errno == EINTR) {
    }
  });
}

/// The report thread's end, on the loop: the index, the journal, and the
/// run's end.
void Daemon::report_written() {
  if (report_thread.joinable()) report_thread.join();
  std::unique_ptr<ReportJob> job = std::move(report_job);
  report_busy = false;
  // the report phase's end (the engine waits for it), or a finished run's report
  const bool with_estimates =
      job ? job->with_estimates : engine && engine->sequencer().phase() == run::Phase::Report;
  if (!job) {  // none could be made: the run ends failed, its log kept as it stands
    if (log_error.empty())
      log_error = "report not written: it could not be made (the journal says why)";
    syncer.wait_idle();
    (void)syncer.take_error();  // this run's, failed already: not the next run's
    if (log) (void)log->close();
    log.reset();
    if (retired_log) (void)retired_log->close();
    retired_log.reset();
  } else {
    log_error = job->log_error;
    try {  // the index and the journal; nothing here may keep the run from its end
      for (const std::string& e : job->errors) error(e);
      if (job->report_error.empty()) {
        state->index_report(job->run_id, job->written);
        info("report written: " + (state->path() / (job->run_id + ".report.json")).string());
      } else {
        error("report not written: " + job->report_error);
      }
    } catch (const std::exception& e) {
      warn(std::string("the report is on disk, not yet in the index: ") + e.what());
    } catch (...) {
    }
  }
  // the run's samples (most of its memory) are in the report now, or the
  // run failed: a service that idles between runs need not hold them (but
  // the estimation worker may still read them: then on_worker_done frees them)
  if (!worker_busy) {
    input.reset();
    result.reset();
  }
  job.reset();
  if (!engine) return;
  if (with_estimates)
    engine->report_written(clock.now_ns(), log_error.empty(), log_error, out);
  else
    broadcast_watch();  // the run's end, its report on disk now
  after_engine();
}

/// A log with no report: a run that was killed. Its log replays up to that
/// moment; the report says so.
void Daemon::report_interrupted_runs() {
  const LogsWithoutReport left = state->logs_without_report();
  for (const std::string& what : left.skipped)
    say(LOG_WARNING, "", "start", "in the state directory, " + what);
  for (const std::string& id : left.runs) {
    const fs::path log_file = state->path() / (id + ".log");
    // a write the kill cut short leaves part of a line: no frame, cut off
    // (and said at once, so a failure below leaves the cut on record); a
    // tail that is no such part stays, and the report says so
    const TailCut c = state->cut_torn_tail(id);
    const std::string torn_text = printable_bytes(c.bytes);  // whatever the kill left
    std::string torn;
    if (!c.bytes.empty()) {
      torn = "; the part of a line the stop cut short (" + std::to_string(c.bytes.size()) +
             " bytes, no frame) was cut off its log";
      say(LOG_WARNING, id, "interrupted",
          "cut the last " + std::to_string(c.bytes.size()) +
              " bytes of its log, part of a line a kill cut short: \"" + torn_text + "\"");
    }
    if (!c.error.empty()) torn += "; its log's end: " + c.error;
    if (!c.regular) {
      // not opened as a regular file (gone, unreadable, or replaced since
      // the directory was read): nothing to digest, and never a blocking read
      say(LOG_WARNING, id, "interrupted", "no report: " + c.error);
      continue;
    }
    auto dg = run::sha256_file(log_file.string(), run::CountLines::Yes, run::Links::Refuse);
    if (!dg) {
      say(LOG_WARNING, id, "interrupted", "no report: " + dg.error().describe() + torn);
      continue;
    }
    const std::uint64_t lines = dg->lines.value_or(0);  // counted: asked for
    json log_j = {{"file", id + ".log"},
                  {"sha256", dg->sha256},
                  {"lines", lines},
                  {"torn_bytes_cut", c.bytes.size()}};
    if (!c.bytes.empty()) log_j["torn_tail"] = torn_text;
    const json j = {{"format", "turncal-report-1"},
                    {"schema_version", run::kReportSchemaVersion},
                    {"run_id", id},
                    {"status", "interrupted"},
                    {"reason", "the daemon stopped during the run (killed or crashed)" + torn},
                    {"log", std::move(log_j)},
                    {"verdict", {{"pass", false}, {"checks", json::array()}}}};
    if (auto w =
            state->write_report(id, j, run::report_text(j), run::report_html(j, nullptr, nullptr));
        !w)
      say(LOG_ERR, id, "interrupted", "report not written: " + w.error().describe());
    say(LOG_WARNING, id, "interrupted",
        "run " + id + " was interrupted; its log (" + std::to_string(lines) + " frames) is kept" +
            torn);
  }
}

namespace {

/// Whether there is a socket at `path` (false: nothing); anything else
/// there (a file, a folder, a link) is an error: never replaced.
Result<bool> socket_or_nothing(const std::string& path) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return false;
    return make_error("cannot stat the control socket " + path + ": " + std::strerror(errno));
  }
  if (S_ISSOCK(st.st_mode)) return true;
  const char* what = S_ISLNK(st.st_mode)   ? "a symbolic link"
                     : S_ISDIR(st.st_mode) ? "a directory"
                                           : "a file that is no socket";
  return make_error("the control socket " + path + " is " + what + "; not replaced");
}

/// Whether something listens on the Unix socket at `path`: nothing there
/// is free; anything but a socket is never bound over (a rename would
/// replace it: a configuration that names a file by mistake loses no file);
/// a socket is asked by a connect that sends nothing. Its ECONNREFUSED (no
/// one listens: taken for a stale one, a daemon's that died) is free, its
/// success or wait (a full backlog) a listener, and any other failure (no
/// right to connect, not a stream socket) cannot tell: an error. Under an
/// idle turncald.socket the connect starts the service, the socket's owner.
Result<bool> something_listens(const std::string& path) {
  sockaddr_un a{};
  if (path.size() >= sizeof a.sun_path)
    return make_error("socket path too long: " + path + " (at most " +
                      std::to_string(sizeof a.sun_path - 1) + " characters)");
  TURNCAL_ASSIGN(is_socket, socket_or_nothing(path));
  if (!is_socket) return false;
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return make_error(std::string("socket(AF_UNIX): ") + std::strerror(errno));
  a.sun_family = AF_UNIX;
  std::memcpy(a.sun_path, path.c_str(), path.size());
  const int rc = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  const int err = errno;
  (void)::close(fd);  // a probe: nothing sent
  if (rc == 0 || err == EAGAIN || err == EINPROGRESS) return true;
  if (err == ECONNREFUSED || err == ENOENT) return false;  // ENOENT: gone since the stat
  return make_error("cannot tell whether something listens on the control socket " + path + ": " +
                    std::strerror(err) + "; not bound over it");
}

/// The refusal when something listens on `path`.
Status refuse_listened(const std::string& path) {
  return make_error("the control socket " + path +
                    " has a listener already (turncald.socket, whose service this check may have "
                    "started, or a daemon of another configuration); one daemon per socket");
}

}  // namespace

Status Daemon::claim_socket() {
  const std::string path = cfg.daemon.socket.string();
  std::error_code ec;
  // (a bare name is in the working directory: nothing to create)
  if (!cfg.daemon.socket.parent_path().empty())
    fs::create_directories(cfg.daemon.socket.parent_path(), ec);
  if (ec)
    return make_error("cannot create the control socket's directory " +
                      cfg.daemon.socket.parent_path().string() + ": " + ec.message());
  // what is no socket is refused before a lock file is made beside it
  TURNCAL_TRY(socket_or_nothing(path));
  const std::string lock = path + ".lock";
  TURNCAL_ASSIGN(held, take_lock(lock, "the control socket " + path +
                                           " is another process's (another turncald?): its lock " +
                                           lock + " is taken; one daemon per socket"));
  socket_lock = std::move(held);
  TURNCAL_ASSIGN(listened, something_listens(path));
  if (listened) return refuse_listened(path);
  return Status{Ok{}};
}

json Daemon::status() const {
  json j = {{"ok", true}, {"phase", phase_name()}, {"run_id", run_id}};
  // what the sockets did since the daemon started, and what waits or was lost
  j["can"] = can_json(false);
  if (!engine) return j;
  const auto& s = engine->sequencer();
  const double now = engine->stand_s(clock.now_ns());
  j["index"] = s.index();
  j["elapsed_s"] = s.course().marks.empty() ? 0.0 : now - s.course().marks.front().t_s;
  const double rem = s.remaining_s(now);
  j["remaining_s"] = std::isnan(rem) ? json(nullptr) : json(rem);
  j["duration_s"] = engine->plan().profile.duration_s;
  if (!s.course().reason.empty()) j["reason"] = s.course().reason;
  const auto& l = engine->live();
  auto num = [](double v) { return std::isnan(v) ? json(nullptr) : json(v); };
  j["ve"] = num(l.ve);
  j["vn"] = num(l.vn);
  j["table_angle_deg"] = num(l.table_angle_rad * 180 / M_PI);
  j["ins_mode"] = l.ins_mode;
  j["table_state"] = l.table_state;
  json h = json::object();
  for (int k = 0; k < run::kStreams; ++k) {
    const auto& sh = engine->ingest().health(static_cast<run::Stream>(k));
    h[sh.name] = {
        {"rate_hz", sh.rate_hz()},
        {"dropped", sh.dropped},
        {"stale", engine->stale(static_cast<run::Stream>(k), now, s.settings().stale_floor_s)}};
  }
  j["health"] = h;
  return j;
}

/// The plan a start names: the operator's text, a name in the profiles
/// directory, or the configured default; never a path a client names.
/// `from`: where it came from.
Result<Plan> Daemon::plan_of(const StartRequest& req, std::string& from) const {
  if (!req.plan_text.empty()) {
    from = req.plan_name + " (sent by the client)";
    return parse_plan(req.plan_text, req.plan_name);
  }
  if (!req.plan_name.empty()) {
    const std::string file =
        req.plan_name.ends_with(".toml") ? req.plan_name : req.plan_name + ".toml";
    const fs::path p = cfg.daemon.profiles_directory / file;
    from = p.string();
    std::error_code ec;
    if (!fs::is_regular_file(p, ec))
      return make_error("no plan '" + req.plan_name + "' in the profiles directory " +
                        cfg.daemon.profiles_directory.string());
    return load_plan(p.string());
  }
  from = cfg.daemon.profile.string();
  return load_plan(from);
}

json Daemon::start(const StartRequest& req) {
  if (stopping) return {{"ok", false}, {"error", "turncald is stopping: no new run"}};
  if (running()) return {{"ok", false}, {"error", "a run is in progress: " + run_id}};
  if (worker_busy) return {{"ok", false}, {"error", "the last run's estimation is still running"}};
  if (report_busy)
    return {{"ok", false}, {"error", "the last run's report is still being written"}};
  if (engine && engine->sequencer().course().quick_stop_gave_up) {
    // the last run never saw its quick stop confirmed: no new run until the
    // table itself says it is at rest
    const run::Live& l = engine->live();
    if (l.table_state == 2 || l.table_state < 0 || !(std::abs(l.table_rate_rps) < 1e-3)) {
      char why[200];
      std::snprintf(why, sizeof why,
                    "the last run's quick stop was never confirmed and the table does not report "
                    "rest (state %d, rate %.3f deg/s): stop it at the stand",
                    l.table_state, l.table_rate_rps * 180 / std::numbers::pi);
      return {{"ok", false}, {"error", why}};
    }
  }
  std::string from;
  Result<Plan> plan = plan_of(req, from);
  if (!plan) return {{"ok", false}, {"error", plan.error().describe()}};
  run::SequencerSettings q;
  q.profile = plan->profile;
  q.start_angle_rad = plan->start_angle_rad;
  q.heading_offset_rad = cfg.stand.heading_offset_rad;
  q.limits = cfg.stand.limits;
  q.observe = cfg.daemon.observe || req.observe;
  q.stale_floor_s = cfg.daemon.stale_floor_ms * 1e-3 * cfg.stand.time_scale;
  q.real_time_floor_s = run::real_time_floor_s(cfg.stand);
  // held: a tick of the loop missed, and more than half the floor (stand
  // seconds); the journal hears of holds once every 10 s at most
  q.hold_s = std::max(2 / cfg.daemon.heartbeat_hz, q.stale_floor_s / 2);
  if (req.heading_offset_deg)
    q.heading_offset_rad = *req.heading_offset_deg * std::numbers::pi / 180;
  {
    // refused before a log is opened or a run id given: nothing to record
    run::SequencerSettings checked = q;
    {
      const drivers::Devices dev = drivers::make_devices(cfg.can, roles, {}, 1);
      checked.commands = run::command_signals(*dev.ins, *dev.table);
    }
    if (const std::string bad = run::check_plan(checked); !bad.empty())
      return {{"ok", false}, {"error", "plan refused: " + bad}};
  }
  const std::string unit_id = req.unit.value_or(cfg.stand.unit);
  if (engine) {
    q.table_seq_base = static_cast<std::uint8_t>(engine->commands_sent() + 100);
    q.ins_seq_base = q.table_seq_base;
  }
  // each run on the realtime clock as it reads now, and monotonic from here
  clock.anchor();
  clock_steps_told = 0;
  const std::int64_t now = clock.now_ns();
  std::string id = utc_id(now);
  // two runs within a second: the second gets a suffix, no log is overwritten
  // (a report too: retention may have taken the log of an old run)
  for (int k = 2; state->has_log(id) || state->index().contains(id); ++k)
    id = utc_id(now) + "-" + std::to_string(k);
  const fs::path path = state->path() / (id + ".log");
  // retention first, then the space: the report's and the planned log's
  const Retention keep{cfg.daemon.keep_logs_days,
                       static_cast<std::uint64_t>(cfg.daemon.max_logs_mib * 1024 * 1024)};
  for (const PrunedLog& p : state->prune_logs(keep, static_cast<double>(now) * 1e-9)) {
    char b[200];
    std::snprintf(b, sizeof b, "retention: %s the log of run %s (%.1f MiB, %s)%s%s",
                  p.error.empty() ? "removed" : "cannot remove", p.run_id.c_str(),
                  static_cast<double>(p.bytes) / (1 << 20), p.why.c_str(),
                  p.error.empty() ? "; its report is kept" : ": ", p.error.c_str());
    p.error.empty() ? info(b) : warn(b);
  }
  const auto reserve_bytes =
      static_cast<std::uint64_t>(cfg.daemon.report_reserve_mib * 1024 * 1024);
  if (const double rate = bus_rate.per_s(); rate > 0) {
    const double real_s = run_real_s(*plan, cfg.stand.time_scale);
    const double per_frame = static_cast<double>(log_bytes_bound(1, max_interface_chars(cfg.can)));
    if (const std::string why = space_shortfall(rate, per_frame, real_s, reserve_bytes);
        !why.empty())
      return {{"ok", false}, {"error", "run refused: " + why}};
  }
  if (auto rs = state->reserve(id, reserve_bytes); !rs)
    return {{"ok", false}, {"error", rs.error().describe()}};
  auto w = can::LogWriter::open(path.string());
  if (!w) {
    state->release(id);
    return {{"ok", false}, {"error", w.error().describe()}};
  }
  run_start_ns = now;
  next_space_check_s = 0;
  syncer.wait_idle();  // the last run's are done (its report waited for them)
  syncer.new_file();
  run_id = id;
  log_path = path;
  log.emplace(std::move(*w));
  log_error.clear();
  unit = unit_id;
  for (Port& p : ports)
    if (p.sock) p.at_run_start = p.sock->stats();
  run::BuildSettings b;
  b.heading_offset_rad = q.heading_offset_rad;
  drivers::Devices dev =
      drivers::make_devices(cfg.can, roles, run::plausibility_of(cfg), cfg.stand.time_scale);
  engine = std::make_unique<run::Engine>(db, std::move(dev.ins), std::move(dev.table), *plan, q, b,
                                         run::TimeBase{now / 1000, cfg.stand.time_scale},
                                         run::plausibility_of(cfg));
  holds_untold = 0;  // the last run's, if any, were said with its report
  holds_untold_longest_s = 0;
  input.reset();
  result.reset();
  est_error.clear();
  report_done = false;
  last_phase = run::Phase::Idle;
  table_notices_logged = 0;
  info("run started: " + plan->name + " from " + from + (unit.empty() ? "" : ", unit " + unit));
  engine->start(now, out);
  after_engine();
  return {{"ok", true}, {"run_id", run_id}, {"log", log_path.string()}};
}

/// Every frame the sockets have received or seen confirmed: what the log takes.
std::uint64_t Daemon::frames_seen() const {
  std::uint64_t n = 0;
  for (const Port& p : ports)
    if (p.sock) n += p.sock->stats().rx_frames + p.sock->stats().tx_confirmed;
  return n;
}

/// Why the state directory cannot hold `real_s` more of a log growing at
/// `frames_per_s` frames of `bytes_per_frame`, and `also` bytes more; empty
/// when it can.
std::string Daemon::space_shortfall(double frames_per_s, double bytes_per_frame, double real_s,
                                    std::uint64_t also) const {
  const auto free = state->free_bytes();
  if (!free) {  // not a shortfall: said, and looked at again
    warn(free.error().describe());
    return {};
  }
  const double log_bytes = std::max(0.0, frames_per_s * bytes_per_frame * real_s);
  const double need = log_bytes + static_cast<double>(also);
  if (static_cast<double>(*free) >= need) return {};
  constexpr double kMiB = 1 << 20;
  char b[400];
  std::snprintf(b, sizeof b,
                "the state directory %s has %.2f MiB free; the run needs %.2f MiB: %.2f MiB of "
                "log (%.0f s more at the %.0f frames/s the bus has had)",
                state->path().c_str(), static_cast<double>(*free) / kMiB, need / kMiB,
                log_bytes / kMiB, real_s, frames_per_s);
  std::string why = b;
  if (also > 0) {
    std::snprintf(b, sizeof b, " and %.2f MiB kept for its report",
                  static_cast<double>(also) / kMiB);
    why += b;
  }
  return why;
}

/// From 3 s into a run and every 10 s after, the log it will still write
/// must fit, at the faster of its own mean frame rate and the bus's over
/// the last 10 s (the INS sends more once it navigates): else the run
/// fails now, before the disk is full. A start checks the same at the rate
/// of the bus before it, when it has one. (Not more often: statvfs is a
/// system call on the loop, and where it is slow, as on user-mode Linux's
/// host file system, every one delays a heartbeat.)
void Daemon::check_run_space() {
  constexpr double kSpaceCheckS = 10;
  if (!running() || !log || log->records() == 0) return;
  const double elapsed_s = static_cast<double>(clock.now_ns() - run_start_ns) * 1e-9;
  if (elapsed_s < 3.0 || elapsed_s < next_space_check_s) return;
  next_space_check_s = elapsed_s + kSpaceCheckS;
  const double left_s = run_real_s(engine->plan(), cfg.stand.time_scale) - elapsed_s;
  if (!(left_s > 0)) return;
  const double mean_rate = static_cast<double>(log->records()) / elapsed_s;
  const double recent = bus_rate.per_s();
  const double rate = std::isnan(recent) ? mean_rate : std::max(mean_rate, recent);
  const double per_frame = static_cast<double>(log->bytes()) / static_cast<double>(log->records());
  if (const std::string why = space_shortfall(rate, per_frame, left_s, 0); !why.empty())
    host_fault("the disk cannot hold this run's log: " + why);
}

// ---- sd-event callbacks ----

int Daemon::on_can_io(sd_event_source*, int, uint32_t revents, void* u) {
  auto* p = static_cast<Port*>(u);
  Daemon* d = p->owner;
  return guarded(d, "CAN", [&] {
    if (revents & EPOLLOUT) d->flush_port(*p);
    if (revents & (EPOLLIN | EPOLLERR)) d->on_can(*p);
  });
}

int Daemon::on_tx_retry(sd_event_source*, uint64_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  return guarded(d, "CAN send", [&] {
    for (Port& p : d->ports) d->flush_port(p);
  });
}

/// A reload (SIGHUP: `systemctl reload turncald`, and the package's
/// postinst after an upgrade): the configuration and the program are read
/// when turncald starts, so a socket-activated turncald exits once idle and
/// its socket starts it anew, as installed then, on the next request. A run
/// goes on with what it started with.
void Daemon::ask_reload() {
  if (!socket_activated) {
    warn(
        "SIGHUP ignored: not started by its systemd socket, nothing would start turncald "
        "again; restart it by hand when no run is under way");
    return;
  }
  exit_when_idle = true;
  if (running() || busy())
    info(
        "reload asked: turncald exits when this run has ended, and its socket starts it anew "
        "on the next request");
  else
    info("reload asked");  // the next tick says what it does
}

/// Idle for a reload: no run, no estimate, no frame waiting to go out, no
/// connection made or heard from in the last second, no request part read
/// or unread on one, no reply unsent. Never with a quick stop unconfirmed:
/// that refusal of new runs, and the withheld heartbeat, live in this
/// process only (a restart, by hand, is the operator's call). Without a
/// reload asked for, a program replaced on disk (an upgrade whose reload
/// did not come) is said once.
void Daemon::exit_if_reloading() {
  if (stopping || running() || busy()) return;
  const std::uint64_t now = monotonic_us();
  if (!exit_when_idle) {
    if (replaced_told || now - replaced_checked_us < 10'000'000) return;
    replaced_checked_us = now;
    std::array<char, 4096> exe{};
    const ssize_t n = ::readlink("/proc/self/exe", exe.data(), exe.size() - 1);
    if (n > 0 && std::string(exe.data(), static_cast<std::size_t>(n)).ends_with(" (deleted)")) {
      warn(
          "this program was replaced on disk (an upgrade?) and runs on as it was: `systemctl "
          "reload turncald` starts the new one once no run is in progress");
      replaced_told = true;
    }
    return;
  }
  if (engine && engine->sequencer().course().quick_stop_gave_up) {
    warn(
        "reload refused: the last run's quick stop was never confirmed; check the table, then "
        "restart turncald");
    exit_when_idle = false;
    return;
  }
  for (const Port& p : ports)
    if (p.sock && p.sock->tx_pending()) return;
  for (const auto& c : clients) {
    int unread = 0;
    if (now - c->last_request_us < 1'000'000 || !c->in.empty() || !c->out.empty() ||
        ::ioctl(c->fd, FIONREAD, &unread) != 0 || unread > 0)
      return;
  }
  info("reloading: exiting, idle; the socket starts turncald anew on the next request");
  stopping = true;
  sd_notify(0, "STOPPING=1");
  sd_event_exit(ev, 0);
}

int Daemon::on_timer(sd_event_source* s, uint64_t usec, void* u) {
  auto* d = static_cast<Daemon*>(u);
  const double period_s = 1.0 / (d->cfg.daemon.heartbeat_hz * d->cfg.stand.time_scale);
  if (sd_event_source_set_time(s, usec + static_cast<uint64_t>(period_s * 1e6)) < 0 ||
      sd_event_source_set_enabled(s, SD_EVENT_ON) < 0) {
    // no more heartbeat nor ticks: exit (systemd restarts us) rather than
    // run on deaf; a moving table stops itself on the lost heartbeat
    d->error("cannot re-arm the heartbeat timer: exiting");
    sd_event_exit(d->ev, 1);
    return 0;
  }
  return guarded(d, "the timer", [&] {
    // the heartbeat goes out from this loop, between runs too: a table will
    // not start a move for a host it has not heard from. The reference
    // table's goes first, before a flood's backlog is read (its period is
    // the table's to judge), so it carries the last tick's state: withheld
    // from the tick after a quick stop's give-up, one period (0.1 s) after
    // it. (A CiA 402 master's NMT heartbeat is its own, sent by its tick.)
    const bool observing = d->running() && d->engine->sequencer().settings().observe;
    const bool gave_up = d->engine && d->engine->sequencer().course().quick_stop_gave_up;
    if (!d->cfg.daemon.observe && !observing && !gave_up) {
      for (const can::Frame& f :
           d->engine ? d->engine->ingest().table().heartbeat(d->heartbeat_counter++,
                                                             d->engine->sequencer().host_state())
                     : d->idle_table->heartbeat(d->heartbeat_counter++, 0))
        d->out.push_back({false, f});
      d->send_out();
    }
    d->recover_ports();
    d->tell_clock_steps();
    if (!d->report_busy) d->take_syncer_error();  // else the report's thread takes it
    if (d->report_busy && !d->report_slow_told &&
        monotonic_us() - d->report_since_us > kReportSlowUs) {
      d->report_slow_told = true;
      d->warn("the report has been written for " + std::to_string(kReportSlowUs / 1'000'000) +
              " s and is not done: the state directory's disk is slow or hung; no new run "
              "until it is (a stop waits for it; a kill leaves the run's log to be reported "
              "as interrupted at the next start)");
    }
    d->bus_rate.add(monotonic_us(), d->frames_seen());
    d->check_run_space();
    if (d->engine) {
      // what has arrived counts before anything is judged lost (one budget's worth)
      // every frame stamped before this has been read
      std::int64_t heard_until = std::numeric_limits<std::int64_t>::max();
      for (Port& p : d->ports)
        if (p.sock && p.sock->fd() >= 0) {
          d->on_can(p);
          heard_until = std::min(heard_until, p.heard_until_ns);
        }
      const std::uint64_t holds = d->engine->hold_count();
      d->engine->tick(d->clock.now_ns(), d->out, heard_until);
      d->tell_holds(holds);
    }
    d->after_engine();
    if (d->stopping && !d->running() && !d->busy()) sd_event_exit(d->ev, 0);
    d->exit_if_reloading();
    if (d->listener_lost && !d->running() && !d->busy()) {
      d->error("exiting: the control socket is not listened to");
      sd_event_exit(d->ev, 1);
    }
    if (++d->timer_ticks % 5 == 0) d->broadcast_watch();
    d->reap_clients();
  });
}

int Daemon::on_signal(sd_event_source*, const struct signalfd_siginfo* si, void* u) {
  auto* d = static_cast<Daemon*>(u);
  return guarded(d, "a signal", [&] {
    if (si->ssi_signo == SIGHUP) return d->ask_reload();
    const char* name = si->ssi_signo == SIGTERM ? "SIGTERM" : "SIGINT";
    d->info(std::string(name) + " received");
    d->stopping = true;
    sd_notify(0, "STOPPING=1");
    if (d->running()) {
      d->engine->signal(d->clock.now_ns(), name, d->out);
      d->after_engine();
    }
    if (!d->running() && !d->busy()) sd_event_exit(d->ev, 0);
  });
}

int Daemon::on_worker_done(sd_event_source*, int fd, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  return guarded(d, "the estimation's end", [&] {
    char c;
    (void)!::read(fd, &c, 1);
    if (d->worker.joinable()) d->worker.join();
    d->worker_busy = false;
    if (const int e = d->estimate_nice_errno.exchange(0); e != 0)
      d->warn(std::string("the estimate ran at the loop's priority (setpriority: ") +
              std::strerror(e) + ")");
    else
      d->info("the estimate ran at nice " + std::to_string(kEstimateNice) + ", below the loop");
    if (d->engine && d->report_done) {  // the run ended while it estimated
      d->input.reset();
      d->result.reset();
    }
    if (d->engine)
      d->engine->estimation_done(d->clock.now_ns(), d->result.has_value(), d->est_error, d->out);
    d->after_engine();
  });
}

int Daemon::on_report_done(sd_event_source*, int fd, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  return guarded(d, "the report's end", [&] {
    char c;
    (void)!::read(fd, &c, 1);
    d->report_written();
    if (d->stopping && !d->running() && !d->busy()) sd_event_exit(d->ev, 0);
  });
}

Status Daemon::setup() {
  TURNCAL_ASSIGN(c, load_config(opt.config));
  cfg = std::move(c);
  config_sha256 = run::sha256_hex(read_file(cfg.source));
  if (!opt.state_dir.empty()) cfg.daemon.state_directory = opt.state_dir;
  if (const char* sd = std::getenv("STATE_DIRECTORY"); sd != nullptr && opt.state_dir.empty())
    cfg.daemon.state_directory = std::string(sd).substr(0, std::string(sd).find(':'));
  if (!opt.socket.empty()) cfg.daemon.socket = opt.socket;
  TURNCAL_ASSIGN(d, load_databases(cfg.can));
  db = std::move(d);
  TURNCAL_ASSIGN(r, resolve_roles(cfg.can, db));
  roles = r;
  // a CiA 402 drive's PDO layouts from the DBC: refused now, not at a run
  TURNCAL_TRY(drivers::check_table(cfg.can, roles));
  idle_table =
      drivers::make_devices(cfg.can, roles, run::plausibility_of(cfg), cfg.stand.time_scale).table;
  // what the DBC files say that was read with a warning or skipped
  for (const can::Diagnostic& w : db.warnings)
    say(w.severity == can::Diagnostic::Severity::Note ? LOG_NOTICE : LOG_WARNING, "", "idle",
        w.describe());
  for (const std::string& w : unitless_role_warnings(roles)) say(LOG_WARNING, "", "idle", w);
  state.emplace(cfg.daemon.state_directory);
  TURNCAL_TRY(state->create());
  TURNCAL_ASSIGN(held, state->lock());  // before any file in it is touched
  state_lock = std::move(held);
  // and one per control socket, before anything is done: a second daemon
  // with a state directory of its own would rename its socket over the
  // first's and take its control. One it binds itself is locked; none is
  // bound over a socket something listens on (systemd's, which starts a
  // daemon on demand and holds no lock: its directory is not ours to write)
  if (sd_listen_fds(0) <= 0) TURNCAL_TRY(claim_socket());
  state->release_stale();
  report_interrupted_runs();
  state->load_index();
  for (const auto& [id, e] : state->index())
    if (!e.unreadable.empty()) say(LOG_WARNING, id, "idle", "report unreadable: " + e.unreadable);

  auto open_sock = [&](const std::string& iface) -> Result<socketcan::Socket> {
    socketcan::Options so;
    so.interface = iface;
    so.fd = cfg.can.fd;
    so.tx_queue_limit = cfg.can.tx_queue_frames;
    so.rcvbuf_bytes = static_cast<int>(cfg.can.rx_buffer_bytes);
    so.confirm = true;  // a frame is logged as sent when the kernel echoes it
    so.clock = &clock;
    return socketcan::Socket::open(so);
  };
  TURNCAL_ASSIGN(is, open_sock(cfg.can.ins_interface));
  ports[0].sock.emplace(std::move(is));
  if (cfg.can.table_interface != cfg.can.ins_interface) {
    TURNCAL_ASSIGN(ts, open_sock(cfg.can.table_interface));
    ports[1].sock.emplace(std::move(ts));
  }

  TURNCAL_TRY(listen_control());
  if (::pipe2(done_pipe, O_CLOEXEC | O_NONBLOCK) != 0 ||
      ::pipe2(report_pipe, O_CLOEXEC | O_NONBLOCK) != 0)
    return make_error(std::string("pipe failed: ") + std::strerror(errno));

  return add_sources();
}

Status Daemon::listen_control() {
  // the control socket: systemd's, or our own
  const int n = sd_listen_fds(1);
  if (n > 1) return make_error("expected one socket from systemd, got " + std::to_string(n));
  if (n == 1) {
    listen_fd = SD_LISTEN_FDS_START;
    socket_activated = true;
    const int fl = ::fcntl(listen_fd, F_GETFL);
    if (fl < 0 || ::fcntl(listen_fd, F_SETFL, fl | O_NONBLOCK) != 0)
      return make_error(std::string("the socket from systemd: fcntl: ") + std::strerror(errno));
  } else {
    // bound and made ready under a name of its own, then renamed into
    // place: a client that finds the socket finds it listening, with its
    // final mode and group (between bind and listen a connect is refused,
    // and before chmod the file has the umask's mode)
    const std::string path = cfg.daemon.socket.string();
    const std::string temp = path + ".new";
    sockaddr_un a{};
    if (temp.size() >= sizeof a.sun_path)
      return make_error("socket path too long: " + path + " (bound first as " + temp +
                        ", at most " + std::to_string(sizeof a.sun_path - 1) + " characters)");
    listen_fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (listen_fd < 0) return make_error(std::string("socket(AF_UNIX): ") + std::strerror(errno));
    a.sun_family = AF_UNIX;
    std::memcpy(a.sun_path, temp.c_str(), temp.size());
    // a socket a daemon that died left there goes; anything else stays
    TURNCAL_TRY(socket_or_nothing(temp));
    ::unlink(temp.c_str());
    const auto failed = [&](const std::string& what) {
      const std::string why = std::strerror(errno);
      ::unlink(temp.c_str());
      return make_error(what + ": " + why);
    };
    if (::bind(listen_fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
      return make_error("cannot bind " + temp + ": " + std::strerror(errno));
    if (::listen(listen_fd, 16) != 0) return failed("cannot listen on " + temp);
    if (::chmod(temp.c_str(), 0660) != 0) return failed("cannot chmod " + temp);
    if (!cfg.daemon.socket_group.empty()) {
      const group* g = ::getgrnam(cfg.daemon.socket_group.c_str());
      if (g == nullptr) {
        ::unlink(temp.c_str());
        return make_error("no group '" + cfg.daemon.socket_group + "'");
      }
      if (::chown(temp.c_str(), static_cast<uid_t>(-1), g->gr_gid) != 0)
        return failed("cannot give " + temp + " to group " + cfg.daemon.socket_group);
    }
    // asked again just before it is put in place: turncald.socket may have
    // been started since the claim. A stale socket is removed, and the new
    // one put in place only where nothing is (RENAME_NOREPLACE): what
    // appears in between is never replaced, and refuses the start
    const Result<bool> listened = something_listens(path);
    if (!listened || *listened) {
      ::unlink(temp.c_str());
      return listened ? refuse_listened(path) : Status{listened.error()};
    }
    if (::unlink(path.c_str()) != 0 && errno != ENOENT)
      return failed("cannot remove the stale socket " + path);
    if (::renameat2(AT_FDCWD, temp.c_str(), AT_FDCWD, path.c_str(), RENAME_NOREPLACE) != 0) {
      if (errno == EEXIST) {
        ::unlink(temp.c_str());
        return make_error("the control socket " + path +
                          " appeared while this daemon made its own; not replaced");
      }
      return failed("cannot move " + temp + " to " + path);
    }
  }
  return Status{Ok{}};
}

Status Daemon::add_sources() {
  auto check = [](int rc, const char* what) -> Status {
    if (rc < 0) return make_error(std::string("sd-event: ") + what + ": " + std::strerror(-rc));
    return Status{Ok{}};
  };
  TURNCAL_TRY(check(sd_event_default(&ev), "sd_event_default"));
  sigset_t ss;
  sigemptyset(&ss);
  sigaddset(&ss, SIGTERM);
  sigaddset(&ss, SIGINT);
  sigaddset(&ss, SIGHUP);
  sigprocmask(SIG_BLOCK, &ss, nullptr);
  TURNCAL_TRY(check(sd_event_add_signal(ev, nullptr, SIGTERM, on_signal, this), "SIGTERM"));
  TURNCAL_TRY(check(sd_event_add_signal(ev, nullptr, SIGINT, on_signal, this), "SIGINT"));
  TURNCAL_TRY(check(sd_event_add_signal(ev, nullptr, SIGHUP, on_signal, this), "SIGHUP"));
  for (Port& p : ports) {
    p.owner = this;
    if (!p.sock) continue;
    p.registered_fd = p.sock->fd();
    TURNCAL_TRY(
        check(sd_event_add_io(ev, p.src.out(), p.registered_fd, EPOLLIN, on_can_io, &p), "CAN"));
  }
  TURNCAL_TRY(
      check(sd_event_add_io(ev, listen_src.out(), listen_fd, EPOLLIN, on_accept, this), "listen"));
  TURNCAL_TRY(
      check(sd_event_add_io(ev, nullptr, done_pipe[0], EPOLLIN, on_worker_done, this), "worker"));
  TURNCAL_TRY(
      check(sd_event_add_io(ev, nullptr, report_pipe[0], EPOLLIN, on_report_done, this), "report"));
  uint64_t now = 0;
  TURNCAL_TRY(check(sd_event_now(ev, CLOCK_MONOTONIC, &now), "the loop's clock"));
  TURNCAL_TRY(check(sd_event_add_time(ev, timer.out(), CLOCK_MONOTONIC, now, 1000, on_timer, this),
                    "timer"));
  // the heartbeat, the ticks and the watchdog before any socket
  TURNCAL_TRY(check(timer.set_priority(kPrioTimers), "timer priority"));
  TURNCAL_TRY(
      check(sd_event_add_time(ev, tx_retry.out(), CLOCK_MONOTONIC, now, 1000, on_tx_retry, this),
            "retry timer"));
  TURNCAL_TRY(check(tx_retry.set_priority(kPrioTimers), "retry timer priority"));
  TURNCAL_TRY(check(tx_retry.set_enabled(SD_EVENT_OFF), "retry timer"));
  TURNCAL_TRY(check(
      sd_event_add_time(ev, accept_again.out(), CLOCK_MONOTONIC, now, 1000, on_accept_again, this),
      "accept timer"));
  TURNCAL_TRY(check(accept_again.set_enabled(SD_EVENT_OFF), "accept timer"));
  // WATCHDOG=1 from the loop itself, when WatchdogSec= asks
  TURNCAL_TRY(check(sd_event_set_watchdog(ev, 1), "watchdog"));
  return Status{Ok{}};
}

Daemon::Daemon(Options o) : opt(std::move(o)) {}
Daemon::~Daemon() = default;

int Daemon::run() {
  info("ready: CAN " + cfg.can.ins_interface + "/" + cfg.can.table_interface + ", state " +
       cfg.daemon.state_directory.string());
  sd_notify(0, "READY=1\nSTATUS=idle");
  const int r = sd_event_loop(ev);
  if (worker.joinable()) worker.join();
  if (report_thread.joinable()) report_thread.join();
  clients.clear();
  for (Port& p : ports) p.src.reset();
  timer.reset();
  tx_retry.reset();
  listen_src.reset();
  accept_again.reset();
  sd_event_unref(ev);
  ev = nullptr;
  // sd_event_exit's code (1: a fault that stops the daemon), or a negative
  // errno: either is a failure, for systemd's Restart=
  return r != 0 ? 1 : 0;
}

}  // namespace turncal::daemon
