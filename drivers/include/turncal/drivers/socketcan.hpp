// SocketCAN raw socket, wrapped once (style.md, 8): RAII, errno turned into
// Result at this layer, non-blocking so it fits an event loop.
//
// * receive(): batched (recvmmsg), kernel receive timestamps (SO_TIMESTAMPNS,
//   CLOCK_REALTIME, or taken onto a HostClock given in the options), drops
//   counted from SO_RXQ_OVFL, error frames turned into BusEvents.
// * send(): never blocks; when the kernel queue is full (EAGAIN, ENOBUFS) the
//   frame waits in a bounded queue, and what overflows it is counted. With
//   `confirm`, the kernel's echo of each frame we sent (CAN_RAW_RECV_OWN_MSGS,
//   flagged MSG_CONFIRM) comes back from receive() as a confirmed frame: the
//   frame reached the bus (or, on an interface without IFF_ECHO, the
//   kernel's queue, where the CAN core loops it back when it accepts it).
//   EAGAIN (the socket's send buffer is full) clears when the socket is
//   writable (EPOLLOUT); ENOBUFS (the device or qdisc queue is full, or
//   the controller is bus-off) does not show in poll at all, so a caller
//   retries on a timer (tx_wait()).
// * An interface that goes down is reported (InterfaceDown) and works again
//   when it comes up; one that is removed (InterfaceGone) is re-opened by
//   try_recover() once it exists again, without restarting the process.
#pragma once

#include <cerrno>
#include <cstdint>
#include <deque>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "turncal/can/bus_event.hpp"
#include "turncal/can/frame.hpp"
#include "turncal/drivers/host_clock.hpp"
#include "turncal/result.hpp"

namespace turncal::socketcan {

struct Filter {
  std::uint32_t id = 0;
  bool extended = false;
  std::uint32_t mask = 0;  ///< 0: exact match on id and frame format
};

struct Options {
  std::string interface;
  bool fd = false;              ///< also receive and send CAN FD frames
  std::vector<Filter> filters;  ///< empty: every frame
  bool error_frames = true;     ///< receive error frames (as BusEvents)
  bool receive_own = false;     ///< see our own sent frames
  /// The echoes of our own frames come back as RxBatch::confirmed (implies
  /// CAN_RAW_RECV_OWN_MSGS; they are not counted as received).
  bool confirm = false;
  std::size_t tx_queue_limit = 256;  ///< frames waiting for the kernel queue
  int rcvbuf_bytes = 0;              ///< SO_RCVBUF; 0: kernel default
  /// Receive stamps and event times on this clock (it must outlive the
  /// socket); none: the kernel's CLOCK_REALTIME stamps as they are.
  HostClock* clock = nullptr;
  /// Open (and re-open, after the interface was removed) only a virtual
  /// CAN bus (require_virtual_can): a simulator's socket, which must never bind
  /// a real bus that took the name of its vcan.
  bool require_virtual = false;
};

struct Stats {
  std::uint64_t rx_frames = 0;
  std::uint64_t rx_dropped = 0;  ///< lost in the kernel (socket queue overflow)
  std::uint64_t rx_error_frames = 0;
  std::uint64_t tx_frames = 0;      ///< handed to the kernel
  std::uint64_t tx_confirmed = 0;   ///< echoed back by the kernel (with `confirm`)
  std::uint64_t tx_queued = 0;      ///< had to wait in the send queue
  std::uint64_t tx_overflow = 0;    ///< dropped because the send queue was full
  std::uint64_t tx_failed = 0;      ///< dropped because the interface was down or gone
  std::uint64_t tx_superseded = 0;  ///< waiting frames an urgent one of their ID replaced
  std::uint64_t recoveries = 0;     ///< times the socket was re-opened
};

/// Frames and events of one receive call.
struct RxBatch {
  std::vector<can::TimedFrame> frames;
  std::vector<can::BusEvent> events;
  std::vector<can::TimedFrame> confirmed;  ///< our own frames, echoed (Options::confirm)
  /// The frames of both lists in the order the socket held them: true for
  /// the next of `confirmed`, false for the next of `frames`. A SYNC's echo
  /// read before the TPDOs that answer it must also be used before them.
  std::vector<bool> echoed;
  void clear() {
    frames.clear();
    events.clear();
    confirmed.clear();
    echoed.clear();
  }
  /// Calls f(frame, echoed) for every frame, in the order read.
  template <class F>
  void in_order(F&& f) const {
    std::size_t r = 0;
    std::size_t c = 0;
    for (const bool e : echoed) f(e ? confirmed.at(c++) : frames.at(r++), e);
  }
};

/// What became of a frame given to send().
enum class TxOutcome : std::uint8_t {
  Sent,     ///< the kernel took it
  Queued,   ///< it waits in the send queue (flush() retries)
  Dropped,  ///< lost: the send queue was full, or the interface is down or gone
};

/// What a caller waits for before flush() can make progress.
enum class TxWait : std::uint8_t {
  None,      ///< nothing queued
  Writable,  ///< the socket's buffer was full (EAGAIN): poll for EPOLLOUT
  Retry,     ///< the device queue was full (ENOBUFS): retry after a while
};

enum class LinkState : std::uint8_t { Up, Down, Gone };

class Socket {
 public:
  static Result<Socket> open(Options options);
  Socket(Socket&& other) noexcept;
  Socket& operator=(Socket&& other) noexcept;
  Socket(const Socket&) = delete;
  Socket& operator=(const Socket&) = delete;
  ~Socket();

  /// Descriptor to poll for input (and for output while tx_pending()); -1
  /// while the interface is gone. It changes when the socket is re-opened.
  [[nodiscard]] int fd() const { return fd_; }
  [[nodiscard]] const std::string& interface() const { return opt_.interface; }
  [[nodiscard]] LinkState link() const { return link_; }
  [[nodiscard]] const Stats& stats() const { return stats_; }
  [[nodiscard]] bool tx_pending() const { return !txq_.empty(); }
  [[nodiscard]] std::size_t tx_queue_depth() const { return txq_.size(); }
  [[nodiscard]] TxWait tx_wait() const {
    return txq_.empty() ? TxWait::None : busy_errno_ == ENOBUFS ? TxWait::Retry : TxWait::Writable;
  }

  /// Frames one recvmmsg call takes.
  static constexpr std::size_t kBatchFrames = 64;
  /// Reads up to `max_batches` x kBatchFrames frames without blocking,
  /// appending to `out`; stops at the first short batch (the socket is then
  /// drained). Returns the number of frames read; link changes come as events.
  Result<std::size_t> receive(RxBatch& out, std::size_t max_batches = 4);
  /// Whether the last receive() took all the socket had (it ended on a
  /// short batch), rather than stopping at max_batches.
  [[nodiscard]] bool drained() const { return drained_; }
  /// Sends without blocking; queues when the kernel is full. An error only
  /// for a frame the socket cannot carry (FD frame on a classic socket).
  Result<TxOutcome> send(const can::Frame& frame);
  /// A frame that must go before anything waiting (a quick stop): the
  /// frames of its ID still waiting are dropped (counted superseded: a
  /// move queued before a stop must never follow it), it is written at
  /// once if the kernel takes it, else it waits first in the queue; a full
  /// queue loses its newest frame for it, never it.
  Result<TxOutcome> send_urgent(const can::Frame& frame);
  /// Retries queued frames; returns how many are still waiting.
  std::size_t flush();
  /// While the link is Down or Gone: checks the interface and re-opens the
  /// socket when it is usable again (an InterfaceBack event is appended).
  /// Returns true when the link is Up.
  bool try_recover(RxBatch& out);

 private:
  explicit Socket(Options options) : opt_(std::move(options)) {}
  Status open_socket();
  void close_socket();
  enum class TxResult { Sent, Busy, Failed };
  TxResult write_frame(const can::Frame& frame);
  Status sendable(const can::Frame& frame) const;
  /// Writes the frame and counts it sent or failed; nothing when the kernel
  /// is busy (the caller queues it).
  std::optional<TxOutcome> write_now(const can::Frame& frame);
  void link_event(RxBatch& out, can::BusEventKind kind);

  Options opt_;
  int fd_ = -1;
  LinkState link_ = LinkState::Up;
  /// A write found the interface down (ENETDOWN): a write takes the
  /// socket's pending NETDEV_DOWN error before a receive can, so the next
  /// receive reports the loss instead.
  bool down_on_write_ = false;
  unsigned ifindex_ = 0;
  std::uint32_t last_ovfl_ = 0;
  bool drained_ = true;
  std::deque<can::Frame> txq_;
  Stats stats_;
  int busy_errno_ = 0;  ///< why the last write could not go: EAGAIN or ENOBUFS
};

/// CLOCK_REALTIME now, ns since the Unix epoch (the clock of the kernel
/// receive timestamps).
std::int64_t realtime_ns();

/// The kind of a network interface as rtnetlink gives it (IFLA_INFO_KIND:
/// "vcan", "vxcan", "can" for a real controller's CAN device (USB, PCI,
/// SPI), ...); empty for a driver that registers no link kind (slcan, lo).
Result<std::string> link_kind(const std::string& interface);
/// The same for the interface of that index (the name only for messages):
/// an answer for another index is an error.
Result<std::string> link_kind(const std::string& interface, unsigned index);
/// The link kind in rtnetlink's answer to RTM_GETLINK for `interface` (the
/// bytes one recv took): the first RTM_NEWLINK's IFLA_LINKINFO /
/// IFLA_INFO_KIND, empty when it has none. An NLMSG_ERROR's errno, an
/// answer cut short or malformed anywhere it is read, one for an index
/// other than `index` (unless 0), or none, is an error.
Result<std::string> link_kind_of_answer(std::span<const char> answer, const std::string& interface,
                                        unsigned index = 0);
/// Whether a link kind is a virtual CAN bus's (vcan, vxcan): a bus no real
/// device is on.
bool is_virtual_kind(std::string_view kind);
/// Succeeds for a virtual CAN bus; otherwise says what the interface is (its
/// kind, a device's interface, or that its kind cannot be read: counted as
/// real). With `index`, the interface of that index (what a socket binds).
Status require_virtual_can(const std::string& interface, unsigned index = 0);

}  // namespace turncal::socketcan
