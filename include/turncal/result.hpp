// One error policy for the whole project (style.md, 9): decode, config and
// I/O return a Result; exceptions are kept for fatal start-up errors.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <variant>

namespace turncal {

/// Where in a text source an error was found. `line` and `column` are
/// 1-based; 0 means unknown.
struct SourcePos {
  std::string file;
  std::uint32_t line = 0;
  std::uint32_t column = 0;
};

/// An error value: a message and, for errors in a text source, where.
struct Error {
  std::string message;
  SourcePos where{};

  /// "file:line:column: message" (the parts that are known).
  [[nodiscard]] std::string describe() const {
    std::string out;
    if (!where.file.empty()) out += where.file + ":";
    if (where.line != 0) {
      out += std::to_string(where.line) + ":";
      if (where.column != 0) out += std::to_string(where.column) + ":";
    }
    if (!out.empty()) out += " ";
    out += message;
    return out;
  }
};

/// Either a value or an Error (a small std::expected for C++20).
template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::in_place_index<0>, std::move(value)) {}  // NOLINT: implicit by design
  Result(Error error) : v_(std::in_place_index<1>, std::move(error)) {}  // NOLINT

  [[nodiscard]] bool ok() const noexcept { return v_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }

  [[nodiscard]] T& value() & { return std::get<0>(v_); }
  [[nodiscard]] const T& value() const& { return std::get<0>(v_); }
  [[nodiscard]] T&& value() && { return std::get<0>(std::move(v_)); }
  [[nodiscard]] const Error& error() const& { return std::get<1>(v_); }
  [[nodiscard]] Error&& error() && { return std::get<1>(std::move(v_)); }

  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }

 private:
  std::variant<T, Error> v_;
};

/// Result of an operation that yields nothing but may fail.
struct Ok {};
using Status = Result<Ok>;

inline Error make_error(std::string message, SourcePos where = {}) {
  return Error{std::move(message), std::move(where)};
}

}  // namespace turncal

/// Returns the error of a Result-valued expression from the enclosing function.
#define TURNCAL_TRY(expr)                                      \
  do {                                                         \
    auto turncal_try_ = (expr);                                \
    if (!turncal_try_) return std::move(turncal_try_).error(); \
  } while (0)

/// Declares `var` from a Result-valued expression, or returns its error.
#define TURNCAL_ASSIGN(var, expr)                              \
  auto var##_result_ = (expr);                                 \
  if (!var##_result_) return std::move(var##_result_).error(); \
  auto var = std::move(var##_result_).value()
