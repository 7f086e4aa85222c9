#include "turncal/physics/strapdown.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "turncal/earth.hpp"

namespace turncal::sim {
namespace {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

Mat3 rot_z(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Mat3 m;
  m << c, -s, 0, s, c, 0, 0, 0, 1;
  return m;
}

/// exp([v x]): the rotation by the rotation vector v, I + (sin a / a) K +
/// ((1 - cos a) / a^2) K^2 with K = [v x] and a = |v|. Below 0.02 rad (an
/// IMU step's attitude change, short of a table at 2 rad/s and 100 Hz) the
/// two factors by their series to a^6, whose first term left out is under
/// 1e-19: no sine or cosine, and none of 1 - cos a's cancellation.
Mat3 rodrigues(const Vec3& v) {
  const double a2 = v.squaredNorm();
  double f1 = 0, f2 = 0;  // sin a / a, (1 - cos a) / a^2
  if (a2 < 4e-4) {
    f1 = 1 - a2 / 6 * (1 - a2 / 20 * (1 - a2 / 42));
    f2 = 0.5 * (1 - a2 / 12 * (1 - a2 / 30 * (1 - a2 / 56)));
  } else {
    const double a = std::sqrt(a2);
    f1 = std::sin(a) / a;
    f2 = (1 - std::cos(a)) / a2;
  }
  Mat3 k;
  k << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return Mat3::Identity() + f1 * k + f2 * (k * k);
}

// 3-point Gauss-Legendre on [-1, 1]
constexpr double kGlX[3] = {-0.7745966692414834, 0.0, 0.7745966692414834};
constexpr double kGlW[3] = {5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0};

}  // namespace

Strapdown::Strapdown(const Config& config)
    : cfg_(config),
      profile_table_(config.profile),
      motion_(config.motion != nullptr ? config.motion : &profile_table_.motion()),
      motion_t0_(config.motion != nullptr ? config.motion_t0_s : 0.0),
      angle_t0_(motion_->at(motion_t0_).angle),
      rng_(config.seed),
      dt_(1.0 / config.imu_rate_hz),
      u2_(earth::kRate * std::cos(config.latitude_rad)),
      u3_(earth::kRate * std::sin(config.latitude_rad)),
      g_(earth::normal_gravity(config.latitude_rad, config.height_m)) {
  align();
}

TableMotion::State Strapdown::table_at(double t) const {
  TableMotion::State s = motion_->at(motion_t0_ + t, motion_hint_);
  s.angle -= angle_t0_;
  return s;
}

Strapdown::Increments Strapdown::imu(double ta, double tb) {
  // True motion: body z3 vertical, psi(t) = psi_s + table angle; the INS
  // reference point M (accelerometer 1) on the table axis, at rest.
  const double u2 = u2_, u3 = u3_, g = g_;
  // Integrate over [ta, tb], split where the table's acceleration jumps;
  // the table's state read in ascending time, so that the motion's hint
  // finds each piece without a search.
  cuts_.assign(1, ta);
  motion_->breakpoints_in(motion_t0_ + ta, motion_t0_ + tb, cuts_, motion_hint_);
  for (std::size_t i = 1; i < cuts_.size(); ++i) cuts_[i] -= motion_t0_;
  cuts_.push_back(tb);
  const auto sa = table_at(ta);
  Vec3 earth_rate_int = Vec3::Zero();  // int A(psi)^T u_x dt
  double omega2_int = 0;               // int Omega^2 dt
  if (cuts_.size() == 2 && sa.rate == 0 && sa.accel == 0) {
    // at rest over the whole step (no piece starts inside it): the
    // integrand is constant, its sine and cosine those of the last step
    // while the table has not moved
    const double psi = cfg_.psi_start_rad + sa.angle;
    if (psi != rest_psi_) {
      rest_psi_ = psi;
      rest_sin_ = std::sin(psi);
      rest_cos_ = std::cos(psi);
    }
    earth_rate_int = (tb - ta) * Vec3(u2 * rest_sin_, u2 * rest_cos_, u3);
  } else {
    for (std::size_t i = 0; i + 1 < cuts_.size(); ++i) {
      const double mid = 0.5 * (cuts_[i] + cuts_[i + 1]), half = 0.5 * (cuts_[i + 1] - cuts_[i]);
      for (int k = 0; k < 3; ++k) {
        const auto st = table_at(mid + half * kGlX[k]);
        const double psi = cfg_.psi_start_rad + st.angle;
        const double w = kGlW[k] * half;
        earth_rate_int += w * Vec3(u2 * std::sin(psi), u2 * std::cos(psi), u3);
        omega2_int += w * st.rate * st.rate;
      }
    }
  }
  const auto sb = table_at(tb);
  const double dt = tb - ta;
  Increments inc;
  const Vec3 true_dtheta = earth_rate_int + Vec3(0, 0, sb.angle - sa.angle);
  // gyros: nu_z = nu0 + Theta omega_z (+ noise)
  inc.dtheta = true_dtheta + cfg_.errors.nu0 * dt + cfg_.errors.theta * true_dtheta;
  // accelerometers: f_z = (0, 0, g) at M; accelerometer 2 at its proof mass
  // also senses [dOmega x r + Omega x (Omega x r)]_2 = dOmega r1 - Omega^2 r2.
  Vec3 true_dv(0, 0, g * dt);
  true_dv.y() += cfg_.errors.r.x() * (sb.rate - sa.rate) - cfg_.errors.r.y() * omega2_int;
  inc.dv = true_dv;
  inc.dv.x() += cfg_.errors.df0.x() * dt + cfg_.errors.g.x() * true_dv.z();
  inc.dv.y() += cfg_.errors.df0.y() * dt + cfg_.errors.g.y() * true_dv.z();
  if (cfg_.noise.arw > 0)
    for (int i = 0; i < 3; ++i) inc.dtheta(i) += cfg_.noise.arw * std::sqrt(dt) * normal_(rng_);
  if (cfg_.noise.vrw > 0)
    for (int i = 0; i < 3; ++i) inc.dv(i) += cfg_.noise.vrw * std::sqrt(dt) * normal_(rng_);
  return inc;
}

void Strapdown::align() {
  // Level from the mean accelerometer output over the alignment window.
  const auto steps = static_cast<long>(std::llround(cfg_.profile.align_s / dt_));
  Vec3 dv_sum = Vec3::Zero();
  for (long k = 0; k < steps; ++k) {
    const double ta = -cfg_.profile.align_s + static_cast<double>(k) * dt_;
    dv_sum += imu(ta, ta + dt_).dv;
  }
  const Vec3 up = dv_sum.normalized();
  const Vec3 y_h = (Vec3::UnitY() - Vec3::UnitY().dot(up) * up).normalized();
  const Vec3 x_h = y_h.cross(up);
  Mat3 level;
  level.row(0) = x_h.transpose();
  level.row(1) = y_h.transpose();
  level.row(2) = up.transpose();
  // Heading of z2 clockwise from North: true -psi_s, given with an error.
  const double given =
      std::isnan(cfg_.heading_given_rad) ? -cfg_.psi_start_rad : cfg_.heading_given_rad;
  const double heading = given + cfg_.start.dpsi0_rad;
  c_bn_ = rot_z(-heading) * level;
  // Position given with an error; velocity starts with its own error.
  lat_ = cfg_.latitude_rad +
         cfg_.start.dr_n_m / (earth::meridian_radius(cfg_.latitude_rad) + cfg_.height_m);
  lon_ = cfg_.longitude_rad +
         cfg_.start.dr_e_m / ((earth::normal_radius(cfg_.latitude_rad) + cfg_.height_m) *
                              std::cos(cfg_.latitude_rad));
  h_ = cfg_.height_m;
  v_ = Vec3(cfg_.start.v0.x(), cfg_.start.v0.y(), 0);
  t_ = 0;
}

void Strapdown::navigate(const Increments& inc, double dt) {
  const double sin_lat = std::sin(lat_), cos_lat = std::cos(lat_);
  const double rm = earth::meridian_radius_at_sin(sin_lat) + h_;
  const double rn = earth::normal_radius_at_sin(sin_lat) + h_;
  const Vec3 w_ie(0, earth::kRate * cos_lat, earth::kRate * sin_lat);
  const Vec3 w_en(-v_.y() / rm, v_.x() / rn, v_.x() * (sin_lat / cos_lat) / rn);
  const Vec3 w_in = w_ie + w_en;
  // coning and sculling (two-sample, previous-interval form)
  const Vec3 phi = inc.dtheta + prev_.dtheta.cross(inc.dtheta) / 12.0;
  const Vec3 dv_b = inc.dv + 0.5 * inc.dtheta.cross(inc.dv) +
                    (prev_.dtheta.cross(inc.dv) + prev_.dv.cross(inc.dtheta)) / 12.0;
  // specific force into the mid-interval navigation frame
  Vec3 dv_n = c_bn_ * dv_b;
  dv_n -= 0.5 * (w_in * dt).cross(dv_n);
  const Vec3 gravity(0, 0, -earth::normal_gravity_at_sin(sin_lat, h_));
  const Vec3 v_old = v_;
  v_ += dv_n + (gravity - (2 * w_ie + w_en).cross(v_)) * dt;
  v_.z() = 0;  // vertical channel held: the stand is at a known height
  lat_ += 0.5 * (v_old.y() + v_.y()) * dt / rm;
  lon_ += 0.5 * (v_old.x() + v_.x()) * dt / (rn * std::cos(lat_));
  c_bn_ = rodrigues(-w_in * dt) * c_bn_ * rodrigues(phi);
  prev_ = inc;
}

bool Strapdown::step() {
  const double ta = t_;
  const double tb = static_cast<double>(k_ + 1) * dt_;
  if (tb > cfg_.profile.duration_s + 0.5 * dt_) return false;
  navigate(imu(ta, tb), dt_);
  t_ = static_cast<double>(++k_) * dt_;  // no drift from repeated addition
  return true;
}

VelocitySample Strapdown::output() {
  double ve = v_.x(), vn = v_.y();
  if (cfg_.noise.velocity_sigma > 0) {
    ve += cfg_.noise.velocity_sigma * normal_(rng_);
    vn += cfg_.noise.velocity_sigma * normal_(rng_);
  }
  if (cfg_.noise.velocity_quantum > 0) {
    ve = std::round(ve / cfg_.noise.velocity_quantum) * cfg_.noise.velocity_quantum;
    vn = std::round(vn / cfg_.noise.velocity_quantum) * cfg_.noise.velocity_quantum;
  }
  return {t_, ve, vn};
}

EncoderSample Strapdown::encoder() const {
  return {t_, table_at(t_).angle};
}

NavSample Strapdown::nav() const {
  return {t_, v_.x(), v_.y(), lat_, c_bn_, cfg_.psi_start_rad + table_at(t_).angle};
}

Run simulate(const Config& config) {
  Strapdown sd(config);
  Run run;
  // IMU steps a sample; a rate above the IMU's gives one every step
  const auto every = [&](double rate_hz) {
    return std::max(1L, static_cast<long>(std::llround(config.imu_rate_hz / rate_hz)));
  };
  const long out_every = every(config.output_rate_hz);
  const bool with_encoder = config.encoder_rate_hz > 0;
  const long enc_every = with_encoder ? every(config.encoder_rate_hz) : 0;
  const bool with_nav = config.nav_rate_hz > 0;
  const long nav_every = with_nav ? every(config.nav_rate_hz) : 0;
  const double steps = std::max(0.0, config.profile.duration_s * config.imu_rate_hz) + 2;
  run.velocity.reserve(static_cast<std::size_t>(steps / static_cast<double>(out_every)) + 1);
  if (with_encoder)
    run.encoder.reserve(static_cast<std::size_t>(steps / static_cast<double>(enc_every)) + 1);
  if (with_nav)
    run.nav.reserve(static_cast<std::size_t>(steps / static_cast<double>(nav_every)) + 1);
  long k = 0;
  run.velocity.push_back(sd.output());
  if (with_encoder) run.encoder.push_back(sd.encoder());
  if (with_nav) run.nav.push_back(sd.nav());
  while (sd.step()) {
    ++k;
    if (k % out_every == 0) run.velocity.push_back(sd.output());
    if (with_encoder && k % enc_every == 0) run.encoder.push_back(sd.encoder());
    if (with_nav && k % nav_every == 0) run.nav.push_back(sd.nav());
  }
  return run;
}

}  // namespace turncal::sim
