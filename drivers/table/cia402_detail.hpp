// What the CiA 402 master (cia402.cpp) and its modes of operation
// (cia402_*.cpp) share inside drivers/table: texts of numbers, the conversion
// of a physical value to a drive's u32 counts. Not an interface.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

#include "turncal/result.hpp"

namespace turncal::cia402::detail {

inline std::string hex(std::uint32_t v, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", digits, v);
  return buf;
}

inline std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

inline constexpr double kRadToDeg = 57.29577951308232;

/// A physical value in counts (rounded), or an error when it is not a
/// positive u32: never clamped.
inline Result<std::uint32_t> to_u32_counts(double value, double counts_per_unit, const char* what,
                                           std::uint16_t index, const char* unit) {
  const double c = std::round(value * counts_per_unit);
  if (!std::isfinite(c) || c < 1 || c > 4294967295.0)
    return make_error(std::string(what) + " " + num(value) + " " + unit + " is " + num(c) +
                      " counts, outside the drive's u32 range 1 to 4294967295 (" + hex(index, 4) +
                      ")");
  return static_cast<std::uint32_t>(c);
}

}  // namespace turncal::cia402::detail
