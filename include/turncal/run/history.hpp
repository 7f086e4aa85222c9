// Per-unit history: the reports of one INS across runs, and how well its
// estimates repeat. Pure: the daemon hands it the reports it keeps.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace turncal::run {

/// The history of `unit` over `reports` (report_json's output, any order):
/// the finished runs that estimated ("done"), oldest first, each with its
/// estimates; per parameter the count, the mean, the spread (sample
/// standard deviation across runs) and the RMS of the runs' own sigmas, SI.
/// A spread well above the sigmas says the unit (or the stand) does not
/// repeat as the filter expects.
nlohmann::json history_json(const std::string& unit, const std::vector<nlohmann::json>& reports);

/// The same for people, in display units.
std::string history_text(const nlohmann::json& history);

}  // namespace turncal::run
