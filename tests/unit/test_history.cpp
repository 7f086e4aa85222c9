#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <vector>

#include "turncal/run/history.hpp"

using nlohmann::json;
using turncal::run::history_json;
using turncal::run::history_text;

namespace {

/// A report as report_json writes one, cut to what the history reads.
json report(const std::string& id, const json& unit, const std::string& status, double start,
            double nu, double nu_sigma) {
  json r = {{"run_id", id},
            {"unit", unit},
            {"status", status},
            {"start_time_unix_s", start},
            {"profile", {{"name", "tactical"}}},
            {"verdict", {{"pass", true}}}};
  if (status == "done")
    r["estimates"] = {
        {"nu0_1", {{"value", nu}, {"sigma", nu_sigma}, {"prior_sigma", 1e-5}, {"unit", "rad/s"}}},
        {"r1", {{"value", 0.01}, {"sigma", 0.002}, {"prior_sigma", 0.03}, {"unit", "m"}}}};
  return r;
}

}  // namespace

TEST_SUITE("history") {
  TEST_CASE("one unit's finished runs: oldest first, mean, spread and the runs' sigmas") {
    const std::vector<json> reports = {
        report("c", "SN-1", "done", 300, 3e-6, 0.4e-6),
        report("a", "SN-1", "done", 100, 1e-6, 0.3e-6),
        report("x", "SN-2", "done", 150, 9e-6, 0.3e-6),  // another unit
        report("b", "SN-1", "done", 200, 2e-6, 0.5e-6),
        report("f", "SN-1", "failed", 250, 0, 0),         // ended without estimates
        report("n", nullptr, "done", 260, 5e-6, 0.3e-6),  // no unit named
        json("not a report"),
    };
    const json h = history_json("SN-1", reports);
    REQUIRE(h["runs"].size() == 3);
    CHECK(h["runs"][0]["run_id"] == "a");
    CHECK(h["runs"][1]["run_id"] == "b");
    CHECK(h["runs"][2]["run_id"] == "c");
    CHECK(h["not_estimated"] == 1);
    const json& p = h["parameters"]["nu0_1"];
    CHECK(p["n"] == 3);
    CHECK(p["mean"].get<double>() == doctest::Approx(2e-6).epsilon(1e-12).scale(0));
    // sample standard deviation of 1, 2, 3 (x 1e-6): 1e-6
    CHECK(p["spread"].get<double>() == doctest::Approx(1e-6).epsilon(1e-12).scale(0));
    // RMS of 0.3, 0.5, 0.4 (x 1e-6)
    CHECK(p["rms_sigma"].get<double>() ==
          doctest::Approx(std::sqrt((0.09 + 0.25 + 0.16) / 3) * 1e-6).epsilon(1e-12).scale(0));
    CHECK(h["parameters"]["r1"]["spread"].get<double>() == 0);
    const std::string text = history_text(h);
    CHECK(text.find("3 run(s) estimated, 1 more ended without estimates") != std::string::npos);
    CHECK(text.find("deg/h") != std::string::npos);  // display units
  }

  TEST_CASE("a unit with one run has no spread; an unknown unit has no runs") {
    const std::vector<json> reports = {report("a", "SN-1", "done", 100, 1e-6, 0.3e-6)};
    const json one = history_json("SN-1", reports);
    CHECK(one["parameters"]["nu0_1"]["spread"].is_null());
    CHECK(history_text(one).find(" - ") != std::string::npos);
    const json none = history_json("SN-9", reports);
    CHECK(none["runs"].empty());
    CHECK(none["parameters"].empty());
  }
}

TEST_CASE("history: a parameter a run did not determine is no part of it") {
  json a = report("a", "SN-1", "done", 100, 1e-6, 0.3e-6);
  json b = report("b", "SN-1", "done", 200, 2e-6, 0.5e-6);
  a["estimates"]["theta_11"] = {
      {"value", 0.0}, {"sigma", 1e-4}, {"unit", "1"}, {"determined", "not determined"}};
  b["estimates"]["theta_11"] = {
      {"value", 1e-7}, {"sigma", 1e-4}, {"unit", "1"}, {"determined", "not determined"}};
  b["estimates"]["r1"]["determined"] = "determined";
  const json h = history_json("SN-1", {a, b});
  CHECK_FALSE(h["parameters"].contains("theta_11"));
  CHECK(h["parameters"]["r1"]["n"] == 2);
  CHECK_FALSE(h["runs"][0]["estimates"].contains("theta_11"));
}
