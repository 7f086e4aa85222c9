// A CAN frame as the pure layers see it: no <linux/can.h> here (style.md, 1).
// The SocketCAN driver converts to and from the kernel's structs.
#pragma once

#include <array>
#include <cstdint>
#include <span>

namespace turncal::can {

inline constexpr std::size_t kMaxClassicLen = 8;
inline constexpr std::size_t kMaxFdLen = 64;
inline constexpr std::uint32_t kStdIdMask = 0x7FFu;
inline constexpr std::uint32_t kExtIdMask = 0x1FFFFFFFu;

struct Frame {
  std::uint32_t id = 0;   ///< identifier without flag bits (11 or 29 bit)
  std::uint8_t len = 0;   ///< payload length in bytes (0..8 classic, 0..64 FD)
  bool extended = false;  ///< 29-bit identifier
  bool remote = false;    ///< remote transmission request (classic only)
  bool fd = false;        ///< CAN FD frame
  bool brs = false;       ///< FD bit-rate switch
  bool esi = false;       ///< FD error state indicator
  bool error = false;     ///< error frame: `id` holds the CAN_ERR_* class bits
  std::array<std::uint8_t, kMaxFdLen> data{};

  [[nodiscard]] std::span<const std::uint8_t> payload() const { return {data.data(), len}; }
  friend bool operator==(const Frame& a, const Frame& b) {
    if (a.id != b.id || a.len != b.len || a.extended != b.extended || a.remote != b.remote ||
        a.fd != b.fd || a.brs != b.brs || a.esi != b.esi || a.error != b.error)
      return false;
    for (std::size_t i = 0; i < a.len; ++i)
      if (a.data[i] != b.data[i]) return false;
    return true;
  }
};

/// Valid CAN FD payload lengths (the DLC code points 9..15 map to 12..64).
[[nodiscard]] constexpr bool is_valid_fd_len(std::size_t len) {
  return len <= 8 || len == 12 || len == 16 || len == 20 || len == 24 || len == 32 || len == 48 ||
         len == 64;
}

/// A frame with its receive (or send) time, nanoseconds since the Unix epoch.
struct TimedFrame {
  std::int64_t time_ns = 0;
  Frame frame;
};

}  // namespace turncal::can
