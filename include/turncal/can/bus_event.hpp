// Events of the bus and the interface: what an error frame says, and what
// the driver saw of the interface. Pure.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "turncal/can/frame.hpp"

namespace turncal::can {

enum class BusEventKind : std::uint8_t {
  TxTimeout,           ///< CAN_ERR_TX_TIMEOUT
  LostArbitration,     ///< CAN_ERR_LOSTARB
  ControllerProblem,   ///< CAN_ERR_CRTL: see `detail` (CAN_ERR_CRTL_* bits)
  ProtocolViolation,   ///< CAN_ERR_PROT
  TransceiverProblem,  ///< CAN_ERR_TRX
  NoAck,               ///< CAN_ERR_ACK
  BusOff,              ///< CAN_ERR_BUSOFF
  BusError,            ///< CAN_ERR_BUSERROR
  Restarted,           ///< CAN_ERR_RESTARTED: controller restarted after bus-off
  InterfaceDown,       ///< the interface went down (ENETDOWN)
  InterfaceGone,       ///< the interface was removed (ENODEV)
  InterfaceBack,       ///< the interface is usable again
};

struct BusEvent {
  std::int64_t time_ns = 0;
  BusEventKind kind = BusEventKind::BusError;
  std::uint8_t detail = 0;  ///< controller status bits for ControllerProblem
};

/// Name of an event kind ("bus-off", "controller problem", ...).
const char* to_string(BusEventKind kind);
/// One line for a log: kind and, for controller problems, the status bits.
std::string describe(const BusEvent& event);
/// The events an error frame carries (empty for a data frame or an error
/// frame with no class bits this decoder knows).
std::vector<BusEvent> decode_error_frame(const TimedFrame& frame);

}  // namespace turncal::can
