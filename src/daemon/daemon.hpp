// turncald's daemon: the state of the service and the loop's wiring. An
// sd-event loop runs the CAN sockets, the heartbeat and tick timer, the
// control socket (Unix stream, JSON lines; the clients in clients.cpp, the
// protocol a pure function in control.hpp) and the signals; the run engine
// (src/run) does the experiment; a worker thread runs the estimation and
// another writes the report (report_writer.hpp), so that the loop and the
// watchdog keep going and the heartbeat never waits for a disk; the
// recorder keeps every frame of a run, both directions, in a candump log in
// the state directory (state_dir.hpp). Every sd-event source is an
// EventSource (event_source.hpp), every call on it checked.
//
// Faults of the host are the run's faults: a log that cannot be written, a
// CAN interface that goes down, an exception in a callback (never let out
// of the loop) each fail the run with the reason and stop the table; a
// quick stop is repeated until the table reports it stopped.
//
// Fairness: timers (heartbeat, ticks, the watchdog) run at a higher
// priority than the CAN and control sockets, and one wakeup reads at most
// kRxBatches x 64 frames of a socket, so no flood starves them.
#pragma once

#include <systemd/sd-event.h>
#include <systemd/sd-journal.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "control.hpp"
#include "event_source.hpp"
#include "report_writer.hpp"
#include "state_dir.hpp"
#include "syncer.hpp"
#include "turncal/build_paths.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/socketcan.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/replay.hpp"

namespace turncal::daemon {

/// Bytes of one control request line.
inline constexpr std::size_t kMaxRequest = 64 * 1024;
/// Bytes of replies a client may leave unread.
inline constexpr std::size_t kMaxQueued = 4 << 20;
/// Out of descriptors: accept again after this, us.
inline constexpr std::uint64_t kAcceptBackoffUs = 1000000;
/// A control connection not yet heard from is not closed to make room for
/// another this long after its accept (make_room): time for its first read.
inline constexpr std::uint64_t kFreshGraceUs = 1000000;

/// Whether say() writes structured journal entries (under systemd).
void log_to_journal(bool on);
/// One log line: to the journal with RUN_ID and PHASE fields under
/// systemd, else to stderr.
void say(int priority, const std::string& run_id, const char* phase, const std::string& msg);
/// CLOCK_MONOTONIC, us.
std::uint64_t monotonic_us();

struct Options {
  std::string config = std::string(turncal::build::data_dir) + "/turncal.toml";
  std::string state_dir;
  std::string socket;
};

class Daemon;

/// One CAN interface: its socket, its event source, what it did before
/// the run (for the report's per-run figures).
struct Port {
  Daemon* owner = nullptr;
  std::optional<socketcan::Socket> sock;
  EventSource src;
  int registered_fd = -1;
  std::uint64_t registered_generation = 0;  ///< the socket's recoveries when registered
  socketcan::Stats at_run_start;
  /// Every frame stamped before this (host ns) has been read: the last
  /// read's latest stamp when it left frames (a flood past one budget's
  /// worth) or the kernel dropped some (a full queue); else when the read
  /// that drained it began. No bound before the first read.
  std::int64_t heard_until_ns = std::numeric_limits<std::int64_t>::max();
  bool io_fault_told = false;  ///< that its events could not be set, said
};

struct Client;

class Daemon {
 public:
  explicit Daemon(Options o);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;
  /// Reads the configuration, takes the state directory and the control
  /// socket, opens the CAN interfaces and sets up the loop; an error says
  /// why it cannot serve.
  Status setup();
  /// Serves until the loop exits (a stop, a reload once idle, a fault),
  /// then waits for its threads and frees every source: the exit code.
  int run();

 private:
  Options opt;
  Config cfg;
  can::Database db;
  RoleMap roles;
  /// The table's driver between runs (the host heartbeat goes out then too).
  std::unique_ptr<TableDriver> idle_table;
  /// Every time of the daemon's: realtime at the run's start plus monotonic
  /// time since (the sockets' receive stamps too), so a step of the wall
  /// clock moves no deadline and no log time.
  socketcan::HostClock clock;
  std::uint64_t clock_steps_told = 0;
  sd_event* ev = nullptr;
  std::array<Port, 2> ports;  ///< INS side, table side (empty: one interface)
  EventSource timer;
  EventSource tx_retry;
  EventSource listen_src;
  EventSource accept_again;
  int listen_fd = -1;
  std::vector<std::unique_ptr<Client>> clients;
  bool stopping = false;
  std::uint64_t holds_untold = 0;     ///< holds of the machine not yet in the journal
  double holds_untold_longest_s = 0;  ///< the longest of them
  std::uint64_t holds_told_us = 0;    ///< when the last line about them went out
  std::uint64_t timer_ticks = 0;      ///< watchers get the status every 5th
  /// Started by its systemd socket, which starts it again on the next
  /// request: what lets a reload (SIGHUP) be an exit once idle.
  bool socket_activated = false;
  bool exit_when_idle = false;  ///< a reload asked for: the next idle tick exits
  bool replaced_told = false;   ///< that the program was replaced on disk, said
  std::uint64_t replaced_checked_us = 0;
  std::uint8_t heartbeat_counter = 0;
  std::optional<StateDir> state;
  DirLock state_lock;   ///< the state directory is this daemon's alone
  DirLock socket_lock;  ///< and the control socket's path (when it binds it itself)
  /// Frames the bus has lately carried (what a run's log grows at).
  BusRate bus_rate;
  double next_space_check_s = 0;  ///< of this run, real s from its start
  std::string config_sha256;      ///< of the configuration as loaded

  // the run
  std::unique_ptr<run::Engine> engine;
  std::string run_id;
  std::string unit;  ///< the INS under test of this run
  std::filesystem::path log_path;
  std::optional<can::LogWriter> log;
  /// A log a fault closed the run's writing to: closed for good once no
  /// fsync is on it (when the report is written).
  std::optional<can::LogWriter> retired_log;
  std::string log_error;  ///< the first write error of this run's log
  /// The log's fsyncs at phase ends, off the loop (declared after the logs:
  /// it stops, its last fsync done, before they close).
  Syncer syncer{posix_io().fsync};
  std::int64_t run_start_ns = 0;
  run::Phase last_phase = run::Phase::Idle;
  std::size_t table_notices_logged = 0;  ///< of the run's table driver
  bool report_done = true;
  std::thread worker;
  int done_pipe[2] = {-1, -1};
  std::optional<run::BuiltInput> input;
  std::optional<est::EstimationResult> result;
  std::string est_error;
  std::atomic<bool> worker_busy{false};
  std::atomic<int> estimate_nice_errno{0};  ///< the worker's setpriority, failed
  /// The run's report being written off the loop (report_writer.hpp): the
  /// job is the thread's until it writes to report_pipe.
  std::unique_ptr<ReportJob> report_job;
  std::thread report_thread;
  bool report_busy = false;
  std::uint64_t report_since_us = 0;  ///< monotonic: when it began
  bool report_slow_told = false;
  bool listener_lost = false;  ///< the control socket can be listened to no more
  int report_pipe[2] = {-1, -1};
  std::vector<run::OutFrame> out;
  socketcan::RxBatch rx;

  /// The run's phase; "report" while its report is being written: a run
  /// that ended has its report on disk before a client hears it ended.
  [[nodiscard]] const char* phase_name() const {
    if (report_busy) return run::to_string(run::Phase::Report);
    return engine ? run::to_string(engine->sequencer().phase()) : "idle";
  }
  /// A thread of the last run's still at work (its estimate, its report).
  [[nodiscard]] bool busy() const { return worker_busy || report_busy; }
  [[nodiscard]] bool running() const {
    return engine && !run::finished(engine->sequencer().phase());
  }
  void info(const std::string& m) const { say(LOG_INFO, run_id, phase_name(), m); }
  void warn(const std::string& m) const { say(LOG_WARNING, run_id, phase_name(), m); }
  void error(const std::string& m) const { say(LOG_ERR, run_id, phase_name(), m); }

  Port& port(bool ins_side) { return (ins_side || !ports[1].sock) ? ports[0] : ports[1]; }
  /// Parts of setup(): the control socket (systemd's, or our own), and the
  /// loop's sources.
  Status listen_control();
  Status add_sources();
  void tell_clock_steps();
  void tell_holds(std::uint64_t before, bool flush = false);
  void send_out();
  void flush_port(Port& p);
  void link_back(Port& p);
  void update_io(Port& p);
  void recover_ports();
  void exit_if_reloading();
  void ask_reload();
  void log_record(const can::LogRecord& r);
  void log_sync();
  void take_syncer_error();
  void host_fault(const std::string& what);
  void log_fault(const std::string& what);
  void internal_error(const char* where, const char* what);
  void after_engine();
  void on_can(Port& p);
  [[nodiscard]] nlohmann::json can_json(bool since_run_start) const;
  [[nodiscard]] nlohmann::json status() const;
  nlohmann::json start(const StartRequest& req);
  Result<Plan> plan_of(const StartRequest& req, std::string& from) const;
  [[nodiscard]] std::uint64_t frames_seen() const;
  [[nodiscard]] std::string space_shortfall(double frames_per_s, double bytes_per_frame,
                                            double real_s, std::uint64_t also) const;
  void check_run_space();
  void write_report(bool with_estimates);
  void start_report(bool with_estimates);
  void report_written();
  void report_interrupted_runs();
  /// Takes the control socket's path for this daemon (see setup).
  Status claim_socket();
  void handle_request(Client& c, const std::string& line);
  void broadcast_watch();
  void reap_clients();
  bool make_room(long long newcomer_uid);

  // ---- sd-event callbacks (daemon.cpp, clients.cpp) ----
  static int on_can_io(sd_event_source*, int, uint32_t revents, void* u);
  static int on_tx_retry(sd_event_source*, uint64_t, void* u);
  static int on_timer(sd_event_source* s, uint64_t usec, void* u);
  static int on_signal(sd_event_source*, const struct signalfd_siginfo* si, void* u);
  static int on_worker_done(sd_event_source*, int fd, uint32_t, void* u);
  static int on_report_done(sd_event_source*, int fd, uint32_t, void* u);
  static int on_accept(sd_event_source*, int fd, uint32_t, void* u);
  static int on_accept_again(sd_event_source*, uint64_t, void* u);
  static int on_client(sd_event_source*, int fd, uint32_t revents, void* u);

  /// Runs a callback's body; an exception is logged and, where it came from
  /// the run's own work (`run_work`), fails the run. Nothing leaves it.
  template <class F>
  static int guarded(Daemon* d, const char* where, F&& f, bool run_work = true) {
    try {
      f();
    } catch (const std::exception& e) {
      if (run_work)
        d->internal_error(where, e.what());
      else
        d->warn(std::string("error in ") + where + ": " + e.what());
    } catch (...) {
      if (run_work) d->internal_error(where, "unknown exception");
    }
    return 0;
  }
};

}  // namespace turncal::daemon
