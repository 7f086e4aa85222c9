// The HTML report of a run: one self-contained page (inline CSS, SVG and a
// few lines of script; nothing fetched), for people to look at: the run,
// pass/fail, the parameter table (estimate, prior and posterior sigma, their
// ratio) and the combinations; SVG plots of sigma against time per
// parameter group, the INS velocity and the filter residuals against time
// with the turns marked, the table angle and rate, and the histogram of the
// normalized innovations. Pure: the daemon and the replay write what this
// returns.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/run/record.hpp"

namespace turncal::run {

/// The page of `report` (report_json's output). `input` and `result` give
/// the time series; without them (a run that ended before estimation) the
/// page shows the report alone.
std::string report_html(const nlohmann::json& report, const BuiltInput* input,
                        const est::EstimationResult* result);

/// One plot of sigma against time: parameters (indices from sx::kNu0) that
/// share one display unit, so the plot has one unit on its axis.
struct SigmaPlotGroup {
  std::string title;
  std::vector<int> params;
};
const std::vector<SigmaPlotGroup>& sigma_plot_groups();

}  // namespace turncal::run
