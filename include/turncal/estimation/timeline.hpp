// The experiment as a sequence of filter steps: holds discretized once per
// hold (model.md, 7), turns by the encoder samples, measurements on a grid
// of epochs from t0 and at the turn boundaries (model.md, 5): the last INS
// sample before each turn and the first after it. Epochs that fall inside
// a turn carry no measurement and are skipped: a step spans whatever holds
// and turns lie between two measurements.
#pragma once

#include <cmath>
#include <functional>
#include <optional>
#include <span>
#include <vector>

#include "turncal/estimation/model.hpp"
#include "turncal/result.hpp"

namespace turncal::est {

struct TurnWindow {
  double t_start_s;  ///< last still instant before the turn
  double t_end_s;    ///< first still instant after it
  /// The planned turn, for the fallback when the encoder has a gap in the
  /// window: angle (model sense, signed) and plateau rate. NaN: unknown.
  double angle_rad = NAN;
  double plateau_rate_rps = NAN;
  /// The boundary measurements (model.md, 5): the time of the last INS
  /// sample at or before t_start_s and of the first at or after t_end_s.
  /// NaN: none (no sample between this turn and the one before or after,
  /// or a timeline without them).
  double sample_before_s = NAN;
  double sample_after_s = NAN;
};

struct TimelineInput {
  Site site;
  ProcessNoise noise;
  double epoch_s = 1.0;
  double duration_s = 0;             ///< from t0
  double psi_start_rad = 0;          ///< start orientation (model sense)
  std::vector<TurnWindow> turns;     ///< ascending, not overlapping
  std::vector<AngleSample> encoder;  ///< ascending, psi unwrapped (model sense)
  /// The longest encoder gap within a turn window that the sample-based
  /// turn transition accepts; a longer one switches that turn to the
  /// constant-rate closed form. The sample sums are exact on the plateau
  /// and miss about alpha^2 g^3 / 12 of int Omega^2 across a gap g on a
  /// rate ramp: on the reference turn a 0.2 s hole adds 7e-6 m/s (that
  /// term) to the transition's 9e-6 m/s; the closed form misses by 2.5e-4
  /// m/s (test_estimator.cpp).
  double max_encoder_gap_s = 0.25;
  /// The second pass's nominal (model.md, 8): the model linearised about
  /// it, each epoch about its state at the epoch's middle.
  std::optional<Nominal> nominal;
};

struct TimelineStep {
  double t_from;
  double t_to;  ///< a measurement time: an epoch, or a turn boundary's sample
  const Discrete* d;
  /// The measurement at t_to is the one INS sample at t_to (a turn's
  /// boundary), not one taken from around an epoch.
  bool boundary = false;
  /// An epoch's measurement takes its samples from inside (still_from_s,
  /// still_to_s): the still interval around t_to that no turn and no
  /// boundary measurement has (open at both ends).
  double still_from_s = -INFINITY;
  double still_to_s = INFINITY;
};

/// A still interval between turns (or the start or end of the run).
struct HoldSpan {
  double t_from_s;
  double t_to_s;
  double psi_rad;  ///< orientation during the hold (model sense)
};

/// How each turn was propagated.
enum class TurnSource { Encoder, ClosedForm };

struct TimelineReport {
  std::vector<HoldSpan> holds;
  std::vector<TurnSource> turns;
  std::size_t steps = 0;
};

/// Builds the steps; the callback gets them in time order. Fails when a
/// turn window has an encoder gap and no planned angle and rate to fall
/// back on.
Result<TimelineReport> for_each_step(const TimelineInput& in,
                                     const std::function<void(const TimelineStep&)>& fn);

/// psi at t, linear between encoder samples (ascending in t, not empty);
/// the end samples held beyond the ends.
double psi_at(std::span<const AngleSample> enc, double t);

/// The holds of the run and their orientations, as for_each_step sees them.
Result<std::vector<HoldSpan>> hold_spans(const TimelineInput& in);

}  // namespace turncal::est
