#include "turncal/run/calibration.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string_view>

#include "turncal/earth.hpp"
#include "turncal/estimation/params.hpp"
#include "turncal/run/report.hpp"

namespace turncal::run {

using nlohmann::json;

const char* const kCalibrationConvention =
    "Corrections to the INS's existing calibration, in its instrument axes z (z3 the axis the "
    "table turned it about). The error model (turncal model.md, section 2): the gyros measure "
    "w_m = (I + Theta) w + nu0, accelerometer i (1, 2) measures f_m_i = f_i + df0_i + G_i3 f_3, "
    "and accelerometer 2's proof mass sits at r = (r1, r2, 0) from accelerometer 1's. Apply: "
    "w = (I + Theta)^-1 (w_m - nu0); f_i = f_m_i - df0_i - G_i3 f_3; then f_2 -= "
    "[dw/dt x r + w x (w x r)]_2. Theta is the matrix of the theta_ij given here, G_i3 the g13 "
    "and g23. A term absent from this file was not determined by the run: it is no correction "
    "(keep what the INS has), not a zero. Values in SI (rad/s, 1, m/s^2, m); display_value in "
    "deg/h, ppm, ug, mm.";

const char* const kHowToApply =
    "To apply this run to the INS, `turncalctl export RUN_ID` writes the determined terms as "
    "corrections in instrument axes: w = (I + Theta)^-1 (w_m - nu0) for the gyros, f_i = f_m_i - "
    "df0_i - G_i3 f_3 for the accelerometers. Terms the run did not determine are left out "
    "(keep the INS's own), and a combination it could not split is given as that combination, "
    "for this mounting only.";

namespace {

/// The block of one of the 18 parameters; nullptr for a combination.
const est::BlockInfo* group_of(const std::string& name) {
  const int i = est::param_index(name);
  return i < 0 ? nullptr : &est::block_info(est::kParamTable[static_cast<std::size_t>(i)].block);
}

json term(const json& e, double display, std::string_view display_unit) {
  const double v = e["value"].get<double>();
  const double s = e["sigma"].get<double>();
  return {{"value", v},
          {"sigma", s},
          {"unit", e.value("unit", std::string())},
          {"display_value", v * display},
          {"display_sigma", s * display},
          {"display_unit", std::string(display_unit)}};
}

std::string reason(const json& e) {
  const std::string label = e.value("determined", std::string());
  const double s = e["sigma"].get<double>();
  const double p = e["prior_sigma"].get<double>();
  char ratio[64];
  std::snprintf(ratio, sizeof ratio, "posterior over prior sigma %.2f",
                p > 0 ? s / p : std::numeric_limits<double>::quiet_NaN());
  std::string why = e.value("why", std::string());
  if (label == "partly")
    return std::string("partly determined (") + ratio +
           "): not a correction; the report has its estimate" + (why.empty() ? "" : "; " + why);
  return std::string("not determined (") + ratio + ")" + (why.empty() ? "" : ": " + why);
}

}  // namespace

Result<json> calibration_json(const json& report) {
  if (const std::string bad = check_report(report); !bad.empty())
    return make_error("not a readable report: " + bad);
  const std::string run_id = report.value("run_id", std::string());
  if (report.value("status", std::string()) != "done")
    return make_error("run " + run_id + " is " + report.value("status", std::string("?")) +
                      ", not done: it has no calibration");
  if (!report.contains("estimates") || report["estimates"].empty())
    return make_error("run " + run_id + " has no estimates");
  const json& est = report["estimates"];
  json cal;
  cal["format"] = "turncal-calibration-1";
  cal["run_id"] = run_id;
  cal["unit"] = report.contains("unit") ? report["unit"] : json(nullptr);
  cal["software_version"] = report.value("software_version", std::string());
  cal["convention"] = kCalibrationConvention;
  json gyro = json::object();
  json accel = json::object();
  json not_determined = json::object();
  std::vector<std::string> determined;
  for (const auto& [name, e] : est.items()) {
    const est::BlockInfo* g = group_of(name);
    if (g == nullptr) continue;  // df_eff_i, df_obs_i: the combinations below
    if (e.value("determined", std::string()) != "determined") {
      not_determined[name] = reason(e);
      continue;
    }
    determined.push_back(name);
    json& sensor = g->sensor == "gyro" ? gyro : accel;
    sensor[std::string(g->calibration)][name] = term(e, g->display_per_si, g->display_unit);
  }
  cal["gyro"] = gyro;
  cal["accelerometer"] = accel;
  // the accelerometer biases the run determined only in combination
  // (model.md, 8): what they are, for the mounting they hold for
  const json site = report.value("site", json::object());
  const double g =
      earth::normal_gravity(site.value("latitude_rad", 0.0), site.value("height_m", 0.0));
  json combos = json::array();
  for (const char* i : {"1", "2"}) {
    const std::string df0 = std::string("df0_") + i;
    if (est.contains(df0) && est[df0].value("determined", std::string()) == "determined") continue;
    for (const char* kind : {"df_obs_", "df_eff_"}) {
      const std::string name = kind + std::string(i);
      if (!est.contains(name) || est[name].value("determined", std::string()) != "determined")
        continue;
      const auto [unit, k] = display_unit(name);
      json c = term(est[name], k, unit);
      c["name"] = name;
      const bool obs = std::string_view(kind) == "df_obs_";
      c["definition"] = "df0_" + std::string(i) + " + g G" + i + "3" +
                        (obs ? " - g theta_" + std::string(i) + "3" : std::string());
      c["g"] = g;
      c["holds_for"] =
          "the INS mounted as in this run: instrument axis z3 along the table's axis, vertical, "
          "at the run's site (g as given); the g terms are those of that attitude";
      c["applies_as"] = obs ? "not as a correction on its own: accelerometer " + std::string(i) +
                                  "'s bias in this mounting is df0_" + i + " + g G" + i +
                                  "3 = this + g theta_" + i + "3, which needs theta_" + i +
                                  "3 from a calibration that turns the INS about a horizontal axis"
                            : "accelerometer " + std::string(i) +
                                  "'s bias in this mounting (subtract it from f_m_" + i +
                                  "); it does not part df0_" + i + " from G" + i + "3";
      // both when both are determined (a profile that also parts theta_i3
      // from them): df_eff is the correction, df_obs what it rests on
      combos.push_back(c);
    }
  }
  cal["combinations"] = combos;
  cal["not_determined"] = not_determined;
  if (report.contains("covariance")) {
    const json& cov = report["covariance"];
    std::vector<std::size_t> at;
    for (const std::string& n : determined)
      for (std::size_t k = 0; k < cov["order"].size(); ++k)
        if (cov["order"][k] == n) at.push_back(k);
    if (at.size() != determined.size())
      return make_error("run " + run_id + ": the report's covariance lacks a determined parameter");
    json m = json::array();
    for (const std::size_t a : at) {
      json row = json::array();
      for (const std::size_t b : at) row.push_back(cov["matrix"][a][b]);
      m.push_back(row);
    }
    cal["covariance"] = {{"order", determined}, {"matrix", m}, {"unit", "SI, each term's own"}};
  } else {
    cal["covariance"] = nullptr;  // a report from before turncal kept it
  }
  return cal;
}

namespace {

std::string toml_string(const std::string& s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

std::string toml_number(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  std::string s = buf;
  if (s.find_first_of(".e") == std::string::npos) s += ".0";  // a float, not an integer
  return s;
}

std::string toml_value(const json& v) {
  if (v.is_string()) return toml_string(v.get<std::string>());
  if (v.is_number()) return toml_number(v.get<double>());
  if (v.is_boolean()) return v.get<bool>() ? "true" : "false";
  if (v.is_array()) {
    std::string s = "[";
    for (std::size_t k = 0; k < v.size(); ++k) s += (k ? ", " : "") + toml_value(v[k]);
    return s + "]";
  }
  return "\"\"";  // null: absent in TOML, said in a comment by the caller
}

void toml_table(const std::string& name, const json& t, std::string& out) {
  std::string scalars;
  for (const auto& [k, v] : t.items())
    if (!v.is_object() && !v.is_null()) scalars += k + " = " + toml_value(v) + "\n";
  if (!scalars.empty() || t.empty()) out += "\n[" + name + "]\n" + scalars;
  for (const auto& [k, v] : t.items())
    if (v.is_object()) toml_table(name + "." + k, v, out);
}

}  // namespace

std::string calibration_toml(const json& cal) {
  std::string out = "# turncal calibration of run " + cal.value("run_id", std::string()) + "\n";
  for (const char* k : {"format", "run_id", "software_version", "convention"})
    out += std::string(k) + " = " + toml_value(cal[k]) + "\n";
  if (cal["unit"].is_string())
    out += "unit = " + toml_value(cal["unit"]) + "\n";
  else
    out += "# unit: not named\n";
  toml_table("gyro", cal["gyro"], out);
  toml_table("accelerometer", cal["accelerometer"], out);
  toml_table("not_determined", cal["not_determined"], out);
  if (cal["covariance"].is_object()) {
    out += "\n[covariance]\n";
    out += "order = " + toml_value(cal["covariance"]["order"]) + "\n";
    out += "unit = " + toml_value(cal["covariance"]["unit"]) + "\n";
    out += "matrix = [\n";
    for (const json& row : cal["covariance"]["matrix"]) out += "  " + toml_value(row) + ",\n";
    out += "]\n";
  } else {
    out += "\n# covariance: not in the report (a report from before turncal kept it)\n";
  }
  for (const json& c : cal["combinations"]) {
    out += "\n[[combinations]]\n";
    for (const auto& [k, v] : c.items()) out += k + " = " + toml_value(v) + "\n";
  }
  return out;
}

}  // namespace turncal::run
