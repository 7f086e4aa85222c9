// Single-loop estimation (model.md, 8): one square-root filter over both
// holds and the turn, driven by the INS output velocity; the same filter on
// the model alone (covariance analysis); the two-stage baseline; and what
// the result means: parameters in SI with their sigmas, the effective
// accelerometer biases, the combinations the run determines, the
// correlation matrix and the innovation statistics.
#pragma once

#include <array>
#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include "turncal/estimation/filter.hpp"
#include "turncal/estimation/timeline.hpp"
#include "turncal/result.hpp"

namespace turncal::est {

/// Prior standard deviations of the independent start variables (model.md, 6).
struct Priors {
  double v0_mps = 1e-3;                      ///< initial velocity error, per axis
  double position_m = 10;                    ///< position error, per axis
  double heading_rad = 0;                    ///< heading error given at alignment
  double align_s = 120;                      ///< alignment length (nbar variance q_a / T_align)
  std::array<double, sx::kParams> params{};  ///< the 18 parameters, SI
};

struct VelocityObs {
  double t_s;
  double ve;
  double vn;
};

struct EstimationInput;

/// What the nonlinear nominal gives: the velocity the INS would output,
/// noise-free, and its navigation state, which the model is linearised
/// about (model.md, 8), both ascending in time from t0.
struct NominalRun {
  std::vector<VelocityObs> velocity;
  std::vector<NominalState> track;
};

/// The nonlinear nominal of the second pass: what the INS would do if its
/// errors were `params` (SI, state order from sx::kNu0) and its start
/// errors zero (strapdown_nominal in turncal/estimation/nominal.hpp: the
/// nonlinear strapdown over the recorded table motion).
using NominalModel = Result<NominalRun> (*)(const EstimationInput& in,
                                            const std::array<double, sx::kParams>& params);

/// The nonlinear second pass (model.md, 8): the linear model is exact only
/// about zero errors. Iterated about the estimate p_i: the nominal's
/// velocity h(p_i) is taken from the data and the residual z - h(p_i)
/// estimated by the linear model, with the prior of the parameters moved
/// to mean p_prior - p_i = -p_i, until no parameter changes by more than
/// `tolerance_sigma` of its sigma (Gauss-Newton, or the iterated Kalman
/// filter, with the Jacobian of the model about the nominal's own
/// navigation state: Nominal in model.hpp).
struct SecondPassSettings {
  enum class Mode {
    Auto,    ///< where the first pass predicts a linearisation error over threshold_sigma
    Off,     ///< never (the first pass is the result)
    Always,  ///< whenever a nominal is given
  };
  Mode mode = Mode::Auto;
  NominalModel nominal = nullptr;  ///< none: no second pass
  /// Auto runs the second pass where linearisation_error_sigma() of the
  /// first pass exceeds this: an error of 0.3 sigma added in quadrature
  /// inflates the RMS of error/sigma by 4%.
  double threshold_sigma = 0.3;
  double tolerance_sigma = 0.01;
  int max_iterations = 5;
  /// The IMU rate of the nominal's strapdown (strapdown_nominal). The table
  /// turns about one axis only, so its attitude integrates without coning
  /// at any rate, and 100 Hz moves the estimates by under a hundredth of a
  /// sigma against 400 Hz (tests/scenario/test_second_pass.cpp) at a
  /// quarter of the cost.
  double nominal_imu_rate_hz = 100;
  /// Where this, 0 resolved to the hardware's thread count, is more than
  /// one, the two-stage baseline runs on a thread of its own beside the
  /// first pass and the second. The result does not depend on it. On
  /// Linux it starts at the caller's nice value (turncald's estimation
  /// runs below its loop).
  unsigned threads = 0;
};

struct EstimationInput {
  TimelineInput timeline;
  Priors priors;
  double sigma_z = 1e-3;          ///< velocity output noise of one sample, m/s
  bool mean_measurement = false;  ///< mean around the epoch instead of the nearest sample
  double sample_rate_hz = 100;    ///< INS velocity rate (the covariance analysis's samples)
  /// Measurements at the turn boundaries besides the epochs (model.md, 5);
  /// off only to compare with the grid alone.
  bool boundary_measurements = true;
  std::vector<VelocityObs> velocity;  ///< ascending in time
  /// Report the combinations whose posterior sigma is at most this
  /// fraction of their prior sigma (model.md, 8).
  double sharp_ratio = 0.1;
  bool with_two_stage = false;  ///< also run the two-stage baseline (its covariance)
  int whiteness_lags = 20;      ///< lags of the innovation whiteness test
  SecondPassSettings second_pass;
};

struct Innovation {
  double t_s;
  Meas value;
  Eigen::Matrix2d cov;
};

/// One estimated quantity in SI.
struct ParameterEstimate {
  std::string_view name;
  std::string_view unit;
  double value = 0;
  double sigma = 0;
  double prior_sigma = 0;
};

/// A linear combination sum_j coeff_j p_j of the parameters that the run
/// determines much better than the prior. Scaled so that the coefficient
/// of `lead` (the parameter that weighs most in it) is 1: the value and
/// sigma are in that parameter's unit.
struct Combination {
  std::array<double, sx::kParams> coeff{};
  int lead = 0;  ///< index into the 18 parameters
  double value = 0;
  double sigma = 0;
  double prior_sigma = 0;
  /// When the direction is one of the model's named combinations (within
  /// 8 degrees in the prior-whitened space): its name ("df_obs_1", ...),
  /// and value and sigma are that combination's, in its unit. Else empty.
  std::string_view name;
  /// Eigenvalues within 2% of each other span a degenerate eigenspace, in
  /// which any basis is as sharp: such combinations are rotated onto the
  /// parameter axes they span, and marked so.
  bool from_degenerate = false;
};

/// Consistency and whiteness of the normalized innovations
/// e_k = Re_k^-1/2 nu_k (2 components per epoch).
struct InnovationStats {
  std::size_t count = 0;
  double nis_mean = 0;  ///< mean of e^T e; 2 for a consistent filter
  double nis_lo = 0;    ///< two-sided 95% interval of nis_mean under consistency
  double nis_hi = 0;
  int lags = 0;
  std::array<double, 2> ljung_box{};  ///< Ljung-Box Q of each component over `lags`
  double ljung_box_limit = 0;         ///< 95% point of chi^2(lags)
  /// P(chi^2(lags) > Q) of each component: how often a white sequence
  /// gives a Q this large.
  std::array<double, 2> ljung_box_p{1.0, 1.0};
  /// Where a report calls the innovations not white: a p-value this small
  /// on either axis, which a white sequence gives one run in 500.
  static constexpr double kAlarmP = 1e-3;
  /// NIS within its 95% interval: a consistent filter fails 5% of runs.
  [[nodiscard]] bool consistent() const { return nis_mean >= nis_lo && nis_mean <= nis_hi; }
  /// Neither axis's p-value under kAlarmP.
  [[nodiscard]] bool white() const {
    return ljung_box_p[0] >= kAlarmP && ljung_box_p[1] >= kAlarmP;
  }
};

/// P(chi^2(k) > x), the survival function of the chi-square distribution:
/// the regularized upper incomplete gamma function Q(k/2, x/2).
double chi2_survival(double k, double x);

/// The two-stage baseline (model.md, 8): one filter per hold from the
/// prior, the INS taken as re-aligned at each position, fused as
/// independent information. Only its covariance is computed: its
/// estimates would need a re-aligned INS at each hold, which the
/// single-loop experiment does not have.
struct TwoStage {
  std::array<double, sx::kParams> sigma{};  ///< two-stage sigma per parameter, SI
  std::array<double, sx::kParams> ratio{};  ///< single-loop sigma / two-stage sigma
};

/// What the second pass did.
struct SecondPass {
  bool ran = false;
  /// Why it ran or not, in a sentence.
  std::string reason;
  /// The criterion: the linearisation error the first pass predicts, in
  /// sigmas of the determined quantity where it is largest.
  double predicted_sigma = 0;
  int iterations = 0;      ///< nonlinear nominals run
  bool converged = false;  ///< the last change under tolerance_sigma
  /// The largest change of a parameter in the last iteration, in sigmas.
  double last_change_sigma = NAN;
};

struct EstimationResult {
  StateVec x = StateVec::Zero();
  StateMat p = StateMat::Zero();
  std::vector<double> epoch_t;
  std::vector<StateVec> x_history;      ///< estimate after each epoch
  std::vector<StateVec> sigma_history;  ///< sqrt(diag P) after each epoch
  std::vector<Innovation> innovations;
  std::size_t degraded_updates = 0;
  TimelineReport timeline;
  std::array<ParameterEstimate, sx::kParams> parameters{};
  std::array<ParameterEstimate, 2> df_eff{};  ///< df0_i + g G_i3
  /// df0_i + g G_i3 - g Theta_i3: what one turn about the vertical sees of
  /// the accelerometer (model.md, 8)
  std::array<ParameterEstimate, 2> df_obs{};
  std::vector<Combination> combinations;  ///< sharpest first
  Eigen::Matrix<double, sx::kParams, sx::kParams> correlation =
      Eigen::Matrix<double, sx::kParams, sx::kParams>::Zero();
  InnovationStats innovation_stats;
  bool has_two_stage = false;
  TwoStage two_stage;
  /// After a second pass: the parameters and dv of x and x_history are the
  /// estimates (nominal plus correction); a and b stay the perturbation
  /// about the nominal's position and attitude (its track holds those, in
  /// other coordinates, and they are not added back).
  SecondPass second_pass;
};

/// Sigma_xi (diagonal) from the priors and the process noise.
XiVec prior_sigmas(const Priors& priors, const ProcessNoise& noise);

/// Runs the square-root filter over the record, then the second pass
/// where in.second_pass says.
Result<EstimationResult> estimate(const EstimationInput& in);

/// The second pass's criterion (model.md, 8): the linearisation error, in
/// sigmas, that the first pass `first` predicts for the quantity it
/// determines best relative to its size. The second-order terms of the
/// error equations are a fraction rho of the first-order ones, with
///   rho = |b3|max + |v|max / sqrt(g R):
/// b3 the azimuth error (the heading prior, |nu0_3| T and |Theta_33|
/// times the largest angle turned from the start, each estimate taken
/// with one sigma added, as either may be undetermined): the rotation of
/// the horizontal errors by the azimuth the linear model leaves out; and
/// the largest measured velocity over sqrt(g R), the Schuler-loop speed
/// (7.9 km/s): the transport rate v/R beside the Schuler rate. A
/// relative model error rho in the velocity errs an estimate p by about
/// rho |p|; in its sigmas, rho max_j |p_j| / sigma_j over the determined
/// parameters and df_obs.
double linearisation_error_sigma(const EstimationInput& in, const EstimationResult& first);

/// Covariance analysis: the same filter on the model alone, a measurement
/// at every epoch, no data (in.velocity is ignored). Predicts the accuracy
/// of a planned experiment; the estimates are zero.
Result<EstimationResult> analyse(const EstimationInput& in);

/// The two-stage baseline's covariance; `single` gives the ratio.
Result<TwoStage> two_stage(const EstimationInput& in, const StateMat& single_p);

}  // namespace turncal::est
