// A planned experiment, as kept in config/profiles/*.toml: the table
// profile (holds and turns), the site, the priors and noise of the INS
// under test, and the estimation settings. Validated into plain structs at
// the edge; errors name file, line and key. No toml++ in this header.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/physics/profile.hpp"
#include "turncal/result.hpp"

namespace turncal {

inline constexpr double kStandardGravity = 9.80665;  ///< g0 of "mg", "ug", m/s^2

struct Plan {
  std::string name;
  std::string description;
  std::string source;  ///< file it was read from
  std::string text;    ///< its text, as read (a report keeps it, so a replay needs no file)
  std::vector<std::string> overrides;  ///< "key=value" set over the text, in order
  Profile profile;
  double start_angle_rad = 0;  ///< table angle at t0, counter-clockwise seen from above
  est::Site site;
  est::Priors priors;
  double arw = 0;      ///< gyro angle random walk, rad/sqrt(s)
  double vrw = 0;      ///< accelerometer velocity random walk, m/s/sqrt(s)
  double sigma_z = 0;  ///< INS output velocity noise per sample, m/s
  double epoch_s = 1;
  bool mean_measurement = false;
  double sharp_ratio = 0.1;
  [[nodiscard]] est::ProcessNoise noise() const { return {vrw * vrw, arw * arw}; }
};

/// Parses a plan. Each override is "section.key=VALUE" with VALUE in TOML
/// (`estimation.epoch_s=2`, `estimation.measurement="mean"`,
/// `priors.gyro_bias_dph=[1,1,0.5]`), set over the text before it is
/// validated, so an override is checked like the file; its errors name it.
Result<Plan> parse_plan(std::string_view text, const std::string& file,
                        std::span<const std::string> overrides = {});
Result<Plan> load_plan(const std::string& path, std::span<const std::string> overrides = {});

}  // namespace turncal
