// The state layout of model.md, section 3, declared once (style.md, 4).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <string_view>

namespace turncal::est {

/// Offsets and sizes of the state blocks.
namespace sx {
inline constexpr int kDv = 0;      ///< dv1, dv2: velocity error East, North, m/s
inline constexpr int kA = 2;       ///< a1, a2: computed geographic frame rotation, rad
inline constexpr int kB = 4;       ///< b1, b2, b3: computed body vs computed geographic, rad
inline constexpr int kNu0 = 7;     ///< gyro biases, rad/s
inline constexpr int kTheta = 10;  ///< gyro scale/misalignment, row-major 3x3
inline constexpr int kDf0 = 19;    ///< accelerometer biases 1, 2, m/s^2
inline constexpr int kG = 21;      ///< G13, G23
inline constexpr int kR = 23;      ///< r1, r2: proof-mass offset of accelerometer 2, m
inline constexpr int kNav = 7;     ///< navigation errors
inline constexpr int kParams = 18;
inline constexpr int kN = kNav + kParams;
/// Index of Theta_ij (1-based i, j as in model.md).
constexpr int theta(int i, int j) {
  return kTheta + 3 * (i - 1) + (j - 1);
}
}  // namespace sx

using StateVec = Eigen::Matrix<double, sx::kN, 1>;
using StateMat = Eigen::Matrix<double, sx::kN, sx::kN>;

/// model.md's names of the 18 parameters, in state order from sx::kNu0.
inline constexpr std::array<std::string_view, sx::kParams> kParamNames = {
    "nu0_1",    "nu0_2",    "nu0_3",    "theta_11", "theta_12", "theta_13",
    "theta_21", "theta_22", "theta_23", "theta_31", "theta_32", "theta_33",
    "df0_1",    "df0_2",    "g13",      "g23",      "r1",       "r2"};

/// Independent variables of the start (model.md, 6): x0 = T xi.
namespace sxi {
inline constexpr int kV0 = 0;      ///< dv(t0) East, North, m/s
inline constexpr int kDrE = 2;     ///< position error East, m
inline constexpr int kDrN = 3;     ///< position error North, m
inline constexpr int kDpsi0 = 4;   ///< heading error given at alignment, rad, clockwise from North
inline constexpr int kNbar = 5;    ///< accelerometer noise mean over the alignment, 1 and 2, m/s^2
inline constexpr int kParams = 7;  ///< the 18 parameters, as in the state
inline constexpr int kN = kParams + sx::kParams;
}  // namespace sxi

using XiVec = Eigen::Matrix<double, sxi::kN, 1>;
using XiMat = Eigen::Matrix<double, sx::kN, sxi::kN>;

}  // namespace turncal::est
