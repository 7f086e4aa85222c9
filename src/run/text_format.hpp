// printf-style formatting of one number, for the text reports. Internal to
// src/run.
#pragma once

#include <cstdio>
#include <string>

namespace turncal::run::detail {

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral"
/// `f` is always a literal format with one double conversion.
inline std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}
#pragma GCC diagnostic pop

}  // namespace turncal::run::detail
