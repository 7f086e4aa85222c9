// The state layout of model.md, section 3, and its 18 parameters, each
// declared once (style.md, 4): a block table (where a block sits in the
// state, its units, its prior key) and a parameter table (name, block, why a
// run may miss it). Every offset, list, unit and label of the parameters is
// derived from these two tables; adding a parameter is one row (and its
// block's size) plus its model terms.
#pragma once

#include <array>
#include <cstddef>
#include <string_view>
#include <utility>

#include "turncal/earth.hpp"

namespace turncal::est {

/// The parameter blocks, in state order.
enum class Block : int { kGyroBias, kGyroScale, kAccelBias, kAccelMisalignment, kProofMass };

struct BlockInfo {
  Block block;
  int size;                       ///< parameters in the block
  std::string_view title;         ///< its heading in reports and plots
  std::string_view si_unit;       ///< the unit of its values in the state
  std::string_view display_unit;  ///< the unit it is shown in
  double display_per_si;          ///< SI value times this is the displayed value
  std::string_view prior_key;     ///< the plan's [priors] key: a number, or one per parameter
  double prior_si_per_key;        ///< the key's unit in SI
  double prior_default;           ///< in the key's unit (the tactical reference scenario)
  double prior_max;               ///< in the key's unit, the largest a plan may give
  std::string_view sensor;        ///< "gyro" or "accelerometer" (the calibration file)
  std::string_view calibration;   ///< its table in the calibration file
};

namespace detail {
inline constexpr double kDegPerHour = earth::kDeg / 3600;  ///< deg/h in rad/s
inline constexpr double kMicroG = 9.80665e-6;              ///< ug in m/s^2, to display
}  // namespace detail

inline constexpr std::array<BlockInfo, 5> kBlocks = {{
    {Block::kGyroBias, 3, "Gyro biases", "rad/s", "deg/h", 1 / detail::kDegPerHour, "gyro_bias_dph",
     detail::kDegPerHour, 1, 1e4, "gyro", "bias"},
    {Block::kGyroScale, 9, "Gyro scale and misalignment (Theta)", "1", "ppm", 1e6,
     "gyro_scale_misalignment", 1, 1e-3, 1, "gyro", "scale_misalignment"},
    // the plan's ug is 1e-6 g0 as written there (one ulp off kMicroG)
    {Block::kAccelBias, 2, "Accelerometer biases", "m/s^2", "ug", 1 / detail::kMicroG,
     "accel_bias_ug", 1e-6 * 9.80665, 1000, 1e6, "accelerometer", "bias"},
    {Block::kAccelMisalignment, 2, "Accelerometer misalignments towards the vertical", "1", "ppm",
     1e6, "accel_misalignment", 1, 1e-3, 1, "accelerometer", "misalignment"},
    {Block::kProofMass, 2, "Proof-mass offsets", "m", "mm", 1e3, "proof_mass_offset_m", 1, 0.03, 10,
     "accelerometer", "proof_mass_offset"},
}};

constexpr const BlockInfo& block_info(Block b) {
  return kBlocks[static_cast<std::size_t>(b)];
}

/// The first parameter of a block, counted from the first parameter.
constexpr int block_offset(Block b) {
  int at = 0;
  for (const BlockInfo& k : kBlocks) {
    if (k.block == b) return at;
    at += k.size;
  }
  return -1;
}

/// Offsets and sizes of the state blocks.
namespace sx {
inline constexpr int kDv = 0;   ///< dv1, dv2: velocity error East, North, m/s
inline constexpr int kA = 2;    ///< a1, a2: computed geographic frame rotation, rad
inline constexpr int kB = 4;    ///< b1, b2, b3: computed body vs computed geographic, rad
inline constexpr int kNav = 7;  ///< navigation errors; the parameters follow
inline constexpr int kNu0 = kNav + block_offset(Block::kGyroBias);         ///< gyro biases, rad/s
inline constexpr int kTheta = kNav + block_offset(Block::kGyroScale);      ///< Theta, row-major 3x3
inline constexpr int kDf0 = kNav + block_offset(Block::kAccelBias);        ///< accel biases 1, 2
inline constexpr int kG = kNav + block_offset(Block::kAccelMisalignment);  ///< G13, G23
inline constexpr int kR = kNav + block_offset(Block::kProofMass);  ///< r1, r2 of accelerometer 2
inline constexpr int kParams = [] {
  int n = 0;
  for (const BlockInfo& k : kBlocks) n += k.size;
  return n;
}();
inline constexpr int kN = kNav + kParams;
/// Index of Theta_ij (1-based i, j as in model.md).
constexpr int theta(int i, int j) {
  return kTheta + 3 * (i - 1) + (j - 1);
}
}  // namespace sx

// The model's equations (model.cpp) take Theta as 3x3 and the accelerometer
// blocks as one term per horizontal accelerometer.
static_assert(block_info(Block::kGyroBias).size == 3 && block_info(Block::kGyroScale).size == 9 &&
              block_info(Block::kAccelBias).size == 2 &&
              block_info(Block::kAccelMisalignment).size == 2 &&
              block_info(Block::kProofMass).size == 2);

/// Why a run may leave a parameter undetermined, as its report says.
namespace why {
inline constexpr std::string_view kPrior =
    "the run adds little to the prior: longer holds or more turns";
inline constexpr std::string_view kHorizontal = "needs a rotation about a horizontal axis";
inline constexpr std::string_view kRevolutions =
    "needs net whole revolutions about the vertical (the azimuth jump)";
inline constexpr std::string_view kTheta13 =
    "a turn about the vertical ties it to the accelerometer: only df0_1 + g G13 - g Theta_13 is "
    "seen; parting them needs a rotation about a horizontal axis";
inline constexpr std::string_view kTheta23 =
    "a turn about the vertical ties it to the accelerometer: only df0_2 + g G23 - g Theta_23 is "
    "seen; parting them needs a rotation about a horizontal axis";
inline constexpr std::string_view kAccel1 =
    "a turn about the vertical sees df0_1 and g G13 only as their sum, tied to g Theta_13: "
    "parting them needs a rotation about a horizontal axis";
inline constexpr std::string_view kAccel2 =
    "a turn about the vertical sees df0_2 and g G23 only as their sum, tied to g Theta_23: "
    "parting them needs a rotation about a horizontal axis";
inline constexpr std::string_view kTurn = "needs a faster turn, or more turns";
}  // namespace why

struct ParamInfo {
  std::string_view name;  ///< model.md's name
  Block block;
  std::string_view why;  ///< what a run that misses it lacks
};

/// The 18 parameters, in state order from sx::kNu0.
inline constexpr std::array<ParamInfo, sx::kParams> kParamTable = {{
    {"nu0_1", Block::kGyroBias, why::kPrior},
    {"nu0_2", Block::kGyroBias, why::kPrior},
    {"nu0_3", Block::kGyroBias, why::kPrior},
    {"theta_11", Block::kGyroScale, why::kHorizontal},
    {"theta_12", Block::kGyroScale, why::kHorizontal},
    {"theta_13", Block::kGyroScale, why::kTheta13},
    {"theta_21", Block::kGyroScale, why::kHorizontal},
    {"theta_22", Block::kGyroScale, why::kHorizontal},
    {"theta_23", Block::kGyroScale, why::kTheta23},
    {"theta_31", Block::kGyroScale, why::kHorizontal},
    {"theta_32", Block::kGyroScale, why::kHorizontal},
    {"theta_33", Block::kGyroScale, why::kRevolutions},
    {"df0_1", Block::kAccelBias, why::kAccel1},
    {"df0_2", Block::kAccelBias, why::kAccel2},
    {"g13", Block::kAccelMisalignment, why::kAccel1},
    {"g23", Block::kAccelMisalignment, why::kAccel2},
    {"r1", Block::kProofMass, why::kTurn},
    {"r2", Block::kProofMass, why::kTurn},
}};

/// Each block's rows sit together, at the block's offset, as many as its size.
constexpr bool param_table_matches_blocks() {
  for (const BlockInfo& k : kBlocks) {
    if (block_info(k.block).block != k.block) return false;  // kBlocks in enum order
    const int at = block_offset(k.block);
    for (int i = 0; i < sx::kParams; ++i) {
      const bool inside = i >= at && i < at + k.size;
      if (inside != (kParamTable[static_cast<std::size_t>(i)].block == k.block)) return false;
    }
  }
  return true;
}
static_assert(param_table_matches_blocks(), "kParamTable's rows do not match kBlocks");

/// The named combinations of parameters a report gives beside them
/// (model.md, 8): rows as the parameters', shown in their block's units.
inline constexpr std::array<ParamInfo, 4> kCombinations = {{
    {"df_eff_1", Block::kAccelBias, why::kAccel1},
    {"df_eff_2", Block::kAccelBias, why::kAccel2},
    {"df_obs_1", Block::kAccelBias, why::kPrior},
    {"df_obs_2", Block::kAccelBias, why::kPrior},
}};

/// The index of a parameter from sx::kNu0, or -1 for none of the 18.
constexpr int param_index(std::string_view name) {
  for (std::size_t i = 0; i < kParamTable.size(); ++i)
    if (kParamTable[i].name == name) return static_cast<int>(i);
  return -1;
}

/// model.md's names of the 18 parameters, in state order from sx::kNu0.
inline constexpr std::array<std::string_view, sx::kParams> kParamNames = [] {
  std::array<std::string_view, sx::kParams> a{};
  for (std::size_t i = 0; i < a.size(); ++i) a[i] = kParamTable[i].name;
  return a;
}();

/// SI units of the 18 parameters, in state order from sx::kNu0.
inline constexpr std::array<std::string_view, sx::kParams> kParamUnits = [] {
  std::array<std::string_view, sx::kParams> a{};
  for (std::size_t i = 0; i < a.size(); ++i) a[i] = block_info(kParamTable[i].block).si_unit;
  return a;
}();

static_assert(param_index("theta_23") == sx::theta(2, 3) - sx::kNu0);
static_assert(param_index("df0_1") == sx::kDf0 - sx::kNu0 &&
              param_index("r2") == sx::kR + 1 - sx::kNu0);

/// The row of a parameter or a named combination; nullptr for neither.
constexpr const ParamInfo* named_row(std::string_view name) {
  if (const int i = param_index(name); i >= 0) return &kParamTable[static_cast<std::size_t>(i)];
  for (const ParamInfo& c : kCombinations)
    if (c.name == name) return &c;
  return nullptr;
}

/// The block of a parameter or a named combination; nullptr for neither.
constexpr const BlockInfo* block_of(std::string_view name) {
  const ParamInfo* r = named_row(name);
  return r != nullptr ? &block_info(r->block) : nullptr;
}

/// What a run that leaves `name` undetermined lacks (the prior's reason for
/// a name of neither table).
constexpr std::string_view why_undetermined(std::string_view name) {
  const ParamInfo* r = named_row(name);
  return r != nullptr ? r->why : why::kPrior;
}

/// Display unit of a parameter or a named combination ("deg/h", "ppm",
/// "ug", "mm") and the factor from SI to it; an empty unit for an unknown
/// name.
constexpr std::pair<std::string_view, double> display_unit(std::string_view name) {
  const BlockInfo* b = block_of(name);
  if (b == nullptr) return {"", 0};
  return {b->display_unit, b->display_per_si};
}

}  // namespace turncal::est
