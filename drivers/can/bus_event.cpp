#include "turncal/can/bus_event.hpp"

namespace turncal::can {
namespace {
// Error classes of <linux/can/error.h>, restated so the pure layer needs no
// kernel header.
constexpr std::uint32_t kErrClasses[] = {0x001, 0x002, 0x004, 0x008, 0x010,
                                         0x020, 0x040, 0x080, 0x100};
constexpr BusEventKind kErrKinds[] = {BusEventKind::TxTimeout,
                                      BusEventKind::LostArbitration,
                                      BusEventKind::ControllerProblem,
                                      BusEventKind::ProtocolViolation,
                                      BusEventKind::TransceiverProblem,
                                      BusEventKind::NoAck,
                                      BusEventKind::BusOff,
                                      BusEventKind::BusError,
                                      BusEventKind::Restarted};
}  // namespace

const char* to_string(BusEventKind kind) {
  switch (kind) {
    case BusEventKind::TxTimeout:
      return "tx timeout";
    case BusEventKind::LostArbitration:
      return "lost arbitration";
    case BusEventKind::ControllerProblem:
      return "controller problem";
    case BusEventKind::ProtocolViolation:
      return "protocol violation";
    case BusEventKind::TransceiverProblem:
      return "transceiver problem";
    case BusEventKind::NoAck:
      return "no ack";
    case BusEventKind::BusOff:
      return "bus-off";
    case BusEventKind::BusError:
      return "bus error";
    case BusEventKind::Restarted:
      return "controller restarted";
    case BusEventKind::InterfaceDown:
      return "interface down";
    case BusEventKind::InterfaceGone:
      return "interface removed";
    case BusEventKind::InterfaceBack:
      return "interface back";
  }
  return "unknown";
}

std::string describe(const BusEvent& e) {
  std::string s = to_string(e.kind);
  if (e.kind == BusEventKind::ControllerProblem) {
    static constexpr const char* kBits[] = {"rx overflow",         "tx overflow", "rx warning",
                                            "tx warning",          "rx passive",  "tx passive",
                                            "back to error active"};
    std::string bits;
    for (unsigned b = 0; b < 7; ++b)
      if ((e.detail >> b) & 1u) bits += (bits.empty() ? "" : ", ") + std::string(kBits[b]);
    if (!bits.empty()) s += " (" + bits + ")";
  }
  return s;
}

std::vector<BusEvent> decode_error_frame(const TimedFrame& tf) {
  std::vector<BusEvent> out;
  if (!tf.frame.error) return out;
  for (std::size_t i = 0; i < std::size(kErrClasses); ++i) {
    if ((tf.frame.id & kErrClasses[i]) == 0) continue;
    BusEvent e{tf.time_ns, kErrKinds[i], 0};
    if (e.kind == BusEventKind::ControllerProblem && tf.frame.len > 1) e.detail = tf.frame.data[1];
    out.push_back(e);
  }
  return out;
}

}  // namespace turncal::can
