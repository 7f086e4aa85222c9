// DBC files (the de-facto CAN database format) and the signal codec.
// Pure: parse from text, encode and decode payload bytes. What real vendor
// files use is supported (BU_, BO_, SG_ in Intel and Motorola order, signed
// and unsigned, 1..64 bits, SIG_VALTYPE_ floats, VAL_ tables, CM_, simple
// multiplexing, extended IDs, CAN FD lengths); other sections are skipped.
#pragma once

#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "turncal/can/frame.hpp"
#include "turncal/result.hpp"

namespace turncal::can {

enum class ByteOrder : std::uint8_t { LittleEndian, BigEndian };  // DBC @1 and @0
enum class ValueType : std::uint8_t { Integer, Float32, Float64 };
enum class MuxRole : std::uint8_t { None, Multiplexor, Multiplexed };

struct Signal {
  std::string name;
  std::uint32_t start_bit = 0;  ///< as written in the DBC (Motorola: the MSB, sawtooth numbering)
  std::uint32_t length = 0;     ///< bits, 1..64
  ByteOrder order = ByteOrder::LittleEndian;
  bool is_signed = false;
  ValueType type = ValueType::Integer;
  double factor = 1.0;
  double offset = 0.0;
  double minimum = 0.0;
  double maximum = 0.0;
  std::string unit;
  std::vector<std::string> receivers;
  MuxRole mux = MuxRole::None;
  std::uint64_t mux_value = 0;                 ///< for Multiplexed signals
  std::map<std::int64_t, std::string> values;  ///< VAL_ table
  std::string comment;
  std::uint32_t line = 0;  ///< where it is defined

  // Layout, computed by finalize(): the bytes [first_byte, first_byte+span)
  // hold the signal; `shift` moves its LSB to bit 0 of the loaded window.
  std::uint32_t first_byte = 0;
  std::uint32_t span = 0;
  std::uint32_t shift = 0;
  /// Computes the layout; false when start/length are out of range.
  bool finalize();
  /// Last byte (exclusive) the signal touches.
  [[nodiscard]] std::uint32_t end_byte() const { return first_byte + span; }
};

struct Message {
  std::uint32_t id = 0;  ///< without the extended flag
  bool extended = false;
  std::string name;
  std::uint32_t size = 0;  ///< payload bytes (DLC in the DBC, up to 64)
  bool fd = false;         ///< CAN FD (size > 8, or VFrameFormat says so)
  std::string transmitter;
  std::vector<Signal> signals;
  std::string comment;
  std::uint32_t line = 0;

  [[nodiscard]] const Signal* find_signal(std::string_view name) const;
  [[nodiscard]] const Signal* multiplexor() const;
};

struct Database {
  std::string version;
  std::uint32_t version_line = 0;  ///< where VERSION is; 0: none
  std::vector<std::string> nodes;
  std::vector<Message> messages;

  [[nodiscard]] const Message* find(std::uint32_t id, bool extended) const;
  [[nodiscard]] const Message* find(std::string_view name) const;
};

/// Parses DBC text; `file` is used in error positions.
Result<Database> parse_dbc(std::string_view text, const std::string& file = "<dbc>");
/// Reads and parses a DBC file.
Result<Database> load_dbc(const std::string& path);

// ---- signal codec (pure) ----

/// Raw bits of `sig` from `data` (which must hold sig.end_byte() bytes).
[[nodiscard]] std::uint64_t extract_raw(const Signal& sig, std::span<const std::uint8_t> data);
/// Writes the raw bits of `sig` into `data`, leaving other bits alone.
void insert_raw(const Signal& sig, std::span<std::uint8_t> data, std::uint64_t raw);
/// Raw bits to the physical value (sign, float type, factor, offset).
[[nodiscard]] double raw_to_physical(const Signal& sig, std::uint64_t raw);
/// The physical values a signal can carry: its raw range through factor and
/// offset, narrowed to the DBC's [min|max] where the file gives one ([0|0]
/// gives none). A float signal: what the float holds, through factor and
/// offset, narrowed the same way.
struct PhysicalRange {
  double lo = 0;
  double hi = 0;
};
[[nodiscard]] PhysicalRange physical_range(const Signal& sig);
/// The range for people, to the signal's step, with its unit:
/// "-21474.83648 to 21474.83647 deg".
[[nodiscard]] std::string describe_range(const Signal& sig);
/// True when `value` encodes into `sig` without saturating: a number whose
/// nearest step is inside the raw range and the DBC's [min|max].
[[nodiscard]] bool fits(const Signal& sig, double value);
/// Physical value to raw bits, rounded to the nearest step. A value that
/// does not fit is an error naming the signal and its range, never
/// saturated: a clipped command would move a device somewhere else.
[[nodiscard]] Result<std::uint64_t> physical_to_raw(const Signal& sig, double value);
/// Raw bits as a signed integer (sign-extended when the signal is signed).
[[nodiscard]] std::int64_t raw_to_integer(const Signal& sig, std::uint64_t raw);

/// Why a frame could not be decoded.
enum class DecodeStatus : std::uint8_t { Ok, UnknownId, LengthMismatch, NotData };

/// Tally of decode outcomes: a frame that cannot be decoded is counted and
/// skipped, never fatal.
struct DecodeCounts {
  std::uint64_t ok = 0;
  std::uint64_t unknown_id = 0;
  std::uint64_t length_mismatch = 0;
  std::uint64_t not_data = 0;
  void add(DecodeStatus st) {
    switch (st) {
      case DecodeStatus::Ok:
        ++ok;
        break;
      case DecodeStatus::UnknownId:
        ++unknown_id;
        break;
      case DecodeStatus::LengthMismatch:
        ++length_mismatch;
        break;
      case DecodeStatus::NotData:
        ++not_data;
        break;
    }
  }
  [[nodiscard]] std::uint64_t malformed() const { return length_mismatch; }
};

/// Decodes frames by ID through a Database (which must outlive it). Looks an
/// ID up in a hash map; a frame whose length differs from the message's is
/// counted and skipped, never fatal.
class FrameCodec {
 public:
  explicit FrameCodec(const Database& db);

  /// Message for a frame's ID, or nullptr.
  [[nodiscard]] const Message* message_for(const Frame& frame) const;
  /// Checks the frame against its message; on Ok `*msg` is set.
  DecodeStatus check(const Frame& frame, const Message** msg) const;
  /// Physical values of every signal of the message, in its signal order
  /// (`out` must hold msg->signals.size()). Multiplexed signals not selected
  /// by the multiplexor are set to NaN.
  DecodeStatus decode(const Frame& frame, std::span<double> out,
                      const Message** msg = nullptr) const;
  /// Builds a frame of `msg` from physical values (signal order; NaN leaves
  /// a signal's bits 0). A value that does not fit its signal is an error
  /// naming "Message.Signal", the value and the range: what goes to a
  /// device is built with this.
  static Result<Frame> encode_checked(const Message& msg, std::span<const double> values);
  /// The same unchecked, for values that fit by construction (a virtual
  /// device's own readings at its frame rates, test fixtures): one that
  /// does not fit is clamped to its signal's raw range.
  static Frame encode(const Message& msg, std::span<const double> values);

 private:
  const Database* db_;
  std::unordered_map<std::uint32_t, std::uint32_t> index_;  // key: id | extended << 31
};

}  // namespace turncal::can
