// The record of a run (the samples the estimator needs, kept compact) and
// its translation into the estimation core's input: every time on the INS
// clock from t0 (the first velocity sample, can-icd.md), the encoder mapped
// through the fitted clocks, psi = table angle - heading_offset, the turns
// found in the encoder record itself. Pure: the daemon and the replay build
// the same input from the same frames.
#pragma once

#include <string>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/plan.hpp"
#include "turncal/result.hpp"
#include "turncal/run/ingest.hpp"

namespace turncal::run {

/// Samples of one run. The encoder keeps both ends of each run of equal
/// angles and every sample in between that moved, so a still table costs
/// two samples however long it holds.
class Record {
 public:
  void add(const Sample& s);
  /// Keeps the end of the encoder's last constant run; call before reading
  /// `encoder()` (safe to repeat, and to add more samples after).
  void close();
  [[nodiscard]] const std::vector<VelocitySample>& velocity() const { return velocity_; }
  [[nodiscard]] const std::vector<EncoderSample>& encoder() const { return encoder_; }
  /// The device clocks fitted on the recorded samples alone, so that the
  /// same frames give the same mapping live and in a replay.
  [[nodiscard]] const ClockFit& ins_clock() const { return ins_clock_; }
  [[nodiscard]] const ClockFit& table_clock() const { return table_clock_; }
  [[nodiscard]] std::size_t clock_outliers() const { return clock_outliers_; }

 private:
  ClockFit ins_clock_, table_clock_;
  std::size_t clock_outliers_ = 0;
  std::vector<VelocitySample> velocity_;
  std::vector<EncoderSample> encoder_;
  bool pending_ = false;
  EncoderSample last_{};
};

/// What the encoder says a turn was.
struct TurnAchieved {
  double t_start_s;  ///< INS clock from t0
  double t_end_s;
  double angle_rad;      ///< net, signed
  double peak_rate_rps;  ///< largest |rate| between samples 10 ms or more apart
  double planned_angle_rad = NAN;
};

struct BuildSettings {
  double heading_offset_rad = 0;
  /// A step between encoder samples larger than this is motion (about
  /// 1 arcsec: above an encoder's jitter, far below any turn).
  double jitter_rad = 5e-6;
  /// Motions closer than this in time are one turn.
  double merge_s = 0.5;
  double sample_rate_hz = 100;  ///< INS velocity rate
  bool two_stage = true;
};

struct BuiltInput {
  est::EstimationInput input;
  std::vector<TurnAchieved> turns;
  double t0_ins_s = 0;  ///< the INS clock at t0
  std::size_t velocity_used = 0;
  std::vector<std::string> notes;  ///< what the builder had to assume
};

/// An estimation input with what `plan` sets: site, noise, epoch, priors,
/// output noise, measurement and sharp ratio; `sample_rate_hz` is the INS
/// velocity rate. The record (build_input) and the planning
/// (planned_input) add the timeline and the data.
est::EstimationInput input_of_plan(const Plan& plan, double sample_rate_hz);

/// The estimation input of a recorded run of `plan` (the record closed).
Result<BuiltInput> build_input(const Record& record, const Plan& plan,
                               const BuildSettings& settings);

}  // namespace turncal::run
