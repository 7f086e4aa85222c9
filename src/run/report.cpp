#include "turncal/run/report.hpp"

#include "turncal/run/calibration.hpp"

#include "turncal/earth.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>

#include "text_format.hpp"

namespace turncal::run {

using detail::fmt;

using nlohmann::json;

// ---- the report ----

namespace {

json estimate_json(const est::ParameterEstimate& p) {
  const Determination d = determination(p.name, p.sigma, p.prior_sigma);
  json j = {{"value", p.value},
            {"sigma", p.sigma},
            {"prior_sigma", p.prior_sigma},
            {"unit", std::string(p.unit)},
            {"determined", d.label}};
  if (!d.why.empty()) j["why"] = d.why;
  return j;
}

json health_json(const StreamHealth& h, double now) {
  return {{"frames", h.frames},
          {"dropped", h.dropped},
          {"nominal_hz", h.nominal_hz},
          {"rate_hz", h.rate_hz()},
          {"implausible", h.implausible},
          {"age_s", std::isnan(h.last_host_s) ? json(nullptr) : json(h.age_s(now))}};
}

}  // namespace

Determination determination(std::string_view name, double sigma, double prior_sigma) {
  const double ratio =
      prior_sigma > 0 ? sigma / prior_sigma : std::numeric_limits<double>::quiet_NaN();
  if (ratio < 0.5) return {"determined", ""};
  const std::string why(est::why_undetermined(name));
  if (!(ratio <= 0.9)) return {"not determined", why};
  return {"partly", why};
}

json judge(const json& estimates, const std::vector<Tolerance>& tolerances) {
  json checks = json::array();
  bool pass = true;
  int untested = 0;
  for (const Tolerance& t : tolerances) {
    const auto [unit, k] = display_unit(t.parameter);
    json c = {{"parameter", t.parameter}, {"unit", std::string(unit)}};
    if (!estimates.contains(t.parameter)) {
      c["pass"] = false;
      c["why"] = "not estimated";
      pass = false;
      checks.push_back(c);
      continue;
    }
    const json& e = estimates[t.parameter];
    if (e.value("determined", std::string()) == "not determined" && !std::isfinite(t.max_sigma)) {
      // its value is the prior's: a bound on it would pass or fail by chance
      // (a bound on its sigma is judged: it asks that the run determine it)
      c["pass"] = true;
      c["tested"] = false;
      c["why"] = "not determined by this run: " + e.value("why", std::string());
      ++untested;
      checks.push_back(c);
      continue;
    }
    const double v = estimates[t.parameter]["value"].get<double>() * k;
    const double s = estimates[t.parameter]["sigma"].get<double>() * k;
    // not determined, with a bound on its sigma: that bound decides
    const bool value_judged = e.value("determined", std::string()) != "not determined";
    const bool ok_v = !value_judged || std::abs(v) <= t.max_abs, ok_s = s <= t.max_sigma;
    if (!value_judged) c["why"] = "not determined by this run: its value is not judged";
    c["value"] = v;
    c["sigma"] = s;
    if (std::isfinite(t.max_abs)) c["max_abs"] = t.max_abs;
    if (std::isfinite(t.max_sigma)) c["max_sigma"] = t.max_sigma;
    c["pass"] = ok_v && ok_s;
    pass = pass && ok_v && ok_s;
    checks.push_back(c);
  }
  return {{"pass", pass}, {"checks", checks}, {"not_tested", untested}};
}

json combination_json(const est::Combination& c, bool with_value) {
  json coeff = json::object();
  for (std::size_t i = 0; i < c.coeff.size(); ++i)
    if (c.coeff[i] != 0) coeff[std::string(est::kParamNames[i])] = c.coeff[i];
  const auto lead = static_cast<std::size_t>(c.lead);
  json j = {{"lead", std::string(est::kParamNames[lead])},
            {"unit", std::string(est::kParamUnits[lead])},
            {"coefficients", coeff}};
  if (with_value) j["value"] = c.value;
  j["sigma"] = c.sigma;
  j["prior_sigma"] = c.prior_sigma;
  if (!c.name.empty()) {
    j["name"] = std::string(c.name);
    const std::string i(c.name.substr(c.name.size() - 1));
    j["formula"] = "df0_" + i + " + g G" + i + "3 - g Theta_" + i + "3";
  }
  if (c.from_degenerate) j["degenerate"] = true;
  return j;
}

json report_json(const ReportContext& ctx, const Engine& engine, const BuiltInput* input,
                 const est::EstimationResult* result) {
  const Sequencer& seq = engine.sequencer();
  const Course& course = seq.course();
  const Plan& plan = engine.plan();
  const double now = seq.course().marks.empty() ? 0 : seq.course().marks.back().t_s;
  json j;
  j["format"] = "turncal-report-1";
  j["schema_version"] = kReportSchemaVersion;
  j["run_id"] = ctx.run_id;
  // written in the report phase, the report is that of a finished run
  j["status"] = to_string(seq.phase() == Phase::Report ? Phase::Done : seq.phase());
  if (!course.reason.empty()) j["reason"] = course.reason;
  if (!course.signal_in_estimate.empty())
    j["stop_signal"] = course.signal_in_estimate +
                       " during the estimate: the estimate was finished and this report written "
                       "before the daemon stopped";
  j["start_time_unix_s"] = ctx.start_unix_s;
  j["end_time_unix_s"] = ctx.end_unix_s;
  j["software_version"] = ctx.software_version;
  j["mode"] = ctx.mode;
  j["unit"] = ctx.unit.empty() ? json(nullptr) : json(ctx.unit);
  j["config"] = {{"file", ctx.config_file}, {"sha256", ctx.config_sha256}};
  j["log"] = {{"file", ctx.log_file}, {"sha256", ctx.log_sha256}};
  j["time_base"] = {{"epoch_us", engine.time_base().epoch_us}, {"scale", engine.time_base().scale}};
  j["site"] = {{"latitude_rad", plan.site.latitude_rad}, {"height_m", plan.site.height_m}};
  json turns = json::array();
  for (const TurnSpec& t : plan.profile.turns)
    turns.push_back({{"start_s", t.start_s},
                     {"angle_rad", t.angle_rad},
                     {"max_rate_rps", t.max_rate_rps},
                     {"max_accel_rps2", t.max_accel_rps2}});
  j["profile"] = {{"name", plan.name},
                  {"file", plan.source},
                  {"align_s", plan.profile.align_s},
                  {"duration_s", plan.profile.duration_s},
                  {"start_angle_rad", plan.start_angle_rad},
                  {"turns", turns},
                  {"toml", plan.text},
                  {"overrides", plan.overrides}};
  // what a replay needs besides the log and the profile to see what this run saw
  // no bound (infinite) is null, in the file as in memory (JSON has no infinity)
  const auto bound = [](double b) { return std::isfinite(b) ? json(b) : json(nullptr); };
  j["plausibility"] = {{"max_velocity_mps", bound(engine.plausibility().max_velocity_mps)},
                       {"max_table_rate_rps", bound(engine.plausibility().max_table_rate_rps)},
                       {"max_fraction", engine.plausibility().max_fraction},
                       {"step_slack_s", engine.plausibility().step_slack_s},
                       {"dbc_ranges", engine.plausibility().dbc_ranges}};
  j["settings"] = {{"heading_offset_rad", seq.settings().heading_offset_rad},
                   {"observe", seq.settings().observe},
                   {"stale_floor_s", seq.settings().stale_floor_s},
                   {"real_time_floor_s", seq.settings().real_time_floor_s},
                   {"two_stage", engine.build_settings().two_stage},
                   {"table_geometry", engine.ingest().table().geometry()}};
  // the host's machine held (Engine::Hold): the silences excused, and those not
  json holds = json::array();
  for (const Engine::Hold& h : engine.holds()) holds.push_back({h.from_s, h.to_s});
  j["loop_holds"] = {{"count", engine.hold_count()},
                     {"longest_s", engine.longest_hold_s()},
                     {"not_excused", engine.holds_unexcused()},
                     {"at_s", holds}};
  // health
  const Ingest& in = engine.ingest();
  // what the table's driver told that is no fault: a drive's warning EMCY,
  // an optional object it refused
  j["table_notices"] = in.table().notices();
  j["health"] = {
      {"ins_velocity", health_json(in.health(kVelocity), now)},
      {"ins_status", health_json(in.health(kInsStatus), now)},
      {"table_encoder", health_json(in.health(kEncoder), now)},
      {"table_status", health_json(in.health(kTableStatus), now)},
      {"frames", in.counters().frames},
      {"unknown_id", in.counters().unknown_id},
      {"malformed", in.counters().malformed},
      {"ignored", in.counters().ignored},
      {"clock_outliers", in.counters().clock_outliers},
      {"velocity_tags_dropped", engine.record().velocity_tags().dropped()},
      {"encoder_tags_dropped", engine.record().encoder_tags().dropped()},
      {"clock_late_frames", in.ins_clock().late() + in.table_clock().late()},
      {"half_velocity_pairs", in.counters().half_pairs},
      {"velocity_untimed", in.counters().velocity_untimed},
      {"encoder_reanchored", in.counters().encoder_reanchored},
      {"ins_clock_rate_ppm", in.ins_clock().rate_ppm()},
      {"table_clock_rate_ppm", in.table_clock().rate_ppm()},
      {"ins_clock_rms_s", in.ins_clock().rms_s()},
      {"table_clock_rms_s", in.table_clock().rms_s()},
  };
  // phase timings, from the start
  json phases = json::array();
  const double t_start = course.marks.empty() ? 0 : course.marks.front().t_s;
  for (std::size_t i = 0; i < course.marks.size(); ++i) {
    const PhaseMark& m = course.marks[i];
    json p = {{"phase", to_string(m.phase)}, {"start_s", m.t_s - t_start}};
    if (m.index > 0) p["index"] = m.index;
    if (i + 1 < course.marks.size()) p["duration_s"] = course.marks[i + 1].t_s - m.t_s;
    phases.push_back(p);
  }
  j["phases"] = phases;
  j["t0_from_start_s"] = std::isnan(course.t0_s) ? json(nullptr) : json(course.t0_s - t_start);
  j["quick_stop"] = {{"sent", course.quick_stop_sent},
                     {"acknowledged", course.quick_stop_acked},
                     {"times", course.quick_stops_sent}};
  if (!ctx.can.is_null()) j["can"] = ctx.can;
  if (!std::isnan(course.heading_given_rad)) j["heading_given_rad"] = course.heading_given_rad;
  if (input != nullptr) {
    json achieved = json::array();
    for (const TurnAchieved& a : input->turns)
      achieved.push_back(
          {{"start_s", a.t_start_s},
           {"end_s", a.t_end_s},
           {"angle_rad", a.angle_rad},
           {"peak_rate_rps", a.peak_rate_rps},
           {"planned_angle_rad",
            std::isnan(a.planned_angle_rad) ? json(nullptr) : json(a.planned_angle_rad)}});
    j["turns_achieved"] = achieved;
    j["velocity_samples"] = input->velocity_used;
    j["notes"] = input->notes;
  }
  if (result != nullptr) {
    json e = json::object();
    for (const auto& p : result->parameters) e[std::string(p.name)] = estimate_json(p);
    for (const auto& p : result->df_eff) e[std::string(p.name)] = estimate_json(p);
    for (const auto& p : result->df_obs) e[std::string(p.name)] = estimate_json(p);
    j["estimates"] = e;
    json combos = json::array();
    for (const est::Combination& c : result->combinations)
      combos.push_back(combination_json(c, true));
    j["combinations"] = combos;
    // the parameters' covariance, SI, in the model's order: what a
    // calibration file exports of the block the run determined
    // (turncalctl export); from the correlation and the sigmas above, so
    // the two agree
    json order = json::array();
    json rows = json::array();
    for (std::size_t a = 0; a < est::kParamNames.size(); ++a) {
      order.push_back(std::string(est::kParamNames[a]));
      json row = json::array();
      for (std::size_t b = 0; b < est::kParamNames.size(); ++b)
        row.push_back(
            result->correlation(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) *
            result->parameters[a].sigma * result->parameters[b].sigma);
      rows.push_back(row);
    }
    j["covariance"] = {{"order", order}, {"matrix", rows}};
    if (result->has_two_stage) {
      json ts = json::object();
      for (std::size_t i = 0; i < est::kParamNames.size(); ++i)
        ts[std::string(est::kParamNames[i])] = {
            {"sigma", result->two_stage.sigma[i]},
            {"single_loop_over_two_stage", result->two_stage.ratio[i]}};
      j["two_stage"] = ts;
    }
    const est::InnovationStats& s = result->innovation_stats;
    j["innovations"] = {{"count", s.count},
                        {"nis_mean", s.nis_mean},
                        {"nis_95_interval", {s.nis_lo, s.nis_hi}},
                        {"consistent", s.consistent()},
                        {"ljung_box_lags", s.lags},
                        {"ljung_box", {s.ljung_box[0], s.ljung_box[1]}},
                        {"ljung_box_limit", s.ljung_box_limit},
                        {"ljung_box_p", {s.ljung_box_p[0], s.ljung_box_p[1]}},
                        {"alarm_p", est::InnovationStats::kAlarmP},
                        {"white", s.white()},
                        {"degraded_updates", result->degraded_updates}};
    // the nonlinear second pass (model.md, 8): whether it ran and why
    const est::SecondPass& sp = result->second_pass;
    j["second_pass"] = {{"ran", sp.ran},
                        {"reason", sp.reason},
                        {"predicted_error_sigma", sp.predicted_sigma},
                        {"iterations", sp.iterations},
                        {"converged", sp.converged}};
    if (std::isfinite(sp.last_change_sigma))
      j["second_pass"]["last_change_sigma"] = sp.last_change_sigma;
    j["verdict"] = judge(e, ctx.tolerances);
  } else {
    j["verdict"] = {{"pass", false}, {"checks", json::array()}, {"why", "no estimates"}};
  }
  return j;
}

namespace {

/// The injected value of an estimate: a parameter, or df_eff_i = df0_i + g G_i3.
std::optional<double> truth_of(const json& errors, const std::string& name, double g) {
  if (errors.contains(name) && errors[name].is_number()) return errors[name].get<double>();
  if (name.starts_with("df_eff_")) {
    const std::string i = name.substr(7);
    const auto df = truth_of(errors, "df0_" + i, g), gi3 = truth_of(errors, "g" + i + "3", g);
    if (df && gi3) return *df + g * *gi3;
  }
  if (name.starts_with("df_obs_")) {
    const std::string i = name.substr(7);
    const auto eff = truth_of(errors, "df_eff_" + i, g);
    const auto th = truth_of(errors, "theta_" + i + "3", g);
    if (eff && th) return *eff - g * *th;
  }
  return std::nullopt;
}

}  // namespace

std::string combination_terms(const json& c, const json& report) {
  if (c.contains("formula") && c["formula"].is_string()) return c["formula"].get<std::string>();
  // the terms that matter: a term's part of the combination's prior
  // spread over 5% of the lead's, each with a coefficient from its own
  // display unit to the lead's
  const std::string lead = c.value("lead", std::string());
  const auto [lead_unit, k_lead] = display_unit(lead);
  const json est = report.value("estimates", json::object());
  auto prior_of = [&](const std::string& n) {
    return est.contains(n) && est[n].contains("prior_sigma") && est[n]["prior_sigma"].is_number()
               ? est[n]["prior_sigma"].get<double>()
               : std::numeric_limits<double>::quiet_NaN();
  };
  const double lead_prior = prior_of(lead);
  std::string terms = lead + " (" + std::string(lead_unit) + ")";
  for (const auto& [n, v] : c["coefficients"].items()) {
    if (n == lead || !v.is_number()) continue;
    const double weight = std::abs(v.get<double>() * prior_of(n) / lead_prior);
    if (!(weight > 0.05)) continue;
    const auto [u, k] = display_unit(n);
    const double coeff = k != 0 ? v.get<double>() * k_lead / k : v.get<double>();
    terms += (coeff < 0 ? " - " : " + ") + fmt("%.3g ", std::abs(coeff)) + n + " (" +
             std::string(u) + ")";
  }
  return terms;
}

std::string log_text(const json& log) {
  if (!log.is_object()) return "";
  std::string s = log.value("file", std::string());
  if (log.contains("torn_bytes_cut") && log["torn_bytes_cut"].is_number_integer() &&
      log["torn_bytes_cut"].get<std::int64_t>() > 0)
    s += " (cut off its end: " + log["torn_bytes_cut"].dump() + " bytes of a line cut short, \"" +
         log.value("torn_tail", std::string()) + "\")";
  return s;
}

std::string whiteness_text(const json& innovations) {
  const json& i = innovations;
  // two numbers, as check_report has made sure where the field is there
  auto pair = [&](const char* k) {
    return i.contains(k) && i[k].is_array() && i[k].size() == 2 && i[k][0].is_number() &&
           i[k][1].is_number();
  };
  std::string s = "Ljung-Box";
  if (pair("ljung_box"))
    s += fmt(" Q %.1f", i["ljung_box"][0].get<double>()) +
         fmt(", %.1f", i["ljung_box"][1].get<double>()) +
         fmt(" (%.0f lags)", i.value("ljung_box_lags", 0.0));
  const bool white = i.value("white", false);
  if (!pair("ljung_box_p")) return s + (white ? ": white" : ": NOT white");  // before p-values
  const double alarm = i.value("alarm_p", est::InnovationStats::kAlarmP);
  s += fmt(", p %.3g", i["ljung_box_p"][0].get<double>()) +
       fmt(", %.3g: ", i["ljung_box_p"][1].get<double>());
  return s + (white ? "white" : fmt("NOT white (p under %g)", alarm));
}

std::string report_text(const json& r, const json* truth) {
  const json errors = truth != nullptr ? truth->value("errors", json::object()) : json();
  const json site = r.value("site", json::object());
  const double g =
      earth::normal_gravity(site.value("latitude_rad", 0.0), site.value("height_m", 0.0));
  std::string out;
  auto line = [&](const std::string& s) { out += s + "\n"; };
  line("turncal report " + r.value("run_id", std::string("?")) + ": " +
       r.value("status", std::string("?")));
  if (r.contains("reason")) line("  reason: " + r["reason"].get<std::string>());
  if (r.contains("stop_signal")) line("  stop: " + r["stop_signal"].get<std::string>());
  if (r.contains("unit") && r["unit"].is_string()) line("  unit: " + r["unit"].get<std::string>());
  if (r.contains("profile"))
    line("  profile: " + r["profile"].value("name", std::string()) + " (" +
         fmt("%.0f s", r["profile"].value("duration_s", 0.0)) + ")");
  if (r.contains("log")) line("  log: " + log_text(r["log"]));
  if (r.contains("replay") && r["replay"].is_object()) {
    const json& p = r["replay"];
    std::string s = "  replay";
    s += p.value("of_live_report", false) ? " with the live run's settings" : " of a log alone";
    for (const auto& o : p.value("overrides", json::array())) s += ", " + o.get<std::string>();
    line(s);
    if (p.contains("damage") && p["damage"].is_object())
      line("  log damaged at line " + std::to_string(p["damage"].value("line", 0)) + ": " +
           p["damage"].value("what", std::string()));
    for (const auto& m : p.value("missing_roles", json::array()))
      line("  no frames of " + m.get<std::string>());
  }
  if (r.contains("turns_achieved"))
    for (const auto& t : r["turns_achieved"])
      line("  turn: " + fmt("%.4f deg", t["angle_rad"].get<double>() * 180 / std::numbers::pi) +
           " at peak " +
           fmt("%.3f deg/s", t["peak_rate_rps"].get<double>() * 180 / std::numbers::pi) +
           fmt(", %.2f s", t["start_s"].get<double>()) +
           fmt(" to %.2f s after t0", t["end_s"].get<double>()));
  if (r.contains("estimates")) {
    line("");
    line(std::string("  parameter        estimate        sigma        prior  unit") +
         (truth != nullptr ? "         truth   error/sigma" : ""));
    std::vector<std::string> undetermined;
    for (const auto& [name, e] : r["estimates"].items()) {
      const auto [unit, k] = display_unit(name);
      char buf[400];
      if (e.value("determined", std::string()) == "not determined") {
        std::snprintf(buf, sizeof buf, "  %-10s %14s %12s %12.4g  %-7s %s", name.c_str(),
                      "not determined", "", e["prior_sigma"].get<double>() * k,
                      std::string(unit).c_str(), e.value("why", std::string()).c_str());
        undetermined.push_back(buf);
        continue;
      }
      int n = std::snprintf(buf, sizeof buf, "  %-10s %14.6g %12.4g %12.4g  %-7s", name.c_str(),
                            e["value"].get<double>() * k, e["sigma"].get<double>() * k,
                            e["prior_sigma"].get<double>() * k, std::string(unit).c_str());
      if (e.value("determined", std::string()) == "partly")
        n += std::snprintf(buf + n, sizeof buf - static_cast<std::size_t>(n), " partly");
      if (truth != nullptr)
        if (const auto t = truth_of(errors, name, g))
          std::snprintf(buf + n, sizeof buf - static_cast<std::size_t>(n), " %13.6g %+9.2f", *t * k,
                        (e["value"].get<double>() - *t) / e["sigma"].get<double>());
      line(buf);
    }
    if (!undetermined.empty()) {
      line("  not determined by this run (their values are the prior's; kept in the JSON):");
      for (const std::string& u : undetermined) line(u);
    }
  }
  if (r.contains("combinations") && !r["combinations"].empty()) {
    line("");
    line("  combinations the run determined:");
    for (const auto& c : r["combinations"]) {
      const std::string lead = c["lead"].get<std::string>();
      const auto [unit, k] = display_unit(lead);
      const std::string terms = combination_terms(c, r);
      std::string against;
      if (truth != nullptr) {
        double tv = 0;
        bool all = true;
        for (const auto& [n, v] : c["coefficients"].items()) {
          const auto t = truth_of(errors, n, g);
          all = all && t.has_value();
          if (t) tv += v.get<double>() * *t;
        }
        if (all)
          against = fmt("  (truth %.6g, ", tv * k) +
                    fmt("%+.2f sigma)", (c["value"].get<double>() - tv) / c["sigma"].get<double>());
      }
      line("    " + terms + " = " + fmt("%.6g", c["value"].get<double>() * k) + " +- " +
           fmt("%.3g ", c["sigma"].get<double>() * k) + std::string(unit) + against +
           (c.contains("name") ? " (" + c["name"].get<std::string>() + ")" : "") +
           (c.value("degenerate", false) ? " (one of equally sharp directions)" : ""));
    }
  }
  if (r.value("status", std::string()) == "done" && r.contains("estimates")) {
    line("");
    line("  " + std::string(kHowToApply));
  }
  if (r.contains("innovations")) {
    const auto& i = r["innovations"];
    line("");
    line("  innovations: NIS mean " + fmt("%.3f", i["nis_mean"].get<double>()) +
         " (95%: " + fmt("%.3f", i["nis_95_interval"][0].get<double>()) + " to " +
         fmt("%.3f", i["nis_95_interval"][1].get<double>()) + "); " + whiteness_text(i));
  }
  if (r.contains("second_pass") && r["second_pass"].is_object()) {
    const auto& s = r["second_pass"];
    const bool ran = s.value("ran", false);
    line("  second pass: " +
         (ran ? std::string("ran, ") + std::to_string(s.value("iterations", 0)) + " iterations, " +
                    (s.value("converged", false) ? "converged" : "NOT converged")
              : std::string("not run")) +
         " (" + s.value("reason", std::string()) + ")");
  }
  if (r.contains("verdict")) {
    const auto& v = r["verdict"];
    const json checks = v.value("checks", json::array());  // optional (check_report)
    for (const auto& c : checks) {
      if (!c.value("tested", true)) {
        line("  not tested " + c["parameter"].get<std::string>() + ": " +
             c.value("why", std::string()));
        continue;
      }
      line("  " + std::string(c["pass"].get<bool>() ? "pass " : "FAIL ") +
           c["parameter"].get<std::string>() +
           (c.contains("value")
                ? fmt(" = %.4g", c["value"].get<double>()) +
                      fmt(" +- %.3g ", c["sigma"].get<double>()) + c["unit"].get<std::string>()
                : std::string(": not estimated")));
    }
    const int untested = v.contains("not_tested") ? v["not_tested"].get<int>() : 0;
    line(std::string("  verdict: ") + (v["pass"].get<bool>() ? "PASS" : "FAIL") +
         (untested > 0 ? " (" + std::to_string(untested) + " tolerance" +
                             (untested > 1 ? "s" : "") + " not tested: not determined)"
                       : std::string()));
  }
  return out;
}

namespace {

/// One field's expected JSON type, for check_report.
enum class Kind : std::uint8_t { String, Number, Integer, Boolean, Object, Array };

const char* kind_name(Kind k) {
  switch (k) {
    case Kind::String:
      return "a string";
    case Kind::Number:
      return "a number";
    case Kind::Integer:
      return "an integer";
    case Kind::Boolean:
      return "true or false";
    case Kind::Object:
      return "an object";
    case Kind::Array:
      return "an array";
  }
  return "?";
}

bool is(const json& j, Kind k) {
  switch (k) {
    case Kind::String:
      return j.is_string();
    case Kind::Number:
      return j.is_number();
    case Kind::Integer:
      return j.is_number_integer();
    case Kind::Boolean:
      return j.is_boolean();
    case Kind::Object:
      return j.is_object();
    case Kind::Array:
      return j.is_array();
  }
  return false;
}

/// "path[i]" for an array's element, "path.name" for an object's value.
std::string element_path(const json& j, const std::string& path, const std::string& name) {
  return j.is_array() ? path + "[" + name + "]" : path + "." + name;
}

/// The first field of a report with the wrong type, as "path: expected
/// KIND"; the reader functions below record it and go on quietly.
class Checker {
 public:
  /// `key` of object `j` (at `path`), if present (or required), of kind `k`.
  bool field(const json& j, const std::string& path, const char* key, Kind k, bool required = false,
             bool nullable = false) {
    if (!j.contains(key)) {
      if (required) fail(path + key, "missing");
      return false;
    }
    const json& v = j[key];
    if (v.is_null() && nullable) return false;  // null only where a reader takes it
    if (!is(v, k)) {
      fail(path + key, std::string("expected ") + kind_name(k));
      return false;
    }
    return true;
  }
  /// Every element of an array, or every value of an object, of kind `k`.
  bool each(const json& j, const std::string& path, Kind k) {
    for (const auto& [name, v] : j.items())
      if (!is(v, k)) {
        fail(element_path(j, path, name), std::string("expected ") + kind_name(k));
        return false;
      }
    return true;
  }
  /// Each element of an array (path[i]) or value of an object (path.name)
  /// must be an object; `check` is called on each, with its path, until
  /// the first that is not.
  template <class F>
  void objects(const json& j, const std::string& path, F&& check) {
    for (const auto& [name, v] : j.items()) {
      const std::string at = element_path(j, path, name);
      if (!is(v, Kind::Object)) {
        fail(at, "expected an object");
        return;
      }
      check(v, at + ".");
    }
  }
  /// `key` of object `j`, if present (and not null, where `nullable`), a
  /// number within [lo, hi] (above lo, where `above` is set): a bound no
  /// run could have had is a report edited or damaged, and read so it
  /// would fail or pass every frame.
  void number_in(const json& j, const std::string& path, const char* key, double lo, double hi,
                 bool above = false, bool nullable = false) {
    if (!field(j, path, key, Kind::Number, false, nullable)) return;
    const double v = j[key].get<double>();
    if (v >= lo && v <= hi && (!above || v > lo)) return;
    char b[160];
    if (hi < std::numeric_limits<double>::max())
      std::snprintf(b, sizeof b, "expected a number in [%g, %g], not %g", lo, hi, v);
    else
      std::snprintf(b, sizeof b, "expected a number %s %g, not %g", above ? "above" : "of at least",
                    lo, v);
    fail(path + key, b);
  }
  void fail(const std::string& path, const std::string& what) {
    if (error.empty()) error = path + ": " + what;
  }
  std::string error;
};

}  // namespace

std::string check_report(const json& r) {
  // the largest finite double: a number JSON gives as 1e999 is infinite
  constexpr double kMaxNumber = std::numeric_limits<double>::max();
  if (!r.is_object()) return "not a JSON object";
  Checker c;
  if (c.field(r, "", "schema_version", Kind::Integer) &&
      r["schema_version"].get<std::int64_t>() > kReportSchemaVersion)
    return "schema_version " + r["schema_version"].dump() + " is newer than this turncal reads (" +
           std::to_string(kReportSchemaVersion) + ")";
  for (const char* k :
       {"format", "run_id", "status", "reason", "stop_signal", "mode", "software_version"})
    c.field(r, "", k, Kind::String);
  c.field(r, "", "unit", Kind::String, false, true);  // null: not named
  for (const char* k : {"start_time_unix_s", "end_time_unix_s"}) c.field(r, "", k, Kind::Number);
  if (c.field(r, "", "site", Kind::Object))
    for (const char* k : {"latitude_rad", "height_m"}) c.field(r["site"], "site.", k, Kind::Number);
  if (c.field(r, "", "profile", Kind::Object)) {
    const json& p = r["profile"];
    for (const char* k : {"name", "file", "toml"}) c.field(p, "profile.", k, Kind::String);
    for (const char* k : {"align_s", "duration_s"}) c.field(p, "profile.", k, Kind::Number);
  }
  if (c.field(r, "", "log", Kind::Object)) {
    for (const char* k : {"file", "sha256"}) c.field(r["log"], "log.", k, Kind::String);
    c.field(r["log"], "log.", "lines", Kind::Integer);
    // an interrupted run's: the part of a line its kill left, cut off
    c.field(r["log"], "log.", "torn_bytes_cut", Kind::Integer);
    c.field(r["log"], "log.", "torn_tail", Kind::String);
  }
  if (c.field(r, "", "time_base", Kind::Object)) {
    // microseconds since 1970 whose nanoseconds fit 64 bits (as a log's
    // time stamps do: its seconds end at 9223372035); the config's range
    // of time_scale
    c.number_in(r["time_base"], "time_base.", "epoch_us", 0, 9.223372036e15);
    c.number_in(r["time_base"], "time_base.", "scale", kMinTimeScale, kMaxTimeScale);
  }
  if (c.field(r, "", "plausibility", Kind::Object)) {
    const json& p = r["plausibility"];
    // null: no bound (infinite), as a replay of a log from before bounds writes
    for (const char* k : {"max_velocity_mps", "max_table_rate_rps"})
      c.number_in(p, "plausibility.", k, 0, kMaxNumber, true, true);
    c.number_in(p, "plausibility.", "step_slack_s", 0, kMaxNumber);
    c.number_in(p, "plausibility.", "max_fraction", 0, 1);
    c.field(p, "plausibility.", "dbc_ranges", Kind::Boolean);
  }
  if (c.field(r, "", "settings", Kind::Object)) {
    const json& s = r["settings"];
    for (const char* k : {"two_stage", "observe"}) c.field(s, "settings.", k, Kind::Boolean);
    c.field(s, "settings.", "heading_offset_rad", Kind::Number);
    c.number_in(s, "settings.", "stale_floor_s", 0, kMaxNumber);
    c.number_in(s, "settings.", "real_time_floor_s", 0, kMaxNumber);
    c.field(s, "settings.", "table_geometry", Kind::String);  // older reports lack it
  }
  if (c.field(r, "", "replay", Kind::Object)) {
    const json& p = r["replay"];
    c.field(p, "replay.", "of_live_report", Kind::Boolean);
    if (c.field(p, "replay.", "overrides", Kind::Array))
      c.each(p["overrides"], "replay.overrides", Kind::String);
    if (c.field(p, "replay.", "missing_roles", Kind::Array))
      c.each(p["missing_roles"], "replay.missing_roles", Kind::String);
    if (c.field(p, "replay.", "damage", Kind::Object, false, true)) {  // null: whole
      c.field(p["damage"], "replay.damage.", "line", Kind::Integer);
      c.field(p["damage"], "replay.damage.", "what", Kind::String);
    }
  }
  if (c.field(r, "", "turns_achieved", Kind::Array))
    c.objects(r["turns_achieved"], "turns_achieved", [&](const json& t, const std::string& at) {
      for (const char* k : {"angle_rad", "peak_rate_rps", "start_s", "end_s"})
        c.field(t, at, k, Kind::Number, true);
    });
  if (c.field(r, "", "estimates", Kind::Object))
    c.objects(r["estimates"], "estimates", [&](const json& e, const std::string& at) {
      for (const char* k : {"value", "sigma", "prior_sigma"}) c.field(e, at, k, Kind::Number, true);
      for (const char* k : {"determined", "why"}) c.field(e, at, k, Kind::String);
      c.field(e, at, "unit", Kind::String);
    });
  if (c.field(r, "", "covariance", Kind::Object)) {
    const json& v = r["covariance"];
    if (c.field(v, "covariance.", "order", Kind::Array, true) &&
        c.each(v["order"], "covariance.order", Kind::String) &&
        c.field(v, "covariance.", "matrix", Kind::Array, true)) {
      const std::size_t n = v["order"].size();
      bool square = v["matrix"].size() == n;
      for (const json& row : v["matrix"])
        square = square && row.is_array() && row.size() == n &&
                 c.each(row, "covariance.matrix", Kind::Number);
      if (!square) c.fail("covariance.matrix", "expected a row of numbers per parameter of order");
    }
  }
  if (c.field(r, "", "combinations", Kind::Array))
    c.objects(r["combinations"], "combinations", [&](const json& m, const std::string& at) {
      c.field(m, at, "lead", Kind::String, true);
      if (c.field(m, at, "coefficients", Kind::Object, true))
        c.each(m["coefficients"], at + "coefficients", Kind::Number);
      for (const char* k : {"value", "sigma"}) c.field(m, at, k, Kind::Number, true);
      for (const char* k : {"name", "formula"}) c.field(m, at, k, Kind::String);
      c.field(m, at, "degenerate", Kind::Boolean);
    });
  if (c.field(r, "", "innovations", Kind::Object)) {
    const json& i = r["innovations"];
    c.field(i, "innovations.", "nis_mean", Kind::Number, true);
    c.field(i, "innovations.", "white", Kind::Boolean, true);
    c.field(i, "innovations.", "ljung_box_lags", Kind::Integer);
    c.field(i, "innovations.", "alarm_p", Kind::Number);
    for (const char* k : {"ljung_box", "ljung_box_p"})
      if (c.field(i, "innovations.", k, Kind::Array) &&
          c.each(i[k], std::string("innovations.") + k, Kind::Number) && i[k].size() != 2)
        c.fail(std::string("innovations.") + k, "expected two numbers");
    if (c.field(i, "innovations.", "nis_95_interval", Kind::Array, true) &&
        c.each(i["nis_95_interval"], "innovations.nis_95_interval", Kind::Number) &&
        i["nis_95_interval"].size() != 2)
      c.fail("innovations.nis_95_interval", "expected two numbers");
  }
  if (c.field(r, "", "second_pass", Kind::Object)) {
    const json& s = r["second_pass"];
    for (const char* k : {"ran", "converged"}) c.field(s, "second_pass.", k, Kind::Boolean, true);
    c.field(s, "second_pass.", "reason", Kind::String);
    c.field(s, "second_pass.", "iterations", Kind::Integer);
    for (const char* k : {"predicted_error_sigma", "last_change_sigma"})
      c.field(s, "second_pass.", k, Kind::Number);
  }
  if (c.field(r, "", "verdict", Kind::Object)) {
    const json& v = r["verdict"];
    c.field(v, "verdict.", "pass", Kind::Boolean, true);
    c.field(v, "verdict.", "not_tested", Kind::Integer);
    if (c.field(v, "verdict.", "checks", Kind::Array))
      c.objects(v["checks"], "verdict.checks", [&](const json& k, const std::string& at) {
        c.field(k, at, "pass", Kind::Boolean, true);
        c.field(k, at, "parameter", Kind::String, true);
        c.field(k, at, "tested", Kind::Boolean);
        c.field(k, at, "why", Kind::String);
        if (c.field(k, at, "value", Kind::Number)) {
          c.field(k, at, "sigma", Kind::Number, true);
          c.field(k, at, "unit", Kind::String, true);
        }
      });
  }
  return c.error;
}

}  // namespace turncal::run
