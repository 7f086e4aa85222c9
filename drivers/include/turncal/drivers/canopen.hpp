// CANopen (CiA 301) pieces a master needs, pure: identifiers of the
// predefined connection set, NMT and heartbeat frames, the SDO client
// (expedited and segmented, download and upload, one transfer at a time,
// queued, its timeout driven by tick(now_s)), SDO abort codes and EMCY
// error codes decoded to text. Frames in, frames out, time injected in
// seconds: no sockets, no clocks here.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "turncal/can/frame.hpp"
#include "turncal/result.hpp"

namespace turncal::canopen {

// ---- the predefined connection set (CiA 301, 7.3.5) ----
inline constexpr std::uint32_t kNmtId = 0x000;
inline constexpr std::uint32_t kSyncId = 0x080;
inline constexpr std::uint32_t kEmcyBase = 0x080;
inline constexpr std::uint32_t kTpdo1Base = 0x180;
inline constexpr std::uint32_t kRpdo1Base = 0x200;
inline constexpr std::uint32_t kTpdo2Base = 0x280;
inline constexpr std::uint32_t kSdoTxBase = 0x580;  ///< server to client
inline constexpr std::uint32_t kSdoRxBase = 0x600;  ///< client to server
inline constexpr std::uint32_t kHeartbeatBase = 0x700;

/// A node id is 1..127.
[[nodiscard]] constexpr bool valid_node(std::uint8_t node) {
  return node >= 1 && node <= 127;
}

/// NMT command specifiers (byte 0 of the NMT frame).
enum class NmtCommand : std::uint8_t {
  Start = 0x01,
  Stop = 0x02,
  EnterPreOperational = 0x80,
  ResetNode = 0x81,
  ResetCommunication = 0x82,
};
/// NMT states as a heartbeat carries them.
enum class NmtState : std::uint8_t {
  BootUp = 0x00,
  Stopped = 0x04,
  Operational = 0x05,
  PreOperational = 0x7F,
};
const char* to_string(NmtState s);

[[nodiscard]] can::Frame nmt_frame(NmtCommand cmd, std::uint8_t node);
[[nodiscard]] can::Frame heartbeat_frame(std::uint8_t node, NmtState state);
[[nodiscard]] can::Frame sync_frame();
/// A frame on SYNC's identifier: a classic data frame, base format, id 0x080.
/// Its length is the receiver's to judge (is_sync).
[[nodiscard]] constexpr bool on_sync_id(const can::Frame& f) {
  return f.id == kSyncId && !f.extended && !f.remote && !f.fd && !f.error;
}
/// A SYNC as CiA 301 defines it: no data, or one byte of counter.
[[nodiscard]] constexpr bool is_sync(const can::Frame& f) {
  return on_sync_id(f) && f.len <= 1;
}

// ---- little-endian helpers ----
[[nodiscard]] std::uint32_t get_le(std::span<const std::uint8_t> b, std::size_t off,
                                   std::size_t len);
void put_le(std::span<std::uint8_t> b, std::size_t off, std::size_t len, std::uint64_t v);
[[nodiscard]] std::vector<std::uint8_t> le_bytes(std::uint64_t v, std::size_t len);

// ---- SDO abort codes (CiA 301, table 22) ----
namespace abort_code {
inline constexpr std::uint32_t kToggle = 0x05030000;
inline constexpr std::uint32_t kTimeout = 0x05040000;
inline constexpr std::uint32_t kCommandSpecifier = 0x05040001;
inline constexpr std::uint32_t kUnsupportedAccess = 0x06010000;
inline constexpr std::uint32_t kWriteOnly = 0x06010001;
inline constexpr std::uint32_t kReadOnly = 0x06010002;
inline constexpr std::uint32_t kNoObject = 0x06020000;
inline constexpr std::uint32_t kNotMappable = 0x06040041;
inline constexpr std::uint32_t kPdoLength = 0x06040042;
inline constexpr std::uint32_t kLength = 0x06070010;
inline constexpr std::uint32_t kLengthHigh = 0x06070012;
inline constexpr std::uint32_t kLengthLow = 0x06070013;
inline constexpr std::uint32_t kNoSubindex = 0x06090011;
inline constexpr std::uint32_t kValueRange = 0x06090030;
inline constexpr std::uint32_t kValueHigh = 0x06090031;
inline constexpr std::uint32_t kValueLow = 0x06090032;
inline constexpr std::uint32_t kGeneral = 0x08000000;
inline constexpr std::uint32_t kDeviceState = 0x08000022;
}  // namespace abort_code

/// The standard's text for an abort code, or nullptr for one it does not list.
[[nodiscard]] const char* sdo_abort_text(std::uint32_t code);
/// "0x06020000 object does not exist in the object dictionary" (unknown:
/// "0x12345678 unknown abort code").
[[nodiscard]] std::string describe_sdo_abort(std::uint32_t code);

// ---- EMCY (CiA 301 7.2.7, error codes of CiA 301 and CiA 402) ----
struct Emcy {
  double t_s = 0;              ///< receive time
  std::uint16_t code = 0;      ///< emergency error code; 0x0000: error reset or no error
  std::uint8_t register_ = 0;  ///< error register (0x1001)
  std::array<std::uint8_t, 5> manufacturer{};
  std::string text;  ///< emcy_text(code)
};
/// The standard's name for an emergency error code, or nullptr.
[[nodiscard]] const char* emcy_code_text(std::uint16_t code);
/// "EMCY 0x2310 continuous over-current (device output side)"; an unknown
/// code: "EMCY 0x2345".
[[nodiscard]] std::string emcy_text(std::uint16_t code);
/// Decodes an EMCY frame (8 data bytes); a frame of another length is an error.
[[nodiscard]] Result<Emcy> decode_emcy(const can::Frame& f, double t_s);
[[nodiscard]] can::Frame emcy_frame(std::uint8_t node, std::uint16_t code, std::uint8_t reg,
                                    std::array<std::uint8_t, 5> manufacturer = {});

// ---- SDO client ----

/// How a transfer ended.
struct SdoResult {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool upload = false;
  /// 0: done; else the abort code, ours (timeout, bad response) or the server's.
  std::uint32_t abort = 0;
  bool aborted_by_server = false;
  std::vector<std::uint8_t> data;  ///< what an upload read
  [[nodiscard]] bool ok() const { return abort == 0; }
  /// "write 0x6083:00: 0x06090030 invalid value for parameter (download only)
  /// (aborted by the drive)"
  [[nodiscard]] std::string describe() const;
};

/// Frames the client could not use, counted and skipped.
struct SdoCounts {
  std::uint64_t malformed = 0;   ///< wrong length
  std::uint64_t unexpected = 0;  ///< a response while no transfer was under way, or another's
  /// Of them, initiate responses for another object than the transfer's:
  /// late answers to a transfer already ended.
  std::uint64_t late = 0;
  std::uint64_t timeouts = 0;
  std::uint64_t aborts_sent = 0;
  std::uint64_t aborts_received = 0;
};

/// One SDO client for one server node: transfers run one at a time, in the
/// order they were asked for; each completes (done, aborted or timed out)
/// through its callback, called from on_frame or tick. A callback may queue
/// further transfers.
class SdoClient {
 public:
  using Callback = std::function<void(const SdoResult&)>;
  SdoClient(std::uint8_t node, double timeout_s) : node_(node), timeout_s_(timeout_s) {}

  void download(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                Callback done);
  void upload(std::uint16_t index, std::uint8_t sub, Callback done);
  /// A download that goes next, before those queued (behind the one under
  /// way and any urgent one queued earlier), and that fail_queued() leaves
  /// queued: a quick stop written while a configuration fills the queue.
  void download_urgent(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                       Callback done);
  /// Starts the next queued transfer if none is under way and times out the
  /// one under way; frames to send go to `out`.
  void tick(double now_s, std::vector<can::Frame>& out);
  /// The caller's loop was held from from_s to to_s: the transfer under way
  /// does not count that time against its timeout.
  void held(double from_s, double to_s);
  /// A frame from the bus; false when it is not this server's SDO response.
  bool on_frame(const can::Frame& f, double now_s, std::vector<can::Frame>& out);
  /// Ends every queued transfer and the one under way (aborted on the bus
  /// with `code`); each callback gets `code`, none is lost.
  void cancel_all(std::vector<can::Frame>& out, std::uint32_t code = abort_code::kGeneral);
  /// Ends the queued transfers but urgent ones, not the one under way (safe
  /// in a callback): each callback gets `code`, none is lost; a callback may
  /// queue anew.
  void fail_queued(std::uint32_t code = abort_code::kGeneral);
  [[nodiscard]] bool idle() const { return !active_ && queue_.empty(); }
  [[nodiscard]] std::size_t pending() const { return queue_.size() + (active_ ? 1 : 0); }
  [[nodiscard]] const SdoCounts& counts() const { return counts_; }
  void set_node(std::uint8_t node) { node_ = node; }

 private:
  struct Transfer {
    std::uint16_t index;
    std::uint8_t sub;
    bool upload;
    std::vector<std::uint8_t> data;  // download: to send; upload: received
    Callback done;
    std::size_t offset = 0;      // bytes sent (download)
    std::uint32_t expected = 0;  // upload: size the server indicated; 0: none
    bool size_known = false;
    bool segmented = false;
    bool toggle = false;
    bool initiated = false;
    double deadline = 0;
    bool urgent = false;
  };
  void start(double now_s, std::vector<can::Frame>& out);
  void send_segment(std::vector<can::Frame>& out);
  void finish(std::uint32_t code, bool by_server, double now_s, std::vector<can::Frame>& out);
  void abort_active(std::uint32_t code, double now_s, std::vector<can::Frame>& out);
  [[nodiscard]] can::Frame request() const;

  std::uint8_t node_;
  double timeout_s_;
  std::deque<Transfer> queue_;
  std::optional<Transfer> active_;
  SdoCounts counts_;
};

}  // namespace turncal::canopen
