// Earth constants and the WGS-84 normal gravity model (model.md, 1). The
// only code the linear model and the nonlinear simulation share.
#pragma once

#include <cmath>

namespace turncal::earth {

inline constexpr double kRate = 7.292115e-5;           ///< Earth rate, rad/s
inline constexpr double kA = 6378137.0;                ///< WGS-84 semi-major axis, m
inline constexpr double kF = 1.0 / 298.257223563;      ///< WGS-84 flattening
inline constexpr double kE2 = kF * (2.0 - kF);         ///< first eccentricity squared
inline constexpr double kGammaE = 9.7803253359;        ///< normal gravity at the equator, m/s^2
inline constexpr double kSomiK = 0.00193185265241;     ///< Somigliana constant
inline constexpr double kGM = 3.986004418e14;          ///< m^3/s^2
inline constexpr double kOmegaA2B = 0.00344978650684;  ///< m = w^2 a^2 b / GM
inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kDeg = kPi / 180.0;

/// Meridian radius of curvature R_M from the sine of the latitude, m.
inline double meridian_radius_at_sin(double s) {
  const double w = 1.0 - kE2 * s * s;
  return kA * (1.0 - kE2) / (w * std::sqrt(w));
}
/// Meridian radius of curvature R_M at latitude, m.
inline double meridian_radius(double lat) {
  return meridian_radius_at_sin(std::sin(lat));
}

/// Normal (prime vertical) radius of curvature R_N from the sine of the
/// latitude, m.
inline double normal_radius_at_sin(double s) {
  return kA / std::sqrt(1.0 - kE2 * s * s);
}
/// Normal (prime vertical) radius of curvature R_N at latitude, m.
inline double normal_radius(double lat) {
  return normal_radius_at_sin(std::sin(lat));
}

/// Normal gravity from the sine of the latitude and the height: Somigliana
/// on the ellipsoid with the second-order free-air correction (NIMA
/// TR8350.2, 4-3), m/s^2.
inline double normal_gravity_at_sin(double s, double h) {
  const double s2 = s * s;
  const double g0 = kGammaE * (1.0 + kSomiK * s2) / std::sqrt(1.0 - kE2 * s2);
  return g0 *
         (1.0 - 2.0 / kA * (1.0 + kF + kOmegaA2B - 2.0 * kF * s2) * h + 3.0 / (kA * kA) * h * h);
}
/// Normal gravity at latitude and height, m/s^2.
inline double normal_gravity(double lat, double h) {
  return normal_gravity_at_sin(std::sin(lat), h);
}

}  // namespace turncal::earth
