// The nonlinear strapdown simulation: the truth of the estimator's tests and
// the engine of the virtual stand. A still base at a site, a table turning
// the INS about the vertical, an IMU with the errors of model.md section 2
// injected exactly (accelerometer 2 at its own proof mass), and an INS of
// its own: alignment (level from the mean accelerometer output, heading from
// the table plus an error, position plus an error) and free navigation with
// Earth rate, Coriolis and normal gravity. It shares no code with the linear
// model beyond the Earth constants.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "turncal/physics/profile.hpp"

namespace turncal::sim {

/// Sensor errors in SI, model.md's names.
struct SensorErrors {
  Eigen::Vector3d nu0 = Eigen::Vector3d::Zero();    ///< gyro biases, rad/s
  Eigen::Matrix3d theta = Eigen::Matrix3d::Zero();  ///< gyro scale/misalignment
  Eigen::Vector2d df0 = Eigen::Vector2d::Zero();    ///< accelerometer biases, m/s^2
  Eigen::Vector2d g = Eigen::Vector2d::Zero();      ///< G13, G23
  Eigen::Vector2d r = Eigen::Vector2d::Zero();      ///< proof-mass offset of accelerometer 2, m
};

/// Errors of the start.
struct StartErrors {
  Eigen::Vector2d v0 = Eigen::Vector2d::Zero();  ///< initial velocity error East, North, m/s
  double dr_e_m = 0;                             ///< position error East, m
  double dr_n_m = 0;                             ///< position error North, m
  double dpsi0_rad = 0;  ///< heading given minus true, clockwise from North, rad
};

struct Noise {
  double arw = 0;               ///< gyro angle random walk, rad/sqrt(s)
  double vrw = 0;               ///< accelerometer velocity random walk, m/s/sqrt(s)
  double velocity_sigma = 0;    ///< white noise on the output velocity, m/s
  double velocity_quantum = 0;  ///< output quantization step, m/s (0: none)
};

struct Config {
  double latitude_rad = 0;
  double longitude_rad = 0;
  double height_m = 0;
  double psi_start_rad = 0;  ///< start orientation: angle of z1 from East, counter-clockwise
  Profile profile;
  SensorErrors errors;
  StartErrors start;
  Noise noise;
  /// The table moved by commands instead of by `profile` (the virtual
  /// stand): its clock reads motion_t0_s at t0, the run has no end
  /// (profile.duration_s still bounds step()), and the motion must outlive
  /// the simulation. Only profile.align_s is used from the profile.
  const TableMotion* motion = nullptr;
  double motion_t0_s = 0;
  /// The heading the INS is given at alignment (of z2, clockwise from
  /// North, rad), e.g. from a host's command; NaN: the true heading. The
  /// error start.dpsi0_rad is added either way.
  double heading_given_rad = NAN;
  double imu_rate_hz = 400;
  double output_rate_hz = 100;   ///< positive; above imu_rate_hz: every IMU step
  double encoder_rate_hz = 200;  ///< simulate()'s encoder samples; 0 (or less): none
  double nav_rate_hz = 0;        ///< simulate()'s navigation states; 0 (or less): none
  std::uint64_t seed = 1;
};

struct VelocitySample {
  double t_s;  ///< experiment time (t0 = 0)
  double ve;   ///< INS output velocity East, m/s
  double vn;   ///< INS output velocity North, m/s
};

struct EncoderSample {
  double t_s;
  double angle_rad;  ///< table angle, counter-clockwise, relative to t0, unwrapped
};

/// The INS's own navigation state (noise-free) beside the truth.
struct NavSample {
  double t_s;
  double ve, vn;         ///< computed velocity East, North, m/s
  double lat_rad;        ///< computed latitude
  Eigen::Matrix3d c_bn;  ///< computed attitude: body to the computed East-North-Up frame
  double psi_rad;        ///< true orientation: angle of z1 from East, counter-clockwise
};

/// Runs alignment, then steps the IMU and the INS one IMU period at a time.
class Strapdown {
 public:
  explicit Strapdown(const Config& config);
  /// Advances one IMU period. Returns false past the end of the profile.
  bool step();
  [[nodiscard]] double time() const { return t_; }
  /// INS output velocity now (with output noise and quantization).
  [[nodiscard]] VelocitySample output();
  /// Table angle now (truth; the encoder reads it).
  [[nodiscard]] EncoderSample encoder() const;
  /// The INS's navigation state now, and the true orientation.
  [[nodiscard]] NavSample nav() const;

  /// The IMU's output over [ta, tb] (simulation time from t0): angle and
  /// velocity increments in body axes, with the configured errors and
  /// noise. What the INS navigates on; a calibration's test applies its
  /// corrections to it.
  struct Increments {
    Eigen::Vector3d dtheta, dv;
  };
  Increments imu(double ta, double tb);

 private:
  /// Table state relative to t0, in simulation time.
  [[nodiscard]] TableMotion::State table_at(double t) const;
  void navigate(const Increments& inc, double dt);
  void align();

  Config cfg_;
  TableTrajectory profile_table_;
  const TableMotion* motion_;  // the profile's or the config's
  /// Where the last read of motion_ left off (TableMotion::at's hint). A
  /// Strapdown is one thread's; the hint changes no result.
  mutable std::size_t motion_hint_ = 0;
  std::vector<double> cuts_;  ///< imu()'s integration intervals, kept to reuse their memory
  /// The table angle of the last step at rest and its sine and cosine.
  double rest_psi_ = NAN, rest_sin_ = NAN, rest_cos_ = NAN;
  double motion_t0_;
  double angle_t0_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double t_ = 0;
  long k_ = 0;  ///< IMU periods since t0
  double dt_;
  /// The true Earth rate's North and Up components and gravity at the
  /// stand, rad/s and m/s^2.
  double u2_, u3_, g_;
  // INS state: attitude body to computed ENU, velocity, position
  Eigen::Matrix3d c_bn_;
  Eigen::Vector3d v_;
  double lat_, lon_, h_;
  Increments prev_{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
};

/// A whole run at the output rate: velocity samples from t0 and encoder
/// samples; convenient for tests and offline use.
struct Run {
  std::vector<VelocitySample> velocity;
  std::vector<EncoderSample> encoder;
  std::vector<NavSample> nav;  ///< at Config::nav_rate_hz
};
Run simulate(const Config& config);

}  // namespace turncal::sim
