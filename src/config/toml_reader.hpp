// The TOML reading shared by the configuration parsers: every error names
// file, line and key; unknown keys are errors. Internal to src/config.
#pragma once

#include <toml++/toml.h>

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <span>
#include <string>
#include <string_view>

#include "turncal/result.hpp"

namespace turncal::config_detail {

/// Where a node was read; a node set by an override (source "--set KEY=VALUE")
/// is named by the override, not by a line of the file.
inline SourcePos pos_of(const toml::source_region& r, const std::string& file) {
  if (r.path && r.path->starts_with("--set ")) return SourcePos{*r.path, 0, 0};
  return SourcePos{file, r.begin.line, r.begin.column};
}

/// Reads a validated [section] into fields; every error names file, line and key.
class Reader {
 public:
  Reader(const toml::table& t, std::string file, std::string prefix)
      : t_(t), file_(std::move(file)), prefix_(std::move(prefix)) {}

  Error error_at(const toml::node& n, std::string_view key, std::string what) const {
    return make_error("key '" + prefix_ + std::string(key) + "': " + std::move(what),
                      pos_of(n.source(), file_));
  }
  /// Unknown keys are errors: a typo must not silently fall back to a default.
  Status no_unknown_keys(std::initializer_list<std::string_view> known) const {
    return no_unknown_keys(std::span<const std::string_view>(known.begin(), known.size()));
  }
  Status no_unknown_keys(std::span<const std::string_view> known) const {
    for (auto&& [k, v] : t_) {
      bool ok = false;
      for (auto kk : known) ok = ok || k.str() == kk;
      if (!ok)
        return make_error("unknown key '" + prefix_ + std::string(k.str()) + "'",
                          pos_of(k.source(), file_));
    }
    return Status{Ok{}};
  }
  Status string(std::string_view key, std::string& out) const {
    const toml::node* n = t_.get(key);
    if (n == nullptr) return Status{Ok{}};
    if (!n->is_string()) return error_at(*n, key, "expected a string");
    out = n->as_string()->get();
    return Status{Ok{}};
  }
  Status boolean(std::string_view key, bool& out) const {
    const toml::node* n = t_.get(key);
    if (n == nullptr) return Status{Ok{}};
    if (!n->is_boolean()) return error_at(*n, key, "expected true or false");
    out = n->as_boolean()->get();
    return Status{Ok{}};
  }
  Status integer(std::string_view key, std::uint32_t& out, std::int64_t lo, std::int64_t hi) const {
    const toml::node* n = t_.get(key);
    if (n == nullptr) return Status{Ok{}};
    if (!n->is_integer()) return error_at(*n, key, "expected an integer");
    const std::int64_t v = n->as_integer()->get();
    if (v < lo || v > hi)
      return error_at(*n, key,
                      "must be between " + std::to_string(lo) + " and " + std::to_string(hi));
    out = static_cast<std::uint32_t>(v);
    return Status{Ok{}};
  }
  /// A number (integer or float) within [lo, hi].
  Status number(std::string_view key, double& out, double lo, double hi) const {
    const toml::node* n = t_.get(key);
    if (n == nullptr) return Status{Ok{}};
    return number_at(*n, key, out, lo, hi);
  }
  /// One number for every element, or an array of exactly out.size() numbers.
  Status numbers(std::string_view key, std::span<double> out, double lo, double hi) const {
    const toml::node* n = t_.get(key);
    if (n == nullptr) return Status{Ok{}};
    if (const toml::array* a = n->as_array()) {
      if (a->size() != out.size())
        return error_at(*n, key,
                        "expected one number or an array of " + std::to_string(out.size()));
      for (std::size_t i = 0; i < out.size(); ++i)
        TURNCAL_TRY(number_at((*a)[i], key, out[i], lo, hi));
      return Status{Ok{}};
    }
    double v = 0;
    TURNCAL_TRY(number_at(*n, key, v, lo, hi));
    for (double& o : out) o = v;
    return Status{Ok{}};
  }
  const toml::table& table() const { return t_; }
  const std::string& file() const { return file_; }

 private:
  Status number_at(const toml::node& n, std::string_view key, double& out, double lo,
                   double hi) const {
    double v = 0;
    if (n.is_integer())
      v = static_cast<double>(n.as_integer()->get());
    else if (n.is_floating_point())
      v = n.as_floating_point()->get();
    else
      return error_at(n, key, "expected a number");
    if (!std::isfinite(v) || v < lo || v > hi)
      return error_at(n, key, "must be between " + fmt(lo) + " and " + fmt(hi));
    out = v;
    return Status{Ok{}};
  }
  static std::string fmt(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%g", v);
    return b;
  }
  const toml::table& t_;
  std::string file_;
  std::string prefix_;
};

}  // namespace turncal::config_detail
