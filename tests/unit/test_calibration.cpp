// The calibration file (turncalctl export) from a real report: what it
// keeps, what it leaves out and why, the covariance block, the refusals,
// and its TOML form read back by a TOML parser.
#include <doctest/doctest.h>

#include <toml++/toml.h>
#include <algorithm>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "turncal/build_paths.hpp"
#include "turncal/run/calibration.hpp"

using nlohmann::json;

namespace {

json golden() {
  std::ifstream in(std::string(turncal::build::source_dir) +
                   "/tests/data/golden/golden-report.json");
  REQUIRE(in);
  return json::parse(in);
}

/// The terms of a calibration's tables: name -> term.
json terms_of(const json& cal) {
  json all = json::object();
  for (const char* sensor : {"gyro", "accelerometer"})
    for (const auto& [table, t] : cal[sensor].items())
      for (const auto& [name, term] : t.items()) all[name] = term;
  return all;
}

}  // namespace

TEST_SUITE("calibration") {
  TEST_CASE("only what the run determined is a correction; the rest is absent with its reason") {
    const json r = golden();
    auto cal = turncal::run::calibration_json(r);
    REQUIRE_MESSAGE(cal.ok(), (cal.ok() ? "" : cal.error().describe()));
    const json terms = terms_of(*cal);
    int determined = 0;
    for (const auto& item : r["estimates"].items()) {
      const std::string& name = item.key();
      const json& e = item.value();
      if (name.rfind("df_", 0) == 0) continue;  // df_eff, df_obs: combinations
      CAPTURE(name);
      if (e["determined"] == "determined") {
        ++determined;
        REQUIRE(terms.contains(name));
        CHECK(terms[name]["value"].get<double>() == e["value"].get<double>());
        CHECK(terms[name]["sigma"].get<double>() == e["sigma"].get<double>());
        CHECK_FALSE((*cal)["not_determined"].contains(name));
      } else {
        CHECK_FALSE(terms.contains(name));
        REQUIRE((*cal)["not_determined"].contains(name));
        const std::string why = (*cal)["not_determined"][name];
        CHECK(why.find(e["determined"] == "partly" ? "partly determined" : "not determined") == 0);
      }
    }
    CHECK(determined == 4);  // nu0_1, nu0_2, r1, r2 in this run
    // display units: deg/h for a gyro bias, mm for r
    const double nu = terms["nu0_1"]["value"];
    CHECK(terms["nu0_1"]["display_value"].get<double>() ==
          doctest::Approx(nu * 180 / 3.141592653589793 * 3600).epsilon(1e-12));
    CHECK(terms["r1"]["display_unit"] == "mm");
    // df0 is not determined, df_obs is: given as the combination it is
    REQUIRE((*cal)["combinations"].size() == 2);
    const json& c = (*cal)["combinations"][0];
    CHECK(c["name"] == "df_obs_1");
    CHECK(c["definition"] == "df0_1 + g G13 - g theta_13");
    CHECK(c["value"].get<double>() == r["estimates"]["df_obs_1"]["value"].get<double>());
    CHECK(std::string(c["applies_as"]).find("not as a correction on its own") == 0);
    // a report from before the covariance was kept: said, not made up
    CHECK((*cal)["covariance"].is_null());
  }

  TEST_CASE("df_obs and df_eff both determined: both exported, each with what it applies as") {
    json r = golden();
    r["estimates"]["df_eff_1"]["determined"] = "determined";
    auto cal = turncal::run::calibration_json(r);
    REQUIRE(cal.ok());
    std::vector<std::string> names;
    for (const json& c : (*cal)["combinations"]) names.push_back(c["name"]);
    CHECK(names == std::vector<std::string>{"df_obs_1", "df_eff_1", "df_obs_2"});
    const json& eff = (*cal)["combinations"][1];
    CHECK(eff["definition"] == "df0_1 + g G13");
    CHECK(eff["value"].get<double>() == r["estimates"]["df_eff_1"]["value"].get<double>());
    CHECK(std::string(eff["applies_as"]).find("accelerometer 1's bias in this mounting") == 0);
  }

  TEST_CASE("the covariance of the determined block is the report's, in the file's order") {
    json r = golden();
    json order = json::array();
    json m = json::array();
    const std::vector<std::string> names = {"nu0_1", "nu0_2", "nu0_3", "r1", "r2"};
    for (std::size_t a = 0; a < names.size(); ++a) {
      order.push_back(names[a]);
      json row = json::array();
      for (std::size_t b = 0; b < names.size(); ++b)
        row.push_back(100.0 * static_cast<double>(a) + static_cast<double>(b));
      m.push_back(row);
    }
    r["covariance"] = {{"order", order}, {"matrix", m}};
    auto cal = turncal::run::calibration_json(r);
    REQUIRE(cal.ok());
    const json& cov = (*cal)["covariance"];
    REQUIRE(cov["order"].size() == 4);  // nu0_3 is not determined: not in the block
    for (std::size_t a = 0; a < 4; ++a)
      for (std::size_t b = 0; b < 4; ++b) {
        const auto ia = static_cast<std::size_t>(
            std::find(names.begin(), names.end(), cov["order"][a].get<std::string>()) -
            names.begin());
        const auto ib = static_cast<std::size_t>(
            std::find(names.begin(), names.end(), cov["order"][b].get<std::string>()) -
            names.begin());
        CHECK(cov["matrix"][a][b].get<double>() ==
              100.0 * static_cast<double>(ia) + static_cast<double>(ib));
      }
    // a covariance without a determined parameter is an error, not a guess
    r["covariance"]["order"][3] = "theta_11";
    CHECK_FALSE(turncal::run::calibration_json(r).ok());
  }

  TEST_CASE("a run not done, or a damaged report, has no calibration") {
    json r = golden();
    r["status"] = "aborted";
    auto cal = turncal::run::calibration_json(r);
    REQUIRE_FALSE(cal.ok());
    CHECK(cal.error().describe().find("aborted, not done") != std::string::npos);
    r = golden();
    r["estimates"]["nu0_1"]["sigma"] = "x";
    cal = turncal::run::calibration_json(r);
    REQUIRE_FALSE(cal.ok());
    CHECK(cal.error().describe().find("estimates.nu0_1.sigma") != std::string::npos);
  }

  TEST_CASE("the TOML form reads back to the same values") {
    json r = golden();
    r["covariance"] = {
        {"order", {"nu0_1", "nu0_2", "r1", "r2"}},
        {"matrix",
         {{1e-13, 2e-18, 3e-10, 4}, {2e-18, 5e-13, 6, 7}, {3e-10, 6, 7.5e-6, 8}, {4, 7, 8, 9}}}};
    auto cal = turncal::run::calibration_json(r);
    REQUIRE(cal.ok());
    const std::string text = turncal::run::calibration_toml(*cal);
    toml::table t;
    try {
      t = toml::parse(text);
    } catch (const toml::parse_error& e) {
      FAIL("the TOML does not parse: " << e.description() << "\n" << text);
    }
    CHECK(t["format"].value<std::string>() == "turncal-calibration-1");
    CHECK(t["convention"].value<std::string>() == (*cal)["convention"].get<std::string>());
    const json terms = terms_of(*cal);
    CHECK(t["gyro"]["bias"]["nu0_1"]["value"].value<double>() ==
          terms["nu0_1"]["value"].get<double>());
    CHECK(t["accelerometer"]["proof_mass_offset"]["r2"]["sigma"].value<double>() ==
          terms["r2"]["sigma"].get<double>());
    CHECK(t["not_determined"]["theta_11"].value<std::string>() ==
          (*cal)["not_determined"]["theta_11"].get<std::string>());
    const auto* m = t["covariance"]["matrix"].as_array();
    REQUIRE(m != nullptr);
    REQUIRE(m->size() == 4);
    CHECK((*m)[2].as_array()->at(2).value<double>() == 7.5e-6);
    CHECK((*m)[0].as_array()->at(3).value<double>() == 4.0);  // a float, not an integer
    const auto* combos = t["combinations"].as_array();
    REQUIRE(combos != nullptr);
    REQUIRE(combos->size() == 2);
    CHECK((*combos)[1].as_table()->at("name").value<std::string>() == "df_obs_2");
  }
}
