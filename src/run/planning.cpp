#include "turncal/run/planning.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "text_format.hpp"
#include "turncal/config.hpp"
#include "turncal/physics/profile.hpp"
#include "turncal/run/record.hpp"
#include "turncal/run/report.hpp"

namespace turncal::run {

using detail::fmt;
using nlohmann::json;

namespace {

constexpr double kDeg = 0.017453292519943295;

/// The biases whose sigmas the sweep shows.
/// (df_obs: what a turn about the vertical determines of the accelerometer)
constexpr std::array<const char*, 5> kBiases = {"nu0_1", "nu0_2", "nu0_3", "df_obs_1", "df_obs_2"};

/// What the reversal and revolution sweep shows: the biases, Theta_33
/// (whole revolutions) and the proof-mass offset (every turn).
constexpr std::array<const char*, 8> kTurnSweep = {"nu0_1", "nu0_2", "nu0_3",    "theta_33",
                                                   "r1",    "r2",    "df_obs_1", "df_obs_2"};

double total_angle(const Plan& p) {
  double a = 0;
  for (const TurnSpec& t : p.profile.turns) a += std::abs(t.angle_rad);
  return a;
}

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral"
/// snprintf to a string; `f` is always a literal format.
template <class... A>
std::string pf(const char* f, A... a) {
  char buf[160];
  std::snprintf(buf, sizeof buf, f, a...);
  return buf;
}
#pragma GCC diagnostic pop

json sigmas_of(const est::EstimationResult& r) {
  json out = json::object();
  for (const auto& p : r.parameters) out[std::string(p.name)] = p.sigma;
  for (const auto& p : r.df_eff) out[std::string(p.name)] = p.sigma;
  for (const auto& p : r.df_obs) out[std::string(p.name)] = p.sigma;
  return out;
}

}  // namespace

est::EstimationInput planned_input(const Plan& plan, const PlanningSettings& s) {
  const TableTrajectory traj(plan.profile);
  const double psi0 = plan.start_angle_rad - s.heading_offset_rad;
  est::EstimationInput in = input_of_plan(plan, s.sample_rate_hz);
  est::TimelineInput& t = in.timeline;
  t.duration_s = plan.profile.duration_s;
  t.psi_start_rad = psi0;
  for (std::size_t i = 0; i < traj.turns(); ++i)
    t.turns.push_back(
        {traj.turn_start(i), traj.turn_end(i), plan.profile.turns[i].angle_rad, traj.peak_rate(i)});
  // the encoder as a run's record keeps it: both ends of every still run and
  // every sample that moved
  const auto n = static_cast<long>(std::floor(plan.profile.duration_s * s.encoder_hz));
  auto angle = [&](long k) { return traj.at(static_cast<double>(k) / s.encoder_hz).angle; };
  double prev = angle(0), cur = prev;
  for (long k = 0; k <= n; ++k) {
    const double next = k < n ? angle(k + 1) : cur;
    if (k == 0 || k == n || cur != prev || cur != next)
      t.encoder.push_back({static_cast<double>(k) / s.encoder_hz, psi0 + cur});
    prev = cur;
    cur = next;
  }
  return in;
}

Plan scaled_plan(const Plan& plan, double hold_factor, double turn_angle_rad) {
  Plan p = plan;
  for (TurnSpec& t : p.profile.turns)
    if (!std::isnan(turn_angle_rad)) t.angle_rad = std::copysign(turn_angle_rad, t.angle_rad);
  // the holds (before, between and after the turns) scaled; each turn as
  // long as its motion takes
  const TableTrajectory old(plan.profile), turned(p.profile);
  double t = 0, last_end = 0;
  for (std::size_t i = 0; i < p.profile.turns.size(); ++i) {
    t += (old.turn_start(i) - last_end) * hold_factor;
    p.profile.turns[i].start_s = t;
    t += turned.turn_end(i) - turned.turn_start(i);
    last_end = old.turn_end(i);
  }
  p.profile.duration_s = t + (plan.profile.duration_s - last_end) * hold_factor;
  return p;
}

Result<json> plan_json(const Plan& plan, const PlanningSettings& s) {
  TURNCAL_ASSIGN(r, est::analyse(planned_input(plan, s)));
  json j;
  j["format"] = "turncal-plan-1";
  j["profile"] = {{"name", plan.name},
                  {"file", plan.source},
                  {"overrides", plan.overrides},
                  {"duration_s", plan.profile.duration_s},
                  {"align_s", plan.profile.align_s},
                  {"turns", plan.profile.turns.size()}};
  j["settings"] = {{"heading_offset_rad", s.heading_offset_rad},
                   {"sample_rate_hz", s.sample_rate_hz},
                   {"epoch_s", plan.epoch_s},
                   {"measurement", plan.mean_measurement ? "mean" : "sample"},
                   {"estimable_ratio", s.estimable_ratio}};
  json pred = json::object();
  json estimable = json::array();
  auto add = [&](const est::ParameterEstimate& p) {
    const double ratio = p.prior_sigma > 0 ? p.sigma / p.prior_sigma : 1;
    const bool est = ratio < s.estimable_ratio;
    pred[std::string(p.name)] = {{"sigma", p.sigma},
                                 {"prior_sigma", p.prior_sigma},
                                 {"ratio", ratio},
                                 {"estimable", est},
                                 {"unit", std::string(p.unit)}};
    if (est) estimable.push_back(std::string(p.name));
  };
  for (const auto& p : r.parameters) add(p);
  for (const auto& p : r.df_eff) add(p);
  for (const auto& p : r.df_obs) add(p);
  j["predicted"] = pred;
  j["estimable"] = estimable;
  json combos = json::array();
  for (const est::Combination& c : r.combinations) combos.push_back(combination_json(c, false));
  j["combinations"] = combos;
  if (s.sweep && !plan.profile.turns.empty()) {
    json rows = json::array();
    PlanningSettings one = s;
    one.sweep = false;
    for (const double f : {0.25, 0.5, 1.0, 2.0})
      for (const double a : {90.0, 180.0, 270.0}) {
        const Plan q = scaled_plan(plan, f, a * kDeg);
        TURNCAL_ASSIGN(qr, est::analyse(planned_input(q, one)));
        const json sig = sigmas_of(qr);
        json b = json::object();
        for (const char* k : kBiases) b[k] = sig[k];
        rows.push_back({{"hold_factor", f},
                        {"turn_angle_rad", a * kDeg},
                        {"duration_s", q.profile.duration_s},
                        {"sigma", b}});
      }
    j["sweep"] = rows;
    // the same hour spent on reversals (turns of 180 deg, back and forth,
    // evenly spread) and on whole revolutions (the first turn's timing)
    json more = json::array();
    auto row = [&](const char* kind, int n, const Plan& q) -> Status {
      TURNCAL_ASSIGN(qr, est::analyse(planned_input(q, one)));
      const json sig = sigmas_of(qr);
      json b = json::object();
      for (const char* k : kTurnSweep) b[k] = sig[k];
      more.push_back({{"kind", kind},
                      {"turns", n},
                      {"total_angle_rad", total_angle(q)},
                      {"duration_s", q.profile.duration_s},
                      {"sigma", b}});
      return Status{Ok{}};
    };
    for (const int n : {1, 2, 4, 8}) TURNCAL_TRY(row("reversals", n, reversals_plan(plan, n)));
    for (const double a : {360.0, 1800.0, 3600.0}) {
      // one turn, the first's timing, by whole revolutions
      Plan q = plan;
      q.profile.turns.resize(1);
      q.profile.turns[0].angle_rad = a * kDeg;
      TURNCAL_TRY(row("revolutions", 1, q));
    }
    j["sweep_turns"] = more;
  }
  return j;
}

Plan reversals_plan(const Plan& plan, int n) {
  Plan p = plan;
  const TurnSpec first = plan.profile.turns.empty() ? TurnSpec{} : plan.profile.turns.front();
  p.profile.turns.clear();
  for (int k = 0; k < n; ++k) {
    TurnSpec t = first;
    t.angle_rad = (k % 2 == 0 ? 1 : -1) * 180 * kDeg;
    t.start_s = plan.profile.duration_s * (k + 1) / (n + 1);
    p.profile.turns.push_back(t);
  }
  return p;
}

std::string plan_text(const json& j) {
  std::string out;
  auto line = [&](const std::string& s) { out += s + "\n"; };
  const json& p = j["profile"];
  line("turncal plan " + p.value("name", std::string("?")) + ": " +
       fmt("%.0f s", p.value("duration_s", 0.0)) + " from t0, " +
       std::to_string(p.value("turns", 0)) + " turn(s)");
  line("");
  line("  parameter   predicted sigma        prior  unit   posterior/prior");
  for (const auto& [name, e] : j["predicted"].items()) {
    const auto [unit, k] = display_unit(name);
    char buf[160];
    std::snprintf(buf, sizeof buf, "  %-10s %16.4g %12.4g  %-6s %8.3f%s", name.c_str(),
                  e["sigma"].get<double>() * k, e["prior_sigma"].get<double>() * k,
                  std::string(unit).c_str(), e["ratio"].get<double>(),
                  e["estimable"].get<bool>() ? "  estimable" : "");
    line(buf);
  }
  line("");
  line("  estimable (posterior below " + fmt("%.2g", j["settings"].value("estimable_ratio", 0.5)) +
       " of the prior): " + std::to_string(j["estimable"].size()) + " of " +
       std::to_string(j["predicted"].size()));
  if (j.contains("combinations") && !j["combinations"].empty())
    line("  sharp combinations: " + std::to_string(j["combinations"].size()));
  if (j.contains("sweep")) {
    line("");
    line("  bias sigmas against hold length and turn angle:");
    line(
        "  holds x  turn deg  run s    nu0_1 deg/h  nu0_2 deg/h  nu0_3 deg/h  df_obs_1 ug  "
        "df_obs_2 ug");
    for (const auto& r : j["sweep"]) {
      const json& s = r["sigma"];
      char buf[200];
      std::snprintf(
          buf, sizeof buf, "  %7.2f  %8.0f  %5.0f  %11.4f  %11.4f  %11.4f  %11.2f  %11.2f",
          r["hold_factor"].get<double>(), r["turn_angle_rad"].get<double>() / kDeg,
          r["duration_s"].get<double>(), s["nu0_1"].get<double>() * display_unit("nu0_1").second,
          s["nu0_2"].get<double>() * display_unit("nu0_2").second,
          s["nu0_3"].get<double>() * display_unit("nu0_3").second,
          s["df_obs_1"].get<double>() * display_unit("df_obs_1").second,
          s["df_obs_2"].get<double>() * display_unit("df_obs_2").second);
      line(buf);
    }
  }
  if (j.contains("sweep_turns")) {
    line("");
    line("  the same run spent on reversals (180 deg, back and forth) or whole revolutions:");
    std::string head = "  turns            total deg";
    for (const char* k : kTurnSweep)
      head += pf(" %12s", (std::string(k) + " " + std::string(display_unit(k).first)).c_str());
    line(head);
    for (const auto& r : j["sweep_turns"]) {
      const bool rev = r["kind"] == "reversals";
      std::string row =
          rev ? pf("  %d reversal%s", r["turns"].get<int>(), r["turns"].get<int>() > 1 ? "s" : "")
              : pf("  %.0f revolution%s",
                   r["total_angle_rad"].get<double>() / (2 * std::numbers::pi),
                   r["total_angle_rad"].get<double>() > 2.1 * std::numbers::pi ? "s" : "");
      row.resize(19, ' ');
      row += pf("%9.0f", r["total_angle_rad"].get<double>() / kDeg);
      for (const char* k : kTurnSweep)
        row += pf(" %12.4g", r["sigma"][k].get<double>() * display_unit(k).second);
      line(row);
    }
  }
  return out;
}

json compare_json(const std::vector<json>& plans) {
  return {{"format", "turncal-plan-compare-1"}, {"plans", plans}};
}

std::string compare_text(const json& c) {
  std::string out;
  auto line = [&](const std::string& s) { out += s + "\n"; };
  const json& plans = c["plans"];
  line("turncal plan --compare: predicted sigmas, side by side. Marks: '~' partly determined");
  line("(sigma 0.5 to 0.9 of its prior), '-' not determined (0.9 or more); none: determined.");
  line("");
  std::string head = "  parameter  unit  ";
  std::string dur = "  run s            ";
  std::string turns = "  turns            ";
  int width = 12;
  for (const auto& p : plans)
    width = std::max(width, static_cast<int>(p["profile"].value("name", std::string("?")).size()));
  for (const auto& p : plans) {
    head += pf(" %*s ", width, p["profile"].value("name", std::string("?")).c_str());
    dur += pf(" %*.0f ", width, p["profile"].value("duration_s", 0.0));
    turns += pf(" %*d ", width, p["profile"].value("turns", 0));
  }
  line(head);
  line(dur);
  line(turns);
  if (plans.empty()) return out;
  for (const auto& [name, first] : plans[0]["predicted"].items()) {
    (void)first;
    const auto [unit, k] = display_unit(name);
    std::string row = pf("  %-10s %-6s", name.c_str(), std::string(unit).c_str());
    for (const auto& p : plans) {
      const json& pred = p["predicted"];
      if (!pred.contains(name)) {
        row += pf(" %*s ", width, "?");
        continue;
      }
      const json& e = pred[name];
      const double ratio = e["ratio"].get<double>();
      row += pf(" %*.4g%s", width, e["sigma"].get<double>() * k,
                ratio >= 0.9   ? "-"
                : ratio >= 0.5 ? "~"
                               : " ");
    }
    line(row);
  }
  return out;
}

namespace {

/// The plan's determined parameters whose sigma `with` gives more than 5%
/// over `base`'s, as {name: {sigma, with}}.
json costs_of(const json& base, const json& with) {
  json out = json::object();
  for (const auto& [name, e] : base["predicted"].items()) {
    if (!e.value("estimable", false) || !with["predicted"].contains(name)) continue;
    const double a = e["sigma"].get<double>(), b = with["predicted"][name]["sigma"].get<double>();
    if (b > 1.05 * a) out[name] = {{"sigma", a}, {"with", b}};
  }
  return out;
}

std::string cost_text(const json& costs) {
  std::string t;
  for (const auto& [name, c] : costs.items()) {
    const auto [unit, k] = display_unit(name);
    t += (t.empty() ? "" : ", ") + name + " " + fmt("%.3g", c["sigma"].get<double>() * k) + " -> " +
         fmt("%.3g", c["with"].get<double>() * k) + " " + std::string(unit);
  }
  return t;
}

}  // namespace

Result<json> ins_output_costs(const Plan& plan, const PlanningSettings& s, const InsOutput& ins,
                              const json& analysed) {
  json out = json::array();
  PlanningSettings quiet = s;
  quiet.sweep = false;
  // rounding: uniform over a step, step / sqrt(12) RMS, added to the noise
  const double rounding = ins.resolution_mps / std::sqrt(12.0);
  if (rounding > 0.25 * plan.sigma_z) {
    Plan coarse = plan;
    coarse.sigma_z = std::hypot(plan.sigma_z, rounding);
    TURNCAL_ASSIGN(with, plan_json(coarse, quiet));
    json costs = costs_of(analysed, with);
    if (!costs.empty())
      out.push_back(
          {{"what", "resolution"},
           {"text",
            "the INS velocity's step of " + fmt("%.3g", ins.resolution_mps * 1e3) + " mm/s (" +
                ins.signal + ") adds " + fmt("%.2g", rounding * 1e3) +
                " mm/s RMS to the plan's output noise of " + fmt("%.2g", plan.sigma_z * 1e3) +
                " mm/s (sigma_z), which the plan's sigmas assume: with it, " + cost_text(costs)},
           {"costs", costs}});
  }
  if (ins.rate_hz > 0 && ins.rate_hz < s.sample_rate_hz) {
    PlanningSettings slow = quiet;
    slow.sample_rate_hz = ins.rate_hz;
    TURNCAL_ASSIGN(with, plan_json(plan, slow));
    json costs = costs_of(analysed, with);
    if (!costs.empty() || ins.rate_hz * plan.epoch_s < 1)
      out.push_back({{"what", "rate"},
                     {"text", "the INS velocity at " + fmt("%.3g", ins.rate_hz) + " Hz, not the " +
                                  fmt("%.3g", s.sample_rate_hz) + " Hz the plan's sigmas assume" +
                                  (ins.rate_hz * plan.epoch_s < 1
                                       ? std::string(", leaves epochs of ") +
                                             fmt("%.3g", plan.epoch_s) + " s without a sample"
                                       : std::string()) +
                                  (costs.empty() ? std::string() : ": " + cost_text(costs))},
                     {"costs", costs}});
  }
  return out;
}

}  // namespace turncal::run
