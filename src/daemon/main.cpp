// turncald: the calibration experiment as a service. An sd-event loop runs
// the CAN sockets, the heartbeat and tick timer, the control socket (Unix
// stream, JSON lines) and the signals; the run engine (src/run) does the
// experiment; a worker thread runs the estimation so that the loop and the
// watchdog keep going; the recorder keeps every frame of a run, both
// directions, in a candump log in the state directory; the report is
// written atomically next to it.
//
//   turncald [--config FILE] [--state-dir DIR] [--socket PATH]
#include <fcntl.h>
#include <grp.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <systemd/sd-daemon.h>
#include <systemd/sd-event.h>
#include <systemd/sd-journal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "turncal/can/candump.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/socketcan.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/history.hpp"
#include "turncal/run/html.hpp"
#include "turncal/run/replay.hpp"
#include "turncal/run/report.hpp"

using namespace turncal;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxRequest = 64 * 1024;  ///< bytes of one control request line
constexpr std::size_t kMaxQueued = 4 << 20;     ///< bytes of replies a client may leave unread
constexpr std::size_t kRxBatches = 4;           ///< recvmmsg calls per receive, kBatchFrames each

bool g_journal = false;  // under systemd: structured journal entries

/// One log line: to the journal with RUN_ID and PHASE fields under
/// systemd, else to stderr.
void say(int priority, const std::string& run_id, const char* phase, const std::string& msg) {
  if (g_journal) {
    sd_journal_send("MESSAGE=%s", msg.c_str(), "PRIORITY=%d", priority, "RUN_ID=%s", run_id.c_str(),
                    "PHASE=%s", phase, "SYSLOG_IDENTIFIER=turncald", nullptr);
    return;
  }
  std::fprintf(stderr, "turncald: %s%s%s\n", run_id.empty() ? "" : run_id.c_str(),
               run_id.empty() ? "" : ": ", msg.c_str());
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Temp file, fsync, rename, fsync of the folder: the file is whole or absent.
Status write_atomic(const fs::path& path, const std::string& data) {
  const fs::path tmp = path.string() + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return make_error("cannot create " + tmp.string() + ": " + std::strerror(errno));
  std::size_t off = 0;
  while (off < data.size()) {
    const ssize_t n = ::write(fd, data.data() + off, data.size() - off);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      ::close(fd);
      return make_error("cannot write " + tmp.string() + ": " + std::strerror(errno));
    }
    off += static_cast<std::size_t>(n);
  }
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  if (!synced || ::rename(tmp.c_str(), path.c_str()) != 0)
    return make_error("cannot put " + path.string() + " in place: " + std::strerror(errno));
  const int dfd = ::open(path.parent_path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  return Status{Ok{}};
}

/// What the index keeps of a report (a discarded json: one that does not parse).
json report_summary(const json& r) {
  if (!r.is_object()) return json::value_t::discarded;
  json s = json::object();
  for (const char* k : {"run_id", "status", "unit", "start_time_unix_s", "estimates"})
    if (r.contains(k)) s[k] = r[k];
  s["profile"] = {{"name", r.contains("profile") ? r["profile"].value("name", "") : ""}};
  s["verdict"] = {{"pass", r.contains("verdict") ? r["verdict"].value("pass", false) : false}};
  return s;
}

std::string utc_id(std::int64_t ns) {
  const std::time_t s = static_cast<std::time_t>(ns / 1'000'000'000);
  std::tm tm{};
  gmtime_r(&s, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y%m%dT%H%M%SZ", &tm);
  return buf;
}

/// A unit identity that is safe in a file listing and a log line.
bool valid_unit(const std::string& u) {
  if (u.empty() || u.size() > 64) return false;
  for (const char c : u)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_' && c != '.')
      return false;
  return true;
}

struct Options {
  std::string config = std::string(TURNCAL_DATA_DIR) + "/turncal.toml";
  std::string state_dir;
  std::string socket;
};

struct Client;

class Daemon {
 public:
  Options opt;
  Config cfg;
  can::Database db;
  RoleMap roles;
  sd_event* ev = nullptr;
  std::optional<socketcan::Socket> ins_sock, table_sock;  // table_sock empty: one interface
  sd_event_source *ins_src = nullptr, *table_src = nullptr;
  int listen_fd = -1;
  std::vector<std::unique_ptr<Client>> clients;
  bool stopping = false;
  std::uint64_t timer_ticks = 0;  ///< watchers get the status every 5th
  std::uint8_t heartbeat_counter = 0;

  // the run
  std::unique_ptr<run::Engine> engine;
  std::string run_id;
  std::string unit;  ///< the INS under test of this run
  fs::path log_path;
  std::optional<can::LogWriter> log;
  std::int64_t run_start_ns = 0;
  run::Phase last_phase = run::Phase::Idle;
  bool report_done = true;
  std::thread worker;
  int done_pipe[2] = {-1, -1};
  std::optional<run::BuiltInput> input;
  std::optional<est::EstimationResult> result;
  std::string est_error;
  std::atomic<bool> worker_busy{false};
  std::vector<run::OutFrame> out;
  socketcan::RxBatch rx;

  [[nodiscard]] const char* phase_name() const {
    return engine ? run::to_string(engine->sequencer().phase()) : "idle";
  }
  [[nodiscard]] bool running() const {
    return engine && !run::finished(engine->sequencer().phase());
  }
  void info(const std::string& m) const { say(LOG_INFO, run_id, phase_name(), m); }
  void warn(const std::string& m) const { say(LOG_WARNING, run_id, phase_name(), m); }

  Status setup();
  void send_out();
  void after_engine();
  void on_can(socketcan::Socket& s, bool ins_side);
  json status() const;
  json start(const json& req);
  void write_report(bool with_estimates);
  void report_interrupted_runs();
  /// The reports kept, by run id, cut to what `reports` and `history` need:
  /// read once at start-up, kept up to date as reports are written, so a
  /// request never reads the state directory while a run's frames arrive.
  std::map<std::string, json> index;
  void index_report(const std::string& id, const json& report);
  void broadcast_watch();
};

struct Client {
  Daemon* d;
  int fd;
  sd_event_source* src = nullptr;
  std::string in;
  bool watching = false;
  ~Client() {
    sd_event_source_unref(src);
    ::close(fd);
  }
  std::string out;           ///< replies the socket has not taken yet
  bool broken = false;       ///< gone, or so far behind that it is dropped
  bool close_after = false;  ///< dropped once its replies are sent
  /// Queues a reply and sends what the socket takes; the rest goes when the
  /// socket is writable again (EPOLLOUT), so a large report is never cut.
  void reply(const json& j) {
    if (broken) return;
    if (out.size() > kMaxQueued) {  // a watcher that stopped reading
      broken = true;
      return;
    }
    out += j.dump() + "\n";
    flush();
  }
  void flush() {
    while (!out.empty() && !broken) {
      const ssize_t n = ::send(fd, out.data(), out.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) break;
      if (n <= 0) {
        broken = true;
        break;
      }
      out.erase(0, static_cast<std::size_t>(n));
    }
    // a client being closed is not read any more (EPOLLIN would fire forever)
    if (src != nullptr)
      sd_event_source_set_io_events(
          src, (close_after ? 0U : EPOLLIN) | (out.empty() || broken ? 0U : EPOLLOUT));
  }
  [[nodiscard]] bool done() const { return broken || (close_after && out.empty()); }
};

void Daemon::send_out() {
  for (const run::OutFrame& o : out) {
    socketcan::Socket& s = (o.ins_side || !table_sock) ? *ins_sock : *table_sock;
    if (!s.send(o.frame)) warn("cannot send a frame on " + s.interface());
    if (log) {
      can::LogRecord r{socketcan::realtime_ns(), s.interface(), o.frame};
      (void)log->write(r);
    }
  }
  out.clear();
}

void Daemon::after_engine() {
  send_out();  // the heartbeat goes out between runs too
  if (!engine) return;
  const run::Phase p = engine->sequencer().phase();
  if (p != last_phase) {
    last_phase = p;
    const int idx = engine->sequencer().index();
    info(std::string("phase ") + run::to_string(p) + (idx > 0 ? " " + std::to_string(idx) : "") +
         (engine->sequencer().course().reason.empty()
              ? ""
              : " (" + engine->sequencer().course().reason + ")"));
    sd_notifyf(0, "STATUS=%s %s", run_id.c_str(), run::to_string(p));
    if (log) (void)log->sync();  // each phase end is on disk
    broadcast_watch();
  }
  if (engine->estimation_due() && !worker_busy) {
    auto in = engine->take_estimation_input();
    if (!in) {
      engine->estimation_done(socketcan::realtime_ns(), false, in.error().describe(), out);
      return after_engine();
    }
    input = std::move(*in);
    worker_busy = true;
    if (worker.joinable()) worker.join();
    worker = std::thread([this] {
      auto r = est::estimate(input->input);
      if (r) {
        result = std::move(*r);
      } else {
        est_error = r.error().describe();
      }
      const char c = 1;
      (void)!::write(done_pipe[1], &c, 1);
    });
  }
  if (engine->report_due()) {
    write_report(true);
    engine->report_written(socketcan::realtime_ns(), true, "", out);
    return after_engine();
  }
  if (run::finished(p) && !report_done) write_report(false);
}

void Daemon::write_report(bool with_estimates) {
  report_done = true;
  if (log) {
    (void)log->sync();
    (void)log->close();
    log.reset();
  }
  run::ReportContext ctx;
  ctx.run_id = run_id;
  ctx.start_unix_s = static_cast<double>(run_start_ns) * 1e-9;
  ctx.end_unix_s = static_cast<double>(socketcan::realtime_ns()) * 1e-9;
  ctx.software_version = run::software_version();
  ctx.config_file = cfg.source.string();
  ctx.config_sha256 = run::sha256_hex(read_file(cfg.source));
  ctx.log_file = log_path.filename().string();
  if (auto dg = run::sha256_file(log_path.string()))
    ctx.log_sha256 = dg->sha256;
  else
    warn(dg.error().describe());
  ctx.tolerances = cfg.tolerances;
  ctx.mode = engine->sequencer().settings().observe ? "observe" : "command";
  ctx.unit = unit;
  const bool est = with_estimates && result && input;
  const json j = run::report_json(ctx, *engine, est ? &*input : nullptr, est ? &*result : nullptr);
  const fs::path dir = cfg.daemon.state_directory;
  auto a = write_atomic(dir / (run_id + ".report.json"), j.dump(2) + "\n");
  auto b = write_atomic(dir / (run_id + ".report.txt"), run::report_text(j));
  auto c = write_atomic(dir / (run_id + ".report.html"),
                        run::report_html(j, est ? &*input : nullptr, est ? &*result : nullptr));
  if (a) index_report(run_id, j);
  if (!a || !b || !c)
    warn("report not written: " + (!a ? a.error() : !b ? b.error() : c.error()).describe());
  else
    info("report written: " + (dir / (run_id + ".report.json")).string());
  // the run's samples (most of its memory) are in the report now, or the
  // run failed: a service that idles between runs need not hold them
  input.reset();
  result.reset();
}

void Daemon::index_report(const std::string& id, const json& report) {
  index[id] = report_summary(report);
}

/// A log with no report: a run that was killed. Its log replays up to that
/// moment; the report says so.
void Daemon::report_interrupted_runs() {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(cfg.daemon.state_directory, ec)) {
    const std::string name = e.path().filename().string();
    if (!name.ends_with(".log")) continue;
    const std::string id = name.substr(0, name.size() - 4);
    const fs::path rep = e.path().parent_path() / (id + ".report.json");
    if (fs::exists(rep)) continue;
    auto dg = run::sha256_file(e.path().string());
    if (!dg) {
      say(LOG_WARNING, id, "interrupted", dg.error().describe());
      continue;
    }
    const std::uint64_t lines = dg->lines;
    const json j = {{"format", "turncal-report-1"},
                    {"run_id", id},
                    {"status", "interrupted"},
                    {"reason", "the daemon stopped during the run (killed or crashed)"},
                    {"log", {{"file", name}, {"sha256", dg->sha256}, {"lines", lines}}},
                    {"verdict", {{"pass", false}, {"checks", json::array()}}}};
    if (write_atomic(rep, j.dump(2) + "\n")) index_report(id, j);
    (void)write_atomic(e.path().parent_path() / (id + ".report.txt"), run::report_text(j));
    (void)write_atomic(e.path().parent_path() / (id + ".report.html"),
                       run::report_html(j, nullptr, nullptr));
    say(LOG_WARNING, id, "interrupted",
        "run " + id + " was interrupted; its log (" + std::to_string(lines) + " frames) is kept");
  }
}

json Daemon::status() const {
  json j = {{"ok", true}, {"phase", phase_name()}, {"run_id", run_id}};
  // what the sockets took since the daemon started, and what the kernel lost
  json can = json::object();
  for (const auto* s : {&ins_sock, &table_sock})
    if (*s)
      can[(*s)->interface()] = {{"rx_frames", (*s)->stats().rx_frames},
                                {"rx_dropped", (*s)->stats().rx_dropped}};
  j["can"] = can;
  if (!engine) return j;
  const auto& s = engine->sequencer();
  const double now = engine->stand_s(socketcan::realtime_ns());
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
    h[sh.name] = {{"rate_hz", sh.rate_hz()},
                  {"dropped", sh.dropped},
                  {"stale", sh.stale(now, s.settings().stale_floor_s)}};
  }
  j["health"] = h;
  return j;
}

json Daemon::start(const json& req) {
  if (running()) return {{"ok", false}, {"error", "a run is in progress: " + run_id}};
  if (worker_busy) return {{"ok", false}, {"error", "the last run's estimation is still running"}};
  std::string profile = cfg.daemon.profile.string();
  if (req.contains("profile") && req["profile"].is_string()) profile = req["profile"];
  auto plan = load_plan(profile);
  if (!plan) return {{"ok", false}, {"error", plan.error().describe()}};
  run::SequencerSettings q;
  q.profile = plan->profile;
  q.start_angle_rad = plan->start_angle_rad;
  q.heading_offset_rad = cfg.stand.heading_offset_rad;
  q.limits = cfg.stand.limits;
  q.observe = cfg.daemon.observe || req.value("observe", false);
  q.stale_floor_s = cfg.daemon.stale_floor_ms * 1e-3 * cfg.stand.time_scale;
  if (req.contains("heading_offset_deg")) {
    if (!req["heading_offset_deg"].is_number())
      return {{"ok", false}, {"error", "heading_offset_deg: expected a number of degrees"}};
    q.heading_offset_rad = req["heading_offset_deg"].get<double>() * std::numbers::pi / 180;
  }
  std::string unit_id = cfg.stand.unit;
  if (req.contains("unit")) {
    if (!req["unit"].is_string() || !valid_unit(req["unit"].get<std::string>()))
      return {
          {"ok", false},
          {"error", "unit: expected the INS identity, 1 to 64 letters, digits, '-', '_' or '.'"}};
    unit_id = req["unit"].get<std::string>();
  }
  if (engine) {
    q.table_seq_base = static_cast<std::uint8_t>(engine->commands_sent() + 100);
    q.ins_seq_base = q.table_seq_base;
  }
  const std::int64_t now = socketcan::realtime_ns();
  run_start_ns = now;
  run_id = utc_id(now);
  // two runs within a second: the second gets a suffix, no log is overwritten
  for (int k = 2; fs::exists(cfg.daemon.state_directory / (run_id + ".log")); ++k)
    run_id = utc_id(now) + "-" + std::to_string(k);
  log_path = cfg.daemon.state_directory / (run_id + ".log");
  auto w = can::LogWriter::open(log_path.string());
  if (!w) return {{"ok", false}, {"error", w.error().describe()}};
  log.emplace(std::move(*w));
  unit = unit_id;
  run::BuildSettings b;
  b.heading_offset_rad = q.heading_offset_rad;
  engine = std::make_unique<run::Engine>(db, roles, *plan, q, b,
                                         run::TimeBase{now / 1000, cfg.stand.time_scale});
  input.reset();
  result.reset();
  est_error.clear();
  report_done = false;
  last_phase = run::Phase::Idle;
  info("run started: " + plan->name + " from " + profile + (unit.empty() ? "" : ", unit " + unit));
  engine->start(now, out);
  after_engine();
  return {{"ok", true}, {"run_id", run_id}, {"log", log_path.string()}};
}

void Daemon::broadcast_watch() {
  const json s = status();
  for (auto& c : clients)
    if (c->watching) c->reply(s);
  std::erase_if(clients, [](const auto& c) { return c->done(); });
}

void Daemon::on_can(socketcan::Socket& s, bool /*ins_side*/) {
  for (;;) {
    rx.clear();
    auto n = s.receive(rx, kRxBatches);
    if (!n) {
      warn(n.error().describe());
      return;
    }
    for (const auto& ev_ : rx.events) warn(s.interface() + ": " + can::describe(ev_));
    for (const can::TimedFrame& f : rx.frames) {
      if (log) (void)log->write({f.time_ns, s.interface(), f.frame});
      if (engine) engine->on_frame(f, out);
    }
    if (log) (void)log->flush();
    after_engine();
    // a short read drained the socket: no second recvmmsg just to see EAGAIN
    if (*n < kRxBatches * socketcan::Socket::kBatchFrames) return;
  }
}

// ---- sd-event callbacks ----

int on_can_ins(sd_event_source*, int, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  d->on_can(*d->ins_sock, true);
  return 0;
}
int on_can_table(sd_event_source*, int, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  d->on_can(*d->table_sock, false);
  return 0;
}

int on_timer(sd_event_source* s, uint64_t usec, void* u) {
  auto* d = static_cast<Daemon*>(u);
  const double period_s = 1.0 / (d->cfg.daemon.heartbeat_hz * d->cfg.stand.time_scale);
  sd_event_source_set_time(s, usec + static_cast<uint64_t>(period_s * 1e6));
  sd_event_source_set_enabled(s, SD_EVENT_ON);
  if (d->engine) {
    // what has arrived counts before anything is judged lost
    d->on_can(*d->ins_sock, true);
    if (d->table_sock) d->on_can(*d->table_sock, false);
    d->engine->tick(socketcan::realtime_ns(), d->out);
  }
  // the heartbeat goes out from this loop, between runs too: a table will not
  // start a move for a host it has not heard from
  const bool observing = d->running() && d->engine->sequencer().settings().observe;
  if (!d->cfg.daemon.observe && !observing)
    d->out.push_back(run::heartbeat_frame(d->roles, d->heartbeat_counter++,
                                          d->engine ? d->engine->sequencer().host_state() : 0));
  d->after_engine();
  if (d->stopping && !d->running() && !d->worker_busy) sd_event_exit(d->ev, 0);
  if (++d->timer_ticks % 5 == 0) d->broadcast_watch();
  return 0;
}

int on_signal(sd_event_source*, const struct signalfd_siginfo* si, void* u) {
  auto* d = static_cast<Daemon*>(u);
  const char* name = si->ssi_signo == SIGTERM ? "SIGTERM" : "SIGINT";
  d->info(std::string(name) + " received");
  d->stopping = true;
  sd_notify(0, "STOPPING=1");
  if (d->running()) {
    d->engine->signal(socketcan::realtime_ns(), name, d->out);
    d->after_engine();
  }
  if (!d->running() && !d->worker_busy) sd_event_exit(d->ev, 0);
  return 0;
}

int on_worker_done(sd_event_source*, int fd, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  char c;
  (void)!::read(fd, &c, 1);
  if (d->worker.joinable()) d->worker.join();
  d->worker_busy = false;
  if (d->engine)
    d->engine->estimation_done(socketcan::realtime_ns(), d->result.has_value(), d->est_error,
                               d->out);
  d->after_engine();
  return 0;
}

void handle_request(Client& c, const std::string& line) {
  Daemon& d = *c.d;
  json req;
  try {
    req = json::parse(line);
  } catch (const json::exception& e) {
    return c.reply({{"ok", false}, {"error", std::string("malformed request: ") + e.what()}});
  }
  if (!req.is_object() || !req.contains("cmd") || !req["cmd"].is_string())
    return c.reply({{"ok", false}, {"error", "malformed request: expected {\"cmd\": ...}"}});
  const std::string cmd = req["cmd"];
  if (cmd == "status") return c.reply(d.status());
  if (cmd == "watch") {
    c.watching = true;
    return c.reply(d.status());
  }
  if (cmd == "start") return c.reply(d.start(req));
  if (cmd == "abort") {
    if (!d.running()) return c.reply({{"ok", false}, {"error", "no run in progress"}});
    d.engine->abort(socketcan::realtime_ns(), req.value("reason", std::string()), d.out);
    d.after_engine();
    return c.reply({{"ok", true}, {"run_id", d.run_id}});
  }
  if (cmd == "reports") {
    json list = json::array();
    for (const auto& [id, r] : d.index) {
      const bool ok = r.is_object();
      list.push_back({{"run_id", id},
                      {"status", ok ? r.value("status", "?") : "unreadable"},
                      {"unit", ok && r.contains("unit") ? r["unit"] : json(nullptr)},
                      {"pass", ok && r.contains("verdict") ? r["verdict"]["pass"] : json(false)}});
    }
    return c.reply({{"ok", true}, {"reports", list}});
  }
  if (cmd == "history") {
    if (!req.contains("unit") || !req["unit"].is_string())
      return c.reply({{"ok", false}, {"error", "history: expected a unit"}});
    std::vector<json> all;
    all.reserve(d.index.size());
    for (const auto& [id, r] : d.index) all.push_back(r);
    const json h = run::history_json(req["unit"].get<std::string>(), all);
    return c.reply({{"ok", true}, {"history", h}, {"text", run::history_text(h)}});
  }
  if (cmd == "report") {
    const std::string id = req.value("run_id", std::string());
    if (id.empty() || id.find('/') != std::string::npos || id.find("..") != std::string::npos)
      return c.reply({{"ok", false}, {"error", "report: expected a run_id"}});
    const fs::path p = d.cfg.daemon.state_directory / (id + ".report.json");
    if (!fs::exists(p)) return c.reply({{"ok", false}, {"error", "no report " + id}});
    json r = json::parse(read_file(p), nullptr, false);
    if (r.is_discarded())
      return c.reply({{"ok", false}, {"error", "report " + id + " unreadable"}});
    return c.reply({{"ok", true}, {"report", r}, {"text", run::report_text(r)}});
  }
  c.reply({{"ok", false}, {"error", "unknown command '" + cmd + "'"}});
}

int on_client(sd_event_source*, int fd, uint32_t revents, void* u) {
  auto* c = static_cast<Client*>(u);
  Daemon& d = *c->d;
  auto drop = [&] { std::erase_if(d.clients, [&](const auto& p) { return p.get() == c; }); };
  if (revents & EPOLLOUT) c->flush();
  if (revents & (EPOLLHUP | EPOLLERR)) c->broken = true;
  if ((revents & EPOLLIN) && !c->close_after && !c->broken) {
    char buf[4096];
    const ssize_t n = ::recv(fd, buf, sizeof buf, MSG_DONTWAIT);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
      // the client closed: what it asked is answered, then it is dropped
      c->close_after = true;
    } else if (n > 0) {
      c->in.append(buf, static_cast<std::size_t>(n));
      std::size_t nl;
      while (!c->close_after && (nl = c->in.find('\n')) != std::string::npos) {
        const std::string line = c->in.substr(0, nl);
        c->in.erase(0, nl + 1);
        if (line.size() > kMaxRequest) {
          c->reply({{"ok", false}, {"error", "request too large"}});
          c->close_after = true;
        } else {
          handle_request(*c, line);
        }
      }
      if (!c->close_after && c->in.size() > kMaxRequest) {
        c->reply({{"ok", false},
                  {"error", "request too large (over " + std::to_string(kMaxRequest) + " bytes)"}});
        c->close_after = true;
      }
    }
  }
  if (c->close_after) c->in.clear();
  if (c->done())
    drop();
  else
    c->flush();  // sends what is left, and sets the events still wanted
  return 0;
}

int on_accept(sd_event_source*, int fd, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  const int cfd = ::accept4(fd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
  if (cfd < 0) return 0;
  struct ucred cred {};
  socklen_t len = sizeof cred;
  if (::getsockopt(cfd, SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0)
    d->info("control connection from pid " + std::to_string(cred.pid) + " uid " +
            std::to_string(cred.uid) + " gid " + std::to_string(cred.gid));
  auto c = std::make_unique<Client>();
  c->d = d;
  c->fd = cfd;
  sd_event_add_io(d->ev, &c->src, cfd, EPOLLIN, on_client, c.get());
  d->clients.push_back(std::move(c));
  return 0;
}

Status Daemon::setup() {
  TURNCAL_ASSIGN(c, load_config(opt.config));
  cfg = std::move(c);
  if (!opt.state_dir.empty()) cfg.daemon.state_directory = opt.state_dir;
  if (const char* sd = std::getenv("STATE_DIRECTORY"); sd != nullptr && opt.state_dir.empty())
    cfg.daemon.state_directory = std::string(sd).substr(0, std::string(sd).find(':'));
  if (!opt.socket.empty()) cfg.daemon.socket = opt.socket;
  TURNCAL_ASSIGN(d, load_databases(cfg.can));
  db = std::move(d);
  TURNCAL_ASSIGN(r, resolve_roles(cfg.can, db));
  roles = r;
  std::error_code ec;
  fs::create_directories(cfg.daemon.state_directory, ec);
  if (ec)
    return make_error("cannot create the state directory " + cfg.daemon.state_directory.string() +
                      ": " + ec.message());
  report_interrupted_runs();
  for (const auto& e : fs::directory_iterator(cfg.daemon.state_directory, ec)) {
    const std::string n = e.path().filename().string();
    if (!n.ends_with(".report.json")) continue;
    const std::string id = n.substr(0, n.size() - 12);
    if (!index.contains(id)) index_report(id, json::parse(read_file(e.path()), nullptr, false));
  }

  auto open_sock = [&](const std::string& iface) -> Result<socketcan::Socket> {
    socketcan::Options so;
    so.interface = iface;
    so.fd = cfg.can.fd;
    so.tx_queue_limit = cfg.can.tx_queue_frames;
    so.rcvbuf_bytes = static_cast<int>(cfg.can.rx_buffer_bytes);
    return socketcan::Socket::open(so);
  };
  TURNCAL_ASSIGN(is, open_sock(cfg.can.ins_interface));
  ins_sock.emplace(std::move(is));
  if (cfg.can.table_interface != cfg.can.ins_interface) {
    TURNCAL_ASSIGN(ts, open_sock(cfg.can.table_interface));
    table_sock.emplace(std::move(ts));
  }

  // the control socket: systemd's, or our own
  const int n = sd_listen_fds(1);
  if (n > 1) return make_error("expected one socket from systemd, got " + std::to_string(n));
  if (n == 1) {
    listen_fd = SD_LISTEN_FDS_START;
    ::fcntl(listen_fd, F_SETFL, ::fcntl(listen_fd, F_GETFL) | O_NONBLOCK);
  } else {
    const std::string path = cfg.daemon.socket.string();
    sockaddr_un a{};
    if (path.size() >= sizeof a.sun_path) return make_error("socket path too long: " + path);
    fs::create_directories(cfg.daemon.socket.parent_path(), ec);
    listen_fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    a.sun_family = AF_UNIX;
    std::memcpy(a.sun_path, path.c_str(), path.size());
    ::unlink(path.c_str());
    if (::bind(listen_fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::listen(listen_fd, 16) != 0)
      return make_error("cannot listen on " + path + ": " + std::strerror(errno));
    ::chmod(path.c_str(), 0660);
    if (!cfg.daemon.socket_group.empty()) {
      const group* g = ::getgrnam(cfg.daemon.socket_group.c_str());
      if (g == nullptr) return make_error("no group '" + cfg.daemon.socket_group + "'");
      if (::chown(path.c_str(), static_cast<uid_t>(-1), g->gr_gid) != 0)
        return make_error("cannot give " + path + " to group " + cfg.daemon.socket_group);
    }
  }
  if (::pipe2(done_pipe, O_CLOEXEC | O_NONBLOCK) != 0) return make_error("pipe failed");

  sd_event_default(&ev);
  sigset_t ss;
  sigemptyset(&ss);
  sigaddset(&ss, SIGTERM);
  sigaddset(&ss, SIGINT);
  sigprocmask(SIG_BLOCK, &ss, nullptr);
  sd_event_add_signal(ev, nullptr, SIGTERM, on_signal, this);
  sd_event_add_signal(ev, nullptr, SIGINT, on_signal, this);
  sd_event_add_io(ev, &ins_src, ins_sock->fd(), EPOLLIN, on_can_ins, this);
  if (table_sock) sd_event_add_io(ev, &table_src, table_sock->fd(), EPOLLIN, on_can_table, this);
  sd_event_add_io(ev, nullptr, listen_fd, EPOLLIN, on_accept, this);
  sd_event_add_io(ev, nullptr, done_pipe[0], EPOLLIN, on_worker_done, this);
  uint64_t now = 0;
  sd_event_now(ev, CLOCK_MONOTONIC, &now);
  sd_event_add_time(ev, nullptr, CLOCK_MONOTONIC, now, 1000, on_timer, this);
  sd_event_set_watchdog(ev, 1);  // WATCHDOG=1 from the loop itself, when WatchdogSec= asks
  return Status{Ok{}};
}

int usage(const char* why) {
  std::fprintf(stderr,
               "turncald: %s\nusage: turncald [--config FILE] [--state-dir DIR] [--socket PATH]\n",
               why);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  g_journal = std::getenv("JOURNAL_STREAM") != nullptr || std::getenv("INVOCATION_ID") != nullptr;
  Daemon d;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) return usage(("missing value after " + a).c_str());
    if (a == "--config")
      d.opt.config = argv[++i];
    else if (a == "--state-dir")
      d.opt.state_dir = argv[++i];
    else if (a == "--socket")
      d.opt.socket = argv[++i];
    else
      return usage(("unknown option " + a).c_str());
  }
  if (auto st = d.setup(); !st) {
    say(LOG_ERR, "", "idle", st.error().describe());
    sd_notifyf(0, "STATUS=failed: %s", st.error().describe().c_str());
    return 1;
  }
  d.info("ready: CAN " + d.cfg.can.ins_interface + "/" + d.cfg.can.table_interface + ", state " +
         d.cfg.daemon.state_directory.string());
  sd_notify(0, "READY=1\nSTATUS=idle");
  const int r = sd_event_loop(d.ev);
  if (d.worker.joinable()) d.worker.join();
  d.clients.clear();
  sd_event_unref(d.ev);
  return r < 0 ? 1 : 0;
}
