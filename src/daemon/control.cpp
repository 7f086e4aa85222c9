#include "control.hpp"

#include <cctype>
#include <initializer_list>

#include "turncal/run/history.hpp"
#include "turncal/run/report.hpp"

namespace turncal::daemon {

using nlohmann::json;

namespace {

json error_reply(const std::string& what) {
  return {{"ok", false}, {"error", what}};
}

/// Refuses a field the command does not know, naming it.
Status known_fields(const json& req, const std::string& cmd,
                    std::initializer_list<const char*> allowed) {
  for (const auto& [key, v] : req.items()) {
    if (key == "cmd") continue;
    bool ok = false;
    for (const char* a : allowed) ok = ok || key == a;
    if (!ok) return make_error(cmd + ": unknown field '" + key + "'");
  }
  return Status{Ok{}};
}

/// A string field, if present; an error naming it when it is not a string.
Result<std::optional<std::string>> string_field(const json& req, const std::string& cmd,
                                                const char* key) {
  if (!req.contains(key)) return std::optional<std::string>{};
  if (!req[key].is_string()) return make_error(cmd + ": " + key + ": expected a string");
  return std::optional<std::string>{req[key].get<std::string>()};
}

Result<StartRequest> parse_start(const json& req) {
  TURNCAL_TRY(
      known_fields(req, "start",
                   {"plan_text", "plan_name", "profile", "observe", "heading_offset_deg", "unit"}));
  StartRequest s;
  TURNCAL_ASSIGN(text, string_field(req, "start", "plan_text"));
  TURNCAL_ASSIGN(name, string_field(req, "start", "plan_name"));
  TURNCAL_ASSIGN(profile, string_field(req, "start", "profile"));
  if (name && !text)
    return make_error(
        "start: plan_name: names the plan_text sent with it; a plan of the "
        "profiles directory goes as profile");
  if (text && profile)
    return make_error("start: plan_text and profile: give the plan's text or its name, not both");
  if (text) {
    if (text->empty() || text->size() > kMaxPlanText)
      return make_error("start: plan_text: expected a plan of 1 to " +
                        std::to_string(kMaxPlanText) + " bytes");
    s.plan_text = *text;
    s.plan_name = name.value_or("plan");
    if (s.plan_name.size() > 255) return make_error("start: plan_name: at most 255 bytes");
  } else if (profile) {
    // a name from the profiles directory, never a path: the daemon opens
    // no file a client names
    if (!valid_name(*profile))
      return make_error(
          "start: profile: expected the name of a plan in the profiles directory "
          "(letters, digits, '-', '_', '.'); a plan file of your own goes as "
          "its text (turncalctl start --profile FILE reads it)");
    s.plan_name = *profile;
  }
  if (req.contains("observe")) {
    if (!req["observe"].is_boolean()) return make_error("start: observe: expected true or false");
    s.observe = req["observe"].get<bool>();
  }
  if (req.contains("heading_offset_deg")) {
    const json& h = req["heading_offset_deg"];
    if (!h.is_number() || !std::isfinite(h.get<double>()) || std::abs(h.get<double>()) > 360)
      return make_error("start: heading_offset_deg: expected a number of degrees, -360 to 360");
    s.heading_offset_deg = h.get<double>();
  }
  TURNCAL_ASSIGN(unit, string_field(req, "start", "unit"));
  if (unit) {
    if (!valid_unit(*unit))
      return make_error(
          "start: unit: expected the INS identity, 1 to 64 letters, digits, '-', '_' or '.'");
    s.unit = *unit;
  }
  return s;
}

}  // namespace

bool valid_unit(std::string_view u) {
  if (u.empty() || u.size() > 64) return false;
  for (const char c : u)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_' && c != '.')
      return false;
  return true;
}

bool valid_name(std::string_view n) {
  return valid_unit(n) && n != "." && n != "..";
}

Result<Request> parse_request(std::string_view line) {
  const json req = json::parse(line, nullptr, false);
  if (req.is_discarded()) return make_error("malformed request: not JSON");
  if (!req.is_object() || !req.contains("cmd") || !req["cmd"].is_string())
    return make_error("malformed request: expected {\"cmd\": ...}");
  const std::string cmd = req["cmd"].get<std::string>();
  if (cmd == "status" || cmd == "watch" || cmd == "reports") {
    TURNCAL_TRY(known_fields(req, cmd, {}));
    if (cmd == "status") return Request{StatusRequest{}};
    if (cmd == "watch") return Request{WatchRequest{}};
    return Request{ReportsRequest{}};
  }
  if (cmd == "start") {
    TURNCAL_ASSIGN(s, parse_start(req));
    return Request{std::move(s)};
  }
  if (cmd == "abort") {
    TURNCAL_TRY(known_fields(req, cmd, {"reason"}));
    TURNCAL_ASSIGN(reason, string_field(req, cmd, "reason"));
    if (reason && reason->size() > 1024) return make_error("abort: reason: at most 1024 bytes");
    return Request{AbortRequest{reason.value_or("")}};
  }
  if (cmd == "history") {
    TURNCAL_TRY(known_fields(req, cmd, {"unit"}));
    TURNCAL_ASSIGN(unit, string_field(req, cmd, "unit"));
    if (!unit || !valid_unit(*unit)) return make_error("history: expected a unit");
    return Request{HistoryRequest{*unit}};
  }
  if (cmd == "report") {
    TURNCAL_TRY(known_fields(req, cmd, {"run_id"}));
    TURNCAL_ASSIGN(id, string_field(req, cmd, "run_id"));
    if (!id || !valid_name(*id)) return make_error("report: expected a run_id");
    return Request{ReportRequest{*id}};
  }
  return make_error("unknown command '" + cmd.substr(0, 64) + "'");
}

json report_summary(const json& r) {
  json s = json::object();
  for (const char* k : {"run_id", "status", "unit", "start_time_unix_s"})
    if (r.contains(k)) s[k] = r[k];
  // of each estimate what the list and the history read: the index holds
  // one summary per report kept, for the daemon's life
  if (const auto est = r.find("estimates"); est != r.end() && est->is_object()) {
    json e = json::object();
    for (auto it = est->begin(); it != est->end(); ++it) {
      json t = json::object();
      if (it->is_object())
        for (const char* k : {"value", "sigma", "unit", "determined"})
          if (const auto f = it->find(k); f != it->end()) t[k] = *f;
      e[it.key()] = std::move(t);
    }
    s["estimates"] = std::move(e);
  }
  const bool has_profile = r.contains("profile") && r["profile"].is_object();
  const bool has_verdict = r.contains("verdict") && r["verdict"].is_object();
  s["profile"] = {{"name", has_profile ? r["profile"].value("name", "") : ""}};
  s["verdict"] = {{"pass", has_verdict && r["verdict"].value("pass", false)}};
  return s;
}

Outcome dispatch(std::string_view line, const View& view) {
  Outcome o;
  auto req = parse_request(line);
  if (!req) {
    o.reply = error_reply(req.error().describe());
    return o;
  }
  std::visit(
      [&](auto& r) {
        using T = std::decay_t<decltype(r)>;
        if constexpr (std::is_same_v<T, StatusRequest>) {
          o.reply = view.status();
        } else if constexpr (std::is_same_v<T, WatchRequest>) {
          o.watch = true;
          o.reply = view.status();
        } else if constexpr (std::is_same_v<T, StartRequest>) {
          o.action = std::move(r);
        } else if constexpr (std::is_same_v<T, AbortRequest>) {
          if (!view.running)
            o.reply = error_reply("no run in progress");
          else
            o.action = std::move(r);
        } else if constexpr (std::is_same_v<T, ReportsRequest>) {
          json list = json::array();
          for (const auto& [id, e] : *view.index) {
            const json& s = e.summary;
            if (!e.unreadable.empty()) {
              list.push_back({{"run_id", id},
                              {"status", "unreadable"},
                              {"reason", e.unreadable},
                              {"unit", nullptr},
                              {"pass", false}});
              continue;
            }
            list.push_back({{"run_id", id},
                            {"status", s.value("status", "?")},
                            {"unit", s.contains("unit") ? s["unit"] : json(nullptr)},
                            {"pass", s["verdict"]["pass"]}});
          }
          o.reply = {{"ok", true}, {"reports", list}};
        } else if constexpr (std::is_same_v<T, HistoryRequest>) {
          std::vector<json> all;
          all.reserve(view.index->size());
          for (const auto& [id, e] : *view.index)
            if (e.unreadable.empty()) all.push_back(e.summary);
          const json h = run::history_json(r.unit, all);
          o.reply = {{"ok", true}, {"history", h}, {"text", run::history_text(h)}};
        } else if constexpr (std::is_same_v<T, ReportRequest>) {
          auto rep = view.read_report(r.run_id);
          if (!rep)
            o.reply = error_reply(rep.error().describe());
          else
            o.reply = {{"ok", true}, {"report", *rep}, {"text", run::report_text(*rep)}};
        }
      },
      *req);
  return o;
}

}  // namespace turncal::daemon
