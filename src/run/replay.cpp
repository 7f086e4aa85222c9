#include "turncal/run/replay.hpp"

#include <cmath>
#include <filesystem>
#include <future>
#include <limits>
#include <memory>

#include "turncal/can/candump.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/plan.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/html.hpp"
#include "turncal/run/read_ahead.hpp"
#include "turncal/run/report.hpp"

namespace turncal::run {

using nlohmann::json;

const char* software_version() {
  return TURNCAL_VERSION;
}

namespace {

/// Stand time between engine ticks in a replay: the daemon ticks at 10 Hz;
/// ten times as often costs little and judges staleness no later.
constexpr double kTickS = 0.01;
/// Frames received closer together than this (host time) are one burst.
constexpr std::int64_t kBurstNs = 1'000'000;
constexpr std::int64_t kBurstMaxNs = 20'000'000;

Result<Plan> replay_plan(const Config& cfg, const json* live, const ReplayOptions& o) {
  std::vector<std::string> overrides;
  if (o.profile.empty() && live != nullptr && live->contains("profile") &&
      (*live)["profile"].contains("toml") && (*live)["profile"]["toml"].is_string()) {
    const json& p = (*live)["profile"];
    if (p.contains("overrides") && p["overrides"].is_array())
      for (const json& s : p["overrides"])
        if (s.is_string()) overrides.push_back(s.get<std::string>());
    overrides.insert(overrides.end(), o.overrides.begin(), o.overrides.end());
    return parse_plan(p["toml"].get<std::string>(),
                      p.value("file", std::string("the live report's profile")), overrides);
  }
  const std::string path = o.profile.empty() ? cfg.daemon.profile.string() : o.profile;
  return load_plan(path, o.overrides);
}

/// A number at a JSON path of the live report, if it is there.
std::optional<double> live_number(const json* live, const char* section, const char* key) {
  if (live == nullptr || !live->contains(section)) return std::nullopt;
  const json& s = (*live)[section];
  if (!s.is_object() || !s.contains(key) || !s[key].is_number()) return std::nullopt;
  return s[key].get<double>();
}

/// The live run's loop holds (Engine::Hold): those its report lists, and
/// how many there were.
struct LiveHolds {
  std::vector<Engine::Hold> at;
  std::uint64_t count = 0;
};

/// A report from before holds were kept has none; one that lists them
/// wrongly (not [from, to] with from before to, out of order, overlapping)
/// is refused: they decide which silences the replay excuses.
Result<LiveHolds> live_holds(const json* live) {
  LiveHolds h;
  if (live == nullptr || !live->contains("loop_holds")) return h;
  const json& j = (*live)["loop_holds"];
  auto bad = [](const std::string& what) {
    return make_error("the live report's loop_holds: " + what +
                      "; it decides which silences the replay excuses: replay without the report");
  };
  if (!j.is_object() || !j.contains("at_s") || !j.at("at_s").is_array() || !j.contains("count") ||
      !j.at("count").is_number_integer() || j.at("count").get<std::int64_t>() < 0)
    return bad("not a count and a list at_s");
  h.count = static_cast<std::uint64_t>(j.at("count").get<std::int64_t>());
  const json& at = j.at("at_s");
  double end = -std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < at.size(); ++i) {
    const json& e = at.at(i);
    const std::string which = "at_s[" + std::to_string(i) + "]";
    if (!e.is_array() || e.size() != 2 || !e.at(0).is_number() || !e.at(1).is_number())
      return bad(which + " is not [from, to]");
    const Engine::Hold hold{e.at(0).get<double>(), e.at(1).get<double>()};
    if (!std::isfinite(hold.from_s) || !std::isfinite(hold.to_s) || !(hold.from_s < hold.to_s))
      return bad(which + " does not end after it starts");
    if (!(hold.from_s >= end)) return bad(which + " starts before the one before it ends");
    end = hold.to_s;
    h.at.push_back(hold);
  }
  if (h.count < h.at.size()) return bad("count is less than the holds listed");
  return h;
}

/// Roles of each stream, and the message that carries them, for a log that
/// never carried it.
std::vector<std::string> missing_roles(const Engine& e, const RoleMap& roles) {
  static constexpr std::array<std::array<Role, 2>, kStreams> kOf = {{
      {Role::InsVelEast, Role::InsVelNorth},
      {Role::InsMode, Role::InsMode},
      {Role::EncoderAngle, Role::EncoderAngle},
      {Role::TableState, Role::TableState},
  }};
  std::vector<std::string> out;
  for (int s = 0; s < kStreams; ++s) {
    if (e.ingest().health(static_cast<Stream>(s)).frames > 0) continue;
    const auto& rs = kOf[static_cast<std::size_t>(s)];
    std::array<Role, 2> r = rs;
    // a CiA 402 drive's TPDO1 carries the table's encoder and status
    if (roles[r[0]].message == nullptr && roles.has(Role::TablePositionActual))
      r = s == kEncoder ? std::array<Role, 2>{Role::TablePositionActual, Role::TablePositionActual}
                        : std::array<Role, 2>{Role::TableStatusword, Role::TableStatusword};
    std::string names(role_key(r[0]));
    if (r[1] != r[0]) names += ", " + std::string(role_key(r[1]));
    const can::Message* m = roles[r[0]].message;
    if (m == nullptr) {
      out.push_back(names);
      continue;
    }
    char id[16];
    std::snprintf(id, sizeof id, m->extended ? "0x%08X" : "0x%03X", m->id);
    out.push_back(names + " (message " + m->name + ", id " + id + ")");
  }
  return out;
}

}  // namespace

Result<ReplayOutcome> replay_log(const Config& cfg, const can::Database& db, const RoleMap& roles,
                                 const std::string& log_path, const json* live,
                                 const ReplayOptions& options) {
  // the live report's settings are read as check_report has found them:
  // of their types, and the bounds and the time scale ones a run can have
  if (live != nullptr)
    if (const std::string why = check_report(*live); !why.empty())
      return make_error("the live report: " + why);
  TURNCAL_ASSIGN(plan, replay_plan(cfg, live, options));
  TURNCAL_ASSIGN(file, can::LogReader::open(log_path));
  ReadAheadLogReader reader(std::move(file));  // parsed on a core of its own
  // the log's digest for the report, on a second core while the log replays
  // (hashing a two-hour log takes as long as replaying it)
  auto log_digest = std::async(std::launch::async, [&log_path] { return sha256_file(log_path); });
  ReplayOutcome out;

  SequencerSettings q;
  q.profile = plan.profile;
  q.start_angle_rad = plan.start_angle_rad;
  q.heading_offset_rad = options.heading_offset_rad.value_or(
      live_number(live, "settings", "heading_offset_rad").value_or(cfg.stand.heading_offset_rad));
  q.limits = cfg.stand.limits;
  q.observe = true;
  q.estimate_partial = true;
  BuildSettings b;
  b.heading_offset_rad = q.heading_offset_rad;
  b.two_stage = true;
  if (live != nullptr && live->contains("settings") && (*live)["settings"].contains("two_stage"))
    b.two_stage = (*live)["settings"]["two_stage"].get<bool>();
  if (options.two_stage) b.two_stage = *options.two_stage;
  if (options.second_pass) b.second_pass = *options.second_pass;

  // the next record; a line that does not parse ends the log there
  const can::LogRecord* rec = nullptr;
  std::optional<LogDamage> damage;
  auto next = [&] {
    auto r = reader.next();
    if (!r) damage = LogDamage{reader.line_number(), r.error().describe()};
    rec = r ? *r : nullptr;
    return rec != nullptr;
  };
  // the first record: the time base of a log without a live report
  bool have = next();
  if (!have && !damage) return make_error(log_path + ": the log is empty");
  TimeBase tb{have ? rec->time_ns / 1000 : 0, cfg.stand.time_scale};
  if (const auto e = live_number(live, "time_base", "epoch_us")) tb.epoch_us = std::llround(*e);
  if (const auto s = live_number(live, "time_base", "scale")) tb.scale = *s;
  // the live run's floor (none before reports carried it), else the config's
  q.stale_floor_s =
      live_number(live, "settings", "stale_floor_s")
          .value_or(live != nullptr ? 0.0 : cfg.daemon.stale_floor_ms * 1e-3 * tb.scale);
  // the same of the floor a stand run faster than real time gets: its
  // clock checks saw it live (none before reports carried it)
  q.real_time_floor_s =
      live_number(live, "settings", "real_time_floor_s")
          .value_or(live != nullptr ? 0.0
                                    : real_time_floor_s(cfg.stand.real_time_floor_ms, tb.scale));

  // the live run's bounds on what a frame can be; a run from before reports
  // carried them checked nothing, and neither does its replay
  const json* live_pl =
      live != nullptr && live->contains("plausibility") && (*live)["plausibility"].is_object()
          ? &(*live)["plausibility"]
          : nullptr;
  Plausibility pl = live != nullptr && !live->contains("plausibility") ? Plausibility::none()
                                                                       : plausibility_of(cfg);
  // a bound written as null is none (JSON has no infinity)
  const auto bound = [live, live_pl](const char* key, double otherwise) {
    if (live_pl != nullptr && live_pl->contains(key) && (*live_pl)[key].is_null())
      return std::numeric_limits<double>::infinity();
    return live_number(live, "plausibility", key).value_or(otherwise);
  };
  pl.max_velocity_mps = bound("max_velocity_mps", pl.max_velocity_mps);
  pl.max_table_rate_rps = bound("max_table_rate_rps", pl.max_table_rate_rps);
  pl.max_fraction = live_number(live, "plausibility", "max_fraction").value_or(pl.max_fraction);
  pl.step_slack_s = live_number(live, "plausibility", "step_slack_s").value_or(pl.step_slack_s);
  // whether frames were held to their DBC ranges: a replay of a run from
  // before the bounds was not. Reports say so since; before, such a
  // replay's report had no velocity bound (null), which no configuration
  // gives (its range is finite)
  if (live_pl != nullptr) {
    if (live_pl->contains("dbc_ranges"))
      pl.dbc_ranges = (*live_pl)["dbc_ranges"].get<bool>();
    else if (live_pl->contains("max_velocity_mps") && (*live_pl)["max_velocity_mps"].is_null())
      pl.dbc_ranges = false;
  }
  drivers::Devices dev = drivers::make_devices(cfg.can, roles, pl, tb.scale);
  // the live run's table geometry (reports carry it since it could differ)
  if (live != nullptr && live->contains("settings") && (*live)["settings"].is_object() &&
      (*live)["settings"].contains("table_geometry") &&
      (*live)["settings"]["table_geometry"].is_string()) {
    const std::string recorded = (*live)["settings"]["table_geometry"].get<std::string>();
    const std::string here = dev.table->geometry();
    if (recorded != here)
      return make_error("the run's table turned counts into angles as \"" + recorded +
                        "\", this configuration as \"" + here +
                        "\": replayed so, every table angle would be scaled or mirrored; replay "
                        "with the run's own configuration");
  }
  Engine engine(db, std::move(dev.ins), std::move(dev.table), plan, q, b, tb, pl);
  std::vector<OutFrame> sent;  // observe mode sends nothing; kept for the interface
  engine.start(tb.epoch_us * 1000, sent);
  // where the live loop was held, it judged no stream lost; nor does the replay
  TURNCAL_ASSIGN(holds, live_holds(live));
  const std::uint64_t holds_unlisted = holds.count - holds.at.size();
  engine.replay_holds(holds.at);
  engine.replaying();
  // the log's times are to the microsecond, the live loop's to the nanosecond
  const double stamp_slack_s = 2e-6 * tb.scale;
  std::int64_t first_ns = have ? rec->time_ns : 0, last_ns = first_ns;
  std::int64_t next_tick_ns = first_ns;
  std::int64_t last_t = first_ns, burst_start = first_ns;
  const auto tick_ns = static_cast<std::int64_t>(kTickS / tb.scale * 1e9);
  while (have) {
    // a hold is a stretch no frame was stamped in: one in it says the
    // report is not this log's
    if (!holds.at.empty()) {
      const double at = engine.stand_s(rec->time_ns);
      // the log takes each port's frames in turn: its times may step back
      const auto after = std::ranges::upper_bound(holds.at, at, {}, &Engine::Hold::from_s);
      if (after != holds.at.begin() && at > std::prev(after)->from_s + stamp_slack_s &&
          at < std::prev(after)->to_s - stamp_slack_s)
        return make_error("the live report's loop_holds: at_s[" +
                          std::to_string(std::distance(holds.at.begin(), after) - 1) +
                          "] is a stretch no frame was stamped in, and line " +
                          std::to_string(reader.line_number()) +
                          " of the log is in it: the report is not this log's; replay without it");
    }
    engine.on_frame(rec->frame, rec->time_ns, sent);
    const std::int64_t t = rec->time_ns;
    last_ns = std::max(last_ns, t);
    if (engine.estimation_due()) break;
    have = next();
    // The daemon takes in all that has arrived before it judges a stream
    // lost, so a host that stalled (every stream silent, then a burst) was
    // never short of frames; no tick inside a burst, then (for a while: a
    // bus that busy is no burst).
    if (t - last_t > kBurstNs) burst_start = t;
    last_t = t;
    const bool burst = have && rec->time_ns - t < kBurstNs && t - burst_start < kBurstMaxNs;
    if (!burst && t >= next_tick_ns) {
      engine.tick(t, sent);
      next_tick_ns = t + tick_ns;
      if (engine.estimation_due()) break;
    }
  }
  out.lines = reader.line_number();
  out.damage = damage;
  if (!engine.estimation_due()) engine.end_of_input(last_ns, sent);

  std::optional<BuiltInput> input;
  std::optional<est::EstimationResult> result;
  if (engine.estimation_due()) {
    auto in = engine.take_estimation_input();
    if (!in) {
      engine.estimation_done(last_ns, false, in.error().describe(), sent);
    } else {
      input = std::move(*in);
      auto r = est::estimate(input->input);
      if (r) result = std::move(*r);
      engine.estimation_done(last_ns, r.ok(), r ? "" : r.error().describe(), sent);
    }
  }
  out.missing = missing_roles(engine, roles);

  ReportContext ctx;
  namespace fs = std::filesystem;
  ctx.run_id =
      live != nullptr ? live->value("run_id", std::string()) : fs::path(log_path).stem().string();
  ctx.start_unix_s = live != nullptr ? live->value("start_time_unix_s", 0.0)
                                     : static_cast<double>(first_ns) * 1e-9;
  ctx.end_unix_s =
      live != nullptr ? live->value("end_time_unix_s", 0.0) : static_cast<double>(last_ns) * 1e-9;
  ctx.software_version = software_version();
  ctx.config_file = cfg.source.string();
  if (auto d = sha256_file(cfg.source.string())) ctx.config_sha256 = d->sha256;
  ctx.log_file = fs::path(log_path).filename().string();
  if (auto d = log_digest.get()) ctx.log_sha256 = d->sha256;
  ctx.tolerances = cfg.tolerances;
  ctx.mode = "replay";
  if (live != nullptr && live->contains("unit") && (*live)["unit"].is_string())
    ctx.unit = (*live)["unit"].get<std::string>();
  const bool est = input && result;
  out.report = report_json(ctx, engine, est ? &*input : nullptr, est ? &*result : nullptr);
  engine.report_written(last_ns, true, "", sent);

  json r = {{"log_lines", out.lines},
            {"of_live_report", live != nullptr},
            {"overrides", options.overrides},
            {"missing_roles", out.missing},
            // past the report's list: those silences are judged as the log shows them
            {"loop_holds_unlisted", holds_unlisted}};
  r["damage"] = damage ? json{{"line", damage->line}, {"what", damage->what}} : json(nullptr);
  out.report["replay"] = r;
  if (damage && !out.report.contains("reason"))
    out.report["reason"] = "the log is damaged at line " + std::to_string(damage->line) +
                           ": estimated from the frames before it";
  if (options.html)
    out.html = report_html(out.report, est ? &*input : nullptr, est ? &*result : nullptr);
  return out;
}

}  // namespace turncal::run
