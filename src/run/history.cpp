#include "turncal/run/history.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <utility>

#include "turncal/config.hpp"

namespace turncal::run {

using nlohmann::json;

json history_json(const std::string& unit, const std::vector<json>& reports) {
  std::vector<const json*> runs;
  std::size_t other = 0;
  for (const json& r : reports) {
    if (!r.is_object() || !r.contains("unit") || !r["unit"].is_string() || r["unit"] != unit)
      continue;
    if (r.value("status", std::string()) != "done" || !r.contains("estimates") ||
        !r["estimates"].is_object()) {
      ++other;
      continue;
    }
    runs.push_back(&r);
  }
  auto start = [](const json* r) { return r->value("start_time_unix_s", 0.0); };
  std::stable_sort(runs.begin(), runs.end(),
                   [&](const json* a, const json* b) { return start(a) < start(b); });
  json list = json::array();
  std::map<std::string, std::vector<std::pair<double, double>>> values;  // (value, sigma)
  std::map<std::string, std::string> units;
  for (const json* r : runs) {
    json est = json::object();
    for (const auto& [name, e] : (*r)["estimates"].items()) {
      // a parameter the run did not determine has the prior's value: no
      // part of the unit's history
      if (e.contains("determined") && e["determined"] == "not determined") continue;
      est[name] = {{"value", e["value"]}, {"sigma", e["sigma"]}};
      values[name].emplace_back(e["value"].get<double>(), e["sigma"].get<double>());
      units[name] = e.value("unit", std::string());
    }
    // reports are type-checked before they get here (check_report), but a
    // report may lack a section
    const bool has_profile = r->contains("profile") && (*r)["profile"].is_object();
    const bool has_verdict = r->contains("verdict") && (*r)["verdict"].is_object();
    list.push_back(
        {{"run_id", r->value("run_id", std::string())},
         {"start_time_unix_s", start(r)},
         {"profile", has_profile ? (*r)["profile"].value("name", std::string()) : std::string()},
         {"pass", has_verdict && (*r)["verdict"].value("pass", false)},
         {"estimates", est}});
  }
  json params = json::object();
  for (const auto& [name, vs] : values) {
    const double n = static_cast<double>(vs.size());
    double mean = 0, var = 0, sum_var = 0;
    for (const auto& [v, sg] : vs) {
      mean += v / n;
      sum_var += sg * sg;
    }
    for (const auto& [v, sg] : vs) var += (v - mean) * (v - mean);
    params[name] = {{"n", vs.size()},
                    {"mean", mean},
                    {"spread", vs.size() > 1 ? json(std::sqrt(var / (n - 1))) : json(nullptr)},
                    {"rms_sigma", std::sqrt(sum_var / n)},
                    {"unit", units[name]}};
  }
  return {{"unit", unit}, {"runs", list}, {"not_estimated", other}, {"parameters", params}};
}

std::string history_text(const json& h) {
  std::string out = "turncal history of unit " + h.value("unit", std::string("?")) + ": " +
                    std::to_string(h["runs"].size()) + " run(s) estimated";
  if (h.value("not_estimated", 0) > 0)
    out += ", " + std::to_string(h["not_estimated"].get<int>()) + " more ended without estimates";
  out += "\n";
  for (const auto& r : h["runs"]) {
    out += "  " + r.value("run_id", std::string()) + "  " + r.value("profile", std::string()) +
           (r.value("pass", false) ? "  pass\n" : "  FAIL\n");
  }
  if (h["parameters"].empty()) return out;
  out += "\n  parameter            mean       spread    rms sigma  spread/sigma  unit   (n)\n";
  for (const auto& [name, p] : h["parameters"].items()) {
    const auto [unit, k] = display_unit(name);
    const bool has_spread = p["spread"].is_number();
    const double spread =
        has_spread ? p["spread"].get<double>() * k : std::numeric_limits<double>::quiet_NaN();
    const double sigma = p["rms_sigma"].get<double>() * k;
    char buf[200];
    std::snprintf(
        buf, sizeof buf, "  %-12s %12.5g %12.5g %12.5g %13s  %-6s (%d)\n", name.c_str(),
        p["mean"].get<double>() * k, spread, sigma,
        has_spread && sigma > 0 ? std::to_string(spread / sigma).substr(0, 5).c_str() : "-",
        std::string(unit).c_str(), p["n"].get<int>());
    out += buf;
  }
  return out;
}

}  // namespace turncal::run
