// SHA-256 (FIPS 180-4): what a report names its run's log and configuration
// by. The compression runs on the CPU's SHA extensions where it has them
// (x86-64 SHA-NI, chosen once at run time), else in portable C++; both give
// the same digest, which the unit tests check against each other.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "turncal/result.hpp"

namespace turncal::run {

/// SHA-256, fed in pieces of any size.
class Sha256 {
 public:
  Sha256();
  void update(std::string_view data);
  /// The digest of everything so far, lower-case hex.
  [[nodiscard]] std::string hex() const;

 private:
  std::array<std::uint32_t, 8> h_;
  std::array<unsigned char, 64> buf_{};
  std::size_t fill_ = 0;
  std::uint64_t bytes_ = 0;
};

/// SHA-256 of a byte string, lower-case hex.
std::string sha256_hex(std::string_view data);

struct FileDigest {
  std::string sha256;
  std::optional<std::uint64_t> lines;  ///< newlines (the frames of a candump log), when asked
};
/// Whether sha256_file counts the file's lines as well (a pass of memchr
/// over every byte: a tenth of a replay's digest, for a count it has).
enum class CountLines : std::uint8_t { No, Yes };
/// Whether sha256_file reads through a symbolic link: a replay may be given
/// one; the daemon's own logs in its state directory never are one.
enum class Links : std::uint8_t { Follow, Refuse };
/// SHA-256 of a file, and its line count when asked, read in 1 MiB pieces
/// (a run's log can be far larger than the daemon's memory budget). Only a
/// regular file is read, and never by a blocking open.
Result<FileDigest> sha256_file(const std::string& path, CountLines count = CountLines::No,
                               Links links = Links::Follow);

namespace detail {
/// The compression function (FIPS 180-4, 6.2.2) over `blocks` whole
/// 64-byte blocks at `p`.
using Sha256Blocks = void (*)(std::array<std::uint32_t, 8>& h, const unsigned char* p,
                              std::size_t blocks);
void sha256_blocks_portable(std::array<std::uint32_t, 8>& h, const unsigned char* p,
                            std::size_t blocks);
/// The SHA extensions' compression, or nullptr where this CPU or this
/// build has none.
Sha256Blocks sha256_blocks_hardware();
}  // namespace detail

}  // namespace turncal::run
