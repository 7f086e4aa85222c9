// The experiment as a sequence of filter steps: holds discretized once per
// hold (model.md, 7), turns by the encoder samples, epochs at a fixed
// interval from t0. Epochs that fall inside a turn carry no measurement
// (model.md, 5) and are skipped: one step spans hold - turn - hold.
#pragma once

#include <functional>
#include <span>
#include <vector>

#include "turncal/estimation/model.hpp"

namespace turncal::est {

struct TurnWindow {
  double t_start_s;  ///< last still instant before the turn
  double t_end_s;    ///< first still instant after it
};

struct TimelineInput {
  Site site;
  ProcessNoise noise;
  double epoch_s = 1.0;
  double duration_s = 0;             ///< from t0
  double psi_start_rad = 0;          ///< start orientation (model sense)
  std::vector<TurnWindow> turns;     ///< ascending, not overlapping
  std::vector<AngleSample> encoder;  ///< covering every turn window, psi unwrapped (model sense)
};

struct TimelineStep {
  double t_from;
  double t_to;  ///< an epoch: a measurement may be taken here
  const Discrete* d;
};

/// Builds the steps; the callback gets them in time order.
void for_each_step(const TimelineInput& in, const std::function<void(const TimelineStep&)>& fn);

}  // namespace turncal::est
