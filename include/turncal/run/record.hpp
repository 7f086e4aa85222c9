// The record of a run (the samples the estimator needs, kept compact) and
// its translation into the estimation core's input: every time on the INS
// clock from t0 (the first velocity sample, can-icd.md), the encoder mapped
// through the fitted clocks, psi = table angle - heading_offset, the turns
// found in the encoder record itself. Pure: the daemon and the replay build
// the same input from the same frames.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/plan.hpp"
#include "turncal/result.hpp"
#include "turncal/run/ingest.hpp"

namespace turncal::run {

/// Samples of one run. The encoder keeps both ends of each run of equal
/// angles and every sample in between that moved, so a still table costs
/// two samples however long it holds. The INS velocity is most of a run's
/// memory (an hour at 100 Hz is 8.6 MB): it is kept as the estimator takes
/// it, 24 bytes a sample, allocated once for the span the run expects, and
/// moved, not copied, into the estimation input.
class Record {
 public:
  /// The velocity samples should span about `span_s` of INS time: once the
  /// rate is seen (on the first 256 samples), room for all of them is
  /// reserved, so the vector never grows by doubling (which would hold old
  /// and new storage, three times the data, at once).
  void expect_span(double span_s) { expected_span_s_ = span_s; }
  /// That room asks the kernel for huge pages (a few page faults where
  /// there would be thousands): for a replay only, whose loop no device
  /// waits on. Not in the daemon: with the kernel's usual settings a huge
  /// page's first touch may compact memory, a stall in its event loop.
  /// Call before the 256th velocity sample, when the room is reserved.
  void use_huge_pages() { huge_pages_ = true; }
  [[nodiscard]] bool huge_pages() const { return huge_pages_; }
  /// A real second is `scale` stand seconds (the stand's time_scale): the
  /// time tag checks' and the clock fits' gates are real time;
  /// `late_floor_s` as for TagCheck::set_time_scale.
  void set_time_scale(double scale, double late_floor_s = 0) {
    velocity_tags_.set_time_scale(scale, late_floor_s);
    encoder_tags_.set_time_scale(scale, late_floor_s);
  }
  void add(const Sample& s);
  /// Keeps the end of the encoder's last constant run; call before reading
  /// `encoder()` (safe to repeat, and to add more samples after).
  void close();
  /// The INS velocity, `t_s` on the INS clock (unwrapped), not yet from t0.
  [[nodiscard]] const std::vector<est::VelocityObs>& velocity() const { return velocity_; }
  /// Moves the velocity samples out; the record keeps its clocks and encoder.
  std::vector<est::VelocityObs> take_velocity() { return std::exchange(velocity_, {}); }
  [[nodiscard]] const std::vector<EncoderSample>& encoder() const { return encoder_; }
  /// The device clocks fitted on the recorded samples alone, so that the
  /// same frames give the same mapping live and in a replay.
  [[nodiscard]] const ClockFit& ins_clock() const { return ins_clock_; }
  [[nodiscard]] const ClockFit& table_clock() const { return table_clock_; }
  [[nodiscard]] std::size_t clock_outliers() const { return clock_outliers_; }
  /// The time tags checked before a sample is kept: velocity on the INS
  /// clock, encoder on the table's. Dropped samples are not in the record.
  [[nodiscard]] const TagCheck& velocity_tags() const { return velocity_tags_; }
  [[nodiscard]] const TagCheck& encoder_tags() const { return encoder_tags_; }
  /// Why a device clock cannot be trusted any more ("" while both can).
  [[nodiscard]] std::string clock_fault() const;
  /// clock_fault() is not "".
  [[nodiscard]] bool clock_faulted() const {
    return velocity_tags_.faulted() || encoder_tags_.faulted();
  }

 private:
  ClockFit ins_clock_, table_clock_;
  TagCheck velocity_tags_, encoder_tags_;
  std::size_t clock_outliers_ = 0;
  double expected_span_s_ = 0;
  bool huge_pages_ = false;
  std::vector<est::VelocityObs> velocity_;
  std::vector<EncoderSample> encoder_;
  bool pending_ = false;
  EncoderSample last_{};
};

/// The span of encoder samples each rate of TurnAchieved::peak_rate_rps is
/// fitted over, s.
inline constexpr double kPeakWindowS = 0.2;

/// The largest |rate| of encoder samples from..to (indices, from < to),
/// each the least-squares slope over kPeakWindowS of samples (over all of
/// them when they span less), rad/s. A slope over two samples would read a
/// table timed by its receipt (a CiA 402 TPDO without SYNC), whose samples
/// come in bursts, several times too fast; the fit's error is the receipt
/// jitter over the window. On a ramp it reads the rate at the window's
/// middle: a turn that never reaches a plateau shows 3 alpha window / 16
/// below its peak (the fit weighs the rate by h^2 - t^2 over the window's
/// half-width h, and the mean |t| so weighted is 3 h / 8).
double peak_rate_rps(const std::vector<est::AngleSample>& enc, std::size_t from, std::size_t to);

/// What the encoder says a turn was.
struct TurnAchieved {
  double t_start_s;  ///< INS clock from t0
  double t_end_s;
  double angle_rad;      ///< net, signed
  double peak_rate_rps;  ///< largest |rate|, each a least-squares fit over kPeakWindowS
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
  /// The nonlinear second pass: where the first pass says linearisation
  /// matters (Auto), never, or always.
  est::SecondPassSettings::Mode second_pass = est::SecondPassSettings::Mode::Auto;
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
/// Takes the record's velocity samples (moved, not copied: they are most
/// of a run's memory), so it is built once per record.
Result<BuiltInput> build_input(Record& record, const Plan& plan, const BuildSettings& settings);

}  // namespace turncal::run
