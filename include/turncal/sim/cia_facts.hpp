// What the virtual CiA 402 drive knows of CANopen, written from the
// standards alone: CiA 301 (v4.2.0) for the communication objects and
// services, CiA 402 (IEC 61800-7-201) for the drive profile. It is the
// drive's own copy, on purpose: the drive is the test double of the
// master in drivers/table, and shares none of its headers or tables, so
// an assumption the master makes is one this drive can contradict
// (tests/unit/check-layers keeps it so).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "turncal/can/frame.hpp"

namespace turncal::stand::facts {

// ---- CiA 301 7.3.5: the pre-defined connection set (11-bit COB-IDs) ----
namespace cob {
constexpr std::uint32_t kNmt = 0x000;
constexpr std::uint32_t kSync = 0x080;  // 0x1005's default
constexpr std::uint32_t kEmcy = 0x080;  // + node ID
constexpr std::uint32_t kTpdo1 = 0x180;
constexpr std::uint32_t kRpdo1 = 0x200;
constexpr std::uint32_t kTpdo2 = 0x280;
constexpr std::uint32_t kSdoTx = 0x580;      // server to client, + node ID
constexpr std::uint32_t kSdoRx = 0x600;      // client to server, + node ID
constexpr std::uint32_t kHeartbeat = 0x700;  // NMT error control, + node ID
/// 0x14xx/0x18xx sub 1, bit 31: the PDO does not exist (is not valid).
constexpr std::uint32_t kPdoInvalid = 0x80000000u;
constexpr std::uint32_t kIdMask = 0x7FF;
}  // namespace cob

// ---- CiA 301 7.2.8.3: NMT ----
/// The state byte of a heartbeat (7.2.8.3.2.2); 0 is the boot-up.
enum class Nmt : std::uint8_t {
  BootUp = 0x00,
  Stopped = 0x04,
  Operational = 0x05,
  PreOperational = 0x7F,
};
/// The NMT command specifiers (7.2.8.3.1).
namespace nmt {
constexpr std::uint8_t kStart = 0x01;
constexpr std::uint8_t kStop = 0x02;
constexpr std::uint8_t kEnterPreOperational = 0x80;
constexpr std::uint8_t kResetNode = 0x81;
constexpr std::uint8_t kResetCommunication = 0x82;
}  // namespace nmt
[[nodiscard]] constexpr std::string_view nmt_name(Nmt s) {
  switch (s) {
    case Nmt::BootUp:
      return "boot-up";
    case Nmt::Stopped:
      return "stopped";
    case Nmt::Operational:
      return "operational";
    case Nmt::PreOperational:
      return "pre-operational";
  }
  return "unknown";
}

// ---- CiA 301 7.2.4.3.17, table 22: SDO abort codes ----
namespace abort {
constexpr std::uint32_t kToggle = 0x05030000;            // toggle bit not alternated
constexpr std::uint32_t kCommandSpecifier = 0x05040001;  // command specifier not valid
constexpr std::uint32_t kUnsupportedAccess = 0x06010000;
constexpr std::uint32_t kReadOnly = 0x06010002;  // attempt to write a read only object
constexpr std::uint32_t kNoObject = 0x06020000;  // object does not exist in the dictionary
constexpr std::uint32_t kNotMappable = 0x06040041;
constexpr std::uint32_t kPdoLength = 0x06040042;  // the mapping exceeds the PDO length
constexpr std::uint32_t kLength = 0x06070010;     // length of service parameter does not match
constexpr std::uint32_t kLengthHigh = 0x06070012;
constexpr std::uint32_t kLengthLow = 0x06070013;
constexpr std::uint32_t kNoSubindex = 0x06090011;
constexpr std::uint32_t kValueRange = 0x06090030;  // invalid value (download only)
constexpr std::uint32_t kValueHigh = 0x06090031;
constexpr std::uint32_t kValueLow = 0x06090032;
constexpr std::uint32_t kDeviceState = 0x08000022;  // not transferred: the device's state
}  // namespace abort

// ---- the objects the drive has (CiA 301 7.5, CiA 402 clause 6 and on) ----
namespace od {
constexpr std::uint16_t kDeviceType = 0x1000;
constexpr std::uint16_t kErrorRegister = 0x1001;
constexpr std::uint16_t kDeviceName = 0x1008;
constexpr std::uint16_t kSoftwareVersion = 0x100A;
constexpr std::uint16_t kConsumerHeartbeat = 0x1016;
constexpr std::uint16_t kProducerHeartbeat = 0x1017;
constexpr std::uint16_t kIdentity = 0x1018;
constexpr std::uint16_t kRpdo1Comm = 0x1400;
constexpr std::uint16_t kRpdo1Map = 0x1600;
constexpr std::uint16_t kTpdo1Comm = 0x1800;
constexpr std::uint16_t kTpdo2Comm = 0x1801;
constexpr std::uint16_t kTpdo1Map = 0x1A00;
constexpr std::uint16_t kTpdo2Map = 0x1A01;
constexpr std::uint16_t kLabel = 0x2001;  // manufacturer's: a stand label, a string
constexpr std::uint16_t kAbortConnectionOption = 0x6007;
constexpr std::uint16_t kErrorCode = 0x603F;
constexpr std::uint16_t kControlword = 0x6040;
constexpr std::uint16_t kStatusword = 0x6041;
constexpr std::uint16_t kQuickStopOption = 0x605A;
constexpr std::uint16_t kShutdownOption = 0x605B;
constexpr std::uint16_t kDisableOperationOption = 0x605C;
constexpr std::uint16_t kModesOfOperation = 0x6060;
constexpr std::uint16_t kModesDisplay = 0x6061;
constexpr std::uint16_t kPositionActual = 0x6064;
constexpr std::uint16_t kVelocityActual = 0x606C;
constexpr std::uint16_t kTargetPosition = 0x607A;
constexpr std::uint16_t kMaxProfileVelocity = 0x607F;
constexpr std::uint16_t kProfileVelocity = 0x6081;
constexpr std::uint16_t kProfileAcceleration = 0x6083;
constexpr std::uint16_t kProfileDeceleration = 0x6084;
constexpr std::uint16_t kQuickStopDeceleration = 0x6085;
constexpr std::uint16_t kPositioningOption = 0x60F2;
/// 0x1000: device profile 402 (low word), servo drive (type 0x0002, 6.3.1)
constexpr std::uint32_t kServoDrive402 = 0x00020192;
/// 0x6060/0x6061: profile position mode
constexpr std::int8_t kProfilePosition = 1;
}  // namespace od

// ---- CiA 402 6.2.1: the statusword (0x6041) ----
namespace sw {
constexpr std::uint16_t kVoltageEnabled = 1u << 4;
constexpr std::uint16_t kWarning = 1u << 7;
constexpr std::uint16_t kRemote = 1u << 9;
constexpr std::uint16_t kTargetReached = 1u << 10;
constexpr std::uint16_t kSetPointAcknowledge = 1u << 12;  // profile position
constexpr std::uint16_t kFollowingError = 1u << 13;       // profile position
}  // namespace sw

// ---- CiA 402 6.2.1: the controlword (0x6040) ----
namespace cw {
constexpr std::uint16_t kSwitchOn = 1u << 0;
constexpr std::uint16_t kEnableVoltage = 1u << 1;
constexpr std::uint16_t kQuickStop = 1u << 2;  // active low
constexpr std::uint16_t kEnableOperation = 1u << 3;
constexpr std::uint16_t kNewSetPoint = 1u << 4;        // profile position
constexpr std::uint16_t kChangeImmediately = 1u << 5;  // profile position
constexpr std::uint16_t kRelative = 1u << 6;           // profile position
constexpr std::uint16_t kFaultReset = 1u << 7;
constexpr std::uint16_t kHalt = 1u << 8;
}  // namespace cw

/// The power drive system's states (CiA 402 figure 6, "state machine").
enum class State : std::uint8_t {
  NotReadyToSwitchOn,
  SwitchOnDisabled,
  ReadyToSwitchOn,
  SwitchedOn,
  OperationEnabled,
  QuickStopActive,
  FaultReactionActive,
  Fault,
};

[[nodiscard]] constexpr std::string_view state_name(State s) {
  switch (s) {
    case State::NotReadyToSwitchOn:
      return "not ready to switch on";
    case State::SwitchOnDisabled:
      return "switch on disabled";
    case State::ReadyToSwitchOn:
      return "ready to switch on";
    case State::SwitchedOn:
      return "switched on";
    case State::OperationEnabled:
      return "operation enabled";
    case State::QuickStopActive:
      return "quick stop active";
    case State::FaultReactionActive:
      return "fault reaction active";
    case State::Fault:
      return "fault";
  }
  return "unknown";
}

/// The statusword's bits 0-3, 5 and 6 in each state (CiA 402 table 30).
[[nodiscard]] constexpr std::uint16_t state_bits(State s) {
  switch (s) {
    case State::NotReadyToSwitchOn:
      return 0x0000;  // xxxx xxxx x0xx 0000
    case State::SwitchOnDisabled:
      return 0x0040;  // x1xx 0000
    case State::ReadyToSwitchOn:
      return 0x0021;  // x01x 0001
    case State::SwitchedOn:
      return 0x0023;  // x01x 0011
    case State::OperationEnabled:
      return 0x0027;  // x01x 0111
    case State::QuickStopActive:
      return 0x0007;  // x00x 0111
    case State::FaultReactionActive:
      return 0x000F;  // x0xx 1111
    case State::Fault:
      return 0x0008;  // x0xx 1000
  }
  return 0;
}

/// The device control commands (CiA 402 table 28).
enum class Command : std::uint8_t {
  None,
  Shutdown,         ///< 0xxx x110: transitions 2, 6, 8
  SwitchOn,         ///< 0xxx 0111: 3; as disable operation, 5
  EnableOperation,  ///< 0xxx 1111: 3 + 4, 4, 16
  DisableVoltage,   ///< 0xxx xx0x: 7, 9, 10, 12
  QuickStop,        ///< 0xxx x01x: 7, 10, 11
  FaultReset,       ///< bit 7's rising edge: 15
};

/// The command a controlword gives after `previous`. Bit 7 high without
/// its edge is no command (the table's commands all have it low).
[[nodiscard]] constexpr Command command_of(std::uint16_t c, std::uint16_t previous) {
  if ((c & cw::kFaultReset) != 0)
    return (previous & cw::kFaultReset) == 0 ? Command::FaultReset : Command::None;
  if ((c & cw::kEnableVoltage) == 0) return Command::DisableVoltage;
  if ((c & cw::kQuickStop) == 0) return Command::QuickStop;
  if ((c & cw::kSwitchOn) == 0) return Command::Shutdown;
  return (c & cw::kEnableOperation) != 0 ? Command::EnableOperation : Command::SwitchOn;
}

// ---- the byte order of CANopen (CiA 301 7.1.1: little-endian) ----
[[nodiscard]] inline std::uint64_t get_le(const std::uint8_t* p, std::size_t n) {
  std::uint64_t v = 0;
  for (std::size_t i = 0; i < n; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
  return v;
}
template <typename Bytes>
[[nodiscard]] std::uint64_t get_le(const Bytes& b, std::size_t at, std::size_t n) {
  return get_le(b.data() + at, n);
}
template <typename Bytes>
void put_le(Bytes& b, std::size_t at, std::size_t n, std::uint64_t v) {
  for (std::size_t i = 0; i < n; ++i) b[at + i] = static_cast<std::uint8_t>(v >> (8 * i));
}
[[nodiscard]] inline std::vector<std::uint8_t> le_bytes(std::uint64_t v, std::size_t n) {
  std::vector<std::uint8_t> b(n);
  put_le(b, 0, n, v);
  return b;
}

// ---- frames ----
/// A standard frame of the drive's, of `len` bytes.
[[nodiscard]] inline can::Frame frame(std::uint32_t id, std::uint8_t len) {
  can::Frame f;
  f.id = id;
  f.len = len;
  return f;
}
/// Heartbeat (or boot-up, state 0): one byte, CiA 301 7.2.8.3.2.2.
[[nodiscard]] inline can::Frame heartbeat(std::uint8_t node, Nmt s) {
  can::Frame f = frame(cob::kHeartbeat + node, 1);
  f.data[0] = static_cast<std::uint8_t>(s);
  return f;
}
/// EMCY: error code, error register (0x1001), five bytes the
/// manufacturer's (here zero); CiA 301 7.2.7.3.1.
[[nodiscard]] inline can::Frame emcy(std::uint8_t node, std::uint16_t code, std::uint8_t reg) {
  can::Frame f = frame(cob::kEmcy + node, 8);
  put_le(f.data, 0, 2, code);
  f.data[2] = reg;
  return f;
}
/// A classic frame on the SYNC's COB-ID; a SYNC has no data, or one byte
/// of counter (CiA 301 7.2.5.3.1): any other length is no SYNC.
[[nodiscard]] inline bool on_sync_id(const can::Frame& f) {
  return f.id == cob::kSync && !f.extended && !f.remote && !f.error && !f.fd;
}
[[nodiscard]] inline bool is_sync(const can::Frame& f) {
  return on_sync_id(f) && f.len <= 1;
}

}  // namespace turncal::stand::facts
