// DBC files (the de-facto CAN database format) and the signal codec.
// Pure: parse from text, encode and decode payload bytes. What real vendor
// files use is supported (BU_, BO_, SG_ in Intel and Motorola order, signed
// and unsigned, 1..64 bits, SIG_VALTYPE_ floats, VAL_ tables, CM_, simple
// and extended multiplexing (SG_MUL_VAL_), extended IDs, CAN FD lengths,
// the long names of the System*LongSymbol attributes); other sections are
// skipped.
//
// Vendor files as written are read, not refused: what the file does not
// quite say (an ID above 0x7FF without the extended bit, a comment for a
// message it does not define, text in Windows-1252) is read the way
// Vector's tools read it, and a signal that cannot be decoded (it does not
// fit its message, its layout or scaling is impossible, its multiplexor is
// unknown) is kept but marked unusable. Each such place is a warning with
// file and line in Database::warnings. Whether an unusable signal matters
// is for the user of the file to say: resolve_roles (config.hpp) refuses a
// role that names one. So is an SG_ line the grammar cannot read: it is
// skipped with a warning, and no role may be in its message. Anything else
// the grammar cannot read stays an error.
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
/// How a signal takes part in multiplexing. An extended multiplexing
/// `m3M` signal is Multiplexed with `multiplexor` set as well.
enum class MuxRole : std::uint8_t { None, Multiplexor, Multiplexed };

/// A range of multiplexor values that selects a signal (SG_MUL_VAL_), both
/// ends included.
struct MuxRange {
  std::uint64_t lo = 0;
  std::uint64_t hi = 0;
  friend bool operator==(const MuxRange&, const MuxRange&) = default;
};

/// Something in the file read with a warning (or a note), with where.
struct Diagnostic {
  enum class Severity : std::uint8_t { Note, Warning };
  Severity severity = Severity::Warning;
  SourcePos where;
  std::string text;
  /// "file:line: warning: text"
  [[nodiscard]] std::string describe() const;
};

struct Signal {
  std::string name;       ///< as written in the DBC (at most 32 characters for Vector's tools)
  std::string long_name;  ///< SystemSignalLongSymbol; empty: none
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
  std::uint64_t mux_value = 0;  ///< for Multiplexed signals: the value written (m3)
  /// Also a multiplexor itself (extended multiplexing, `m3M`).
  bool multiplexor_too = false;
  /// For Multiplexed signals, resolved by the parser: the index in the
  /// message's signals of the multiplexor that selects this one, and the
  /// values that select it (SG_MUL_VAL_, or mux_value alone).
  std::int32_t selector = -1;
  std::vector<MuxRange> selected_by;
  std::map<std::int64_t, std::string> values;  ///< VAL_ table
  std::string comment;
  std::uint32_t line = 0;  ///< where it is defined
  /// False when the signal cannot be decoded; `problem` says why (and a
  /// warning at `line`). Decode gives NaN for it, encode leaves it out.
  bool usable = true;
  std::string problem;

  /// The long name where the file gives one, else the name.
  [[nodiscard]] const std::string& display_name() const {
    return long_name.empty() ? name : long_name;
  }
  /// True for an `M` or `m3M` signal.
  [[nodiscard]] bool is_multiplexor() const {
    return mux == MuxRole::Multiplexor || multiplexor_too;
  }

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
  std::string name;        ///< as written in the DBC
  std::string long_name;   ///< SystemMessageLongSymbol; empty: none
  std::uint32_t size = 0;  ///< payload bytes (DLC in the DBC, up to 64)
  bool fd = false;         ///< CAN FD (size > 8, or VFrameFormat says so)
  std::string transmitter;
  std::vector<Signal> signals;
  std::string comment;
  std::string file;  ///< the DBC file it comes from
  std::uint32_t line = 0;
  /// Its SG_ lines that could not be read (each also a warning): the
  /// message is usable, but no role may be in it.
  std::vector<Diagnostic> unread;

  [[nodiscard]] const std::string& display_name() const {
    return long_name.empty() ? name : long_name;
  }
  /// By the name as written or the long name.
  [[nodiscard]] const Signal* find_signal(std::string_view name) const;
  /// The first multiplexor (`M`) of the message, or nullptr.
  [[nodiscard]] const Signal* multiplexor() const;
  /// True when a payload of this message (`size` bytes) carries signal
  /// `index`: the signal is usable, and each multiplexor of its chain is
  /// carried and holds a value that selects the next.
  [[nodiscard]] bool carries(std::size_t index, std::span<const std::uint8_t> payload) const;
};

struct Database {
  std::string version;
  std::uint32_t version_line = 0;  ///< where VERSION is; 0: none
  std::vector<std::string> nodes;
  std::map<std::string, std::string> node_long_names;  ///< SystemNodeLongSymbol
  std::vector<Message> messages;
  /// What was read with a warning or skipped with a note, in file order.
  std::vector<Diagnostic> warnings;
  /// A message left out (a size no CAN frame has, an ID defined twice).
  struct LeftOut {
    std::string message;  ///< its name as written
    Diagnostic why;       ///< where, and why: a role that names it is refused with this
  };
  std::vector<LeftOut> left_out;

  [[nodiscard]] const Message* find(std::uint32_t id, bool extended) const;
  /// By the name as written or the long name.
  [[nodiscard]] const Message* find(std::string_view name) const;
};

/// Parses DBC text; `file` is used in error and warning positions.
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

/// Decodes frames by ID through a Database (which must outlive it, and is
/// read as it was when the codec was made). Looks an 11-bit ID up in a
/// table, a 29-bit one in a hash map; a frame whose length differs from the
/// message's is counted and skipped, never fatal.
class FrameCodec {
 public:
  explicit FrameCodec(const Database& db);

  /// Message for a frame's ID, or nullptr.
  [[nodiscard]] const Message* message_for(const Frame& frame) const;
  /// Checks the frame against its message; on Ok `*msg` is set.
  DecodeStatus check(const Frame& frame, const Message** msg) const;
  /// Physical values of every signal of the message, in its signal order
  /// (`out` must hold msg->signals.size()). Multiplexed signals not selected
  /// by their multiplexor chain, and unusable signals, are set to NaN.
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
  /// The most signals a message of the database has: what decode's `out`
  /// must hold for every signal of any frame.
  [[nodiscard]] std::size_t max_signals() const { return max_signals_; }

 private:
  /// A signal as decode takes it (where it lies is the signal's own), and
  /// whether one 8-byte load of the frame's data holds it (`direct`), else
  /// the bytewise way.
  struct Slot {
    const Signal* signal;
    std::uint64_t mask;  ///< its `length` low bits
    /// An integer signal's: its sign bit (0: unsigned, or 64 bits long),
    /// factor and offset, beside the rest (raw_to_physical's, the same way)
    std::uint64_t sign;
    double factor, offset;
    bool integer;
    bool unsigned64;     ///< 64 bits, unsigned: no int64 holds it
    std::uint32_t drop;  ///< Motorola: the bits below its bytes after the byte swap
    bool direct;
    bool little_endian;
  };
  /// A message's signals (slots_[first, first + count)); `plain`: each is
  /// usable and none multiplexed, so each is carried in every frame.
  struct Plan {
    std::uint32_t first = 0;
    std::uint32_t count = 0;
    bool plain = false;
  };
  /// The index in db_->messages of the frame's message, or -1.
  [[nodiscard]] std::int32_t index_of(const Frame& frame) const;

  const Database* db_;
  std::unordered_map<std::uint32_t, std::uint32_t> index_;  // key: id | extended << 31
  std::vector<std::int32_t> standard_;                      // by 11-bit id; -1: none
  std::vector<Slot> slots_;
  std::vector<Plan> plans_;  // by message index
  std::size_t max_signals_ = 0;
};

}  // namespace turncal::can
