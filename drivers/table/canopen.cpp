#include "turncal/drivers/canopen.hpp"

#include <algorithm>
#include <cstdio>
#include <utility>

namespace turncal::canopen {

namespace {

std::string hex(std::uint32_t v, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", digits, v);
  return buf;
}

can::Frame data_frame(std::uint32_t id, std::uint8_t len) {
  can::Frame f;
  f.id = id;
  f.len = len;
  return f;
}

/// An upload larger than this is refused (our own abort, out of memory).
constexpr std::size_t kMaxUpload = 65536;

}  // namespace

const char* to_string(NmtState s) {
  switch (s) {
    case NmtState::BootUp:
      return "boot-up";
    case NmtState::Stopped:
      return "stopped";
    case NmtState::Operational:
      return "operational";
    case NmtState::PreOperational:
      return "pre-operational";
  }
  return "unknown";
}

can::Frame nmt_frame(NmtCommand cmd, std::uint8_t node) {
  can::Frame f = data_frame(kNmtId, 2);
  f.data[0] = static_cast<std::uint8_t>(cmd);
  f.data[1] = node;
  return f;
}

can::Frame heartbeat_frame(std::uint8_t node, NmtState state) {
  can::Frame f = data_frame(kHeartbeatBase + node, 1);
  f.data[0] = static_cast<std::uint8_t>(state);
  return f;
}

can::Frame sync_frame() {
  return data_frame(kSyncId, 0);
}

std::uint32_t get_le(std::span<const std::uint8_t> b, std::size_t off, std::size_t len) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < len && i < 4; ++i)
    v |= static_cast<std::uint32_t>(b[off + i]) << (8 * i);
  return v;
}

void put_le(std::span<std::uint8_t> b, std::size_t off, std::size_t len, std::uint64_t v) {
  for (std::size_t i = 0; i < len; ++i) b[off + i] = static_cast<std::uint8_t>(v >> (8 * i));
}

std::vector<std::uint8_t> le_bytes(std::uint64_t v, std::size_t len) {
  std::vector<std::uint8_t> out(len);
  put_le(out, 0, len, v);
  return out;
}

const char* sdo_abort_text(std::uint32_t code) {
  switch (code) {
    case 0x05030000:
      return "toggle bit not alternated";
    case 0x05040000:
      return "SDO protocol timed out";
    case 0x05040001:
      return "client/server command specifier not valid or unknown";
    case 0x05040002:
      return "invalid block size";
    case 0x05040003:
      return "invalid sequence number";
    case 0x05040004:
      return "CRC error";
    case 0x05040005:
      return "out of memory";
    case 0x06010000:
      return "unsupported access to an object";
    case 0x06010001:
      return "attempt to read a write only object";
    case 0x06010002:
      return "attempt to write a read only object";
    case 0x06020000:
      return "object does not exist in the object dictionary";
    case 0x06040041:
      return "object cannot be mapped to the PDO";
    case 0x06040042:
      return "the number and length of the objects to be mapped would exceed the PDO length";
    case 0x06040043:
      return "general parameter incompatibility";
    case 0x06040047:
      return "general internal incompatibility in the device";
    case 0x06060000:
      return "access failed due to a hardware error";
    case 0x06070010:
      return "data type does not match, length of service parameter does not match";
    case 0x06070012:
      return "data type does not match, length of service parameter too high";
    case 0x06070013:
      return "data type does not match, length of service parameter too low";
    case 0x06090011:
      return "sub-index does not exist";
    case 0x06090030:
      return "invalid value for parameter (value range exceeded)";
    case 0x06090031:
      return "value of parameter written too high";
    case 0x06090032:
      return "value of parameter written too low";
    case 0x06090036:
      return "maximum value is less than minimum value";
    case 0x060A0023:
      return "resource not available: SDO connection";
    case 0x08000000:
      return "general error";
    case 0x08000020:
      return "data cannot be transferred or stored to the application";
    case 0x08000021:
      return "data cannot be transferred or stored to the application because of local control";
    case 0x08000022:
      return "data cannot be transferred or stored to the application because of the present "
             "device state";
    case 0x08000023:
      return "object dictionary dynamic generation failed or no object dictionary is present";
    case 0x08000024:
      return "no data available";
    default:
      return nullptr;
  }
}

std::string describe_sdo_abort(std::uint32_t code) {
  const char* t = sdo_abort_text(code);
  return hex(code, 8) + " " + (t != nullptr ? t : "unknown abort code");
}

const char* emcy_code_text(std::uint16_t code) {
  switch (code) {
    case 0x0000:
      return "error reset or no error";
    case 0x1000:
      return "generic error";
    case 0x2000:
      return "current";
    case 0x2100:
      return "current, device input side";
    case 0x2200:
      return "current inside the device";
    case 0x2220:
      return "continuous over-current inside the device";
    case 0x2300:
      return "current, device output side";
    case 0x2310:
      return "continuous over-current (device output side)";
    case 0x2320:
      return "short circuit or earth leakage (device output side)";
    case 0x2330:
      return "earth leakage (device output side)";
    case 0x2340:
      return "short circuit (device output side)";
    case 0x3000:
      return "voltage";
    case 0x3100:
      return "mains voltage";
    case 0x3110:
      return "mains over-voltage";
    case 0x3120:
      return "mains under-voltage";
    case 0x3130:
      return "mains phase failure";
    case 0x3200:
      return "voltage inside the device";
    case 0x3210:
      return "DC link over-voltage";
    case 0x3220:
      return "DC link under-voltage";
    case 0x3300:
      return "output voltage";
    case 0x4000:
      return "temperature";
    case 0x4100:
      return "ambient temperature";
    case 0x4200:
      return "device temperature";
    case 0x4210:
      return "excess temperature device";
    case 0x4300:
      return "drive temperature";
    case 0x4310:
      return "excess temperature drive";
    case 0x4400:
      return "supply temperature";
    case 0x5000:
      return "device hardware";
    case 0x5100:
      return "supply";
    case 0x5400:
      return "power section";
    case 0x5410:
      return "output stages";
    case 0x5440:
      return "contacts";
    case 0x5441:
      return "contact 1 (manufacturer specific)";
    case 0x5442:
      return "contact 2 (manufacturer specific)";
    case 0x5443:
      return "contact 3 (manufacturer specific)";
    case 0x5444:
      return "contact 4 (manufacturer specific)";
    case 0x5445:
      return "contact 5 (manufacturer specific)";
    case 0x5450:
      return "fuses";
    case 0x5500:
      return "data storage";
    case 0x6000:
      return "device software";
    case 0x6010:
      return "reset by watchdog";
    case 0x6100:
      return "internal software";
    case 0x6200:
      return "user software";
    case 0x6300:
      return "data set";
    case 0x6310:
      return "loss of parameters";
    case 0x6320:
      return "parameter error";
    case 0x7000:
      return "additional modules";
    case 0x7100:
      return "power";
    case 0x7110:
      return "brake chopper";
    case 0x7120:
      return "motor";
    case 0x7121:
      return "motor blocked";
    case 0x7122:
      return "motor error or commutation malfunction";
    case 0x7300:
      return "sensor";
    case 0x7301:
      return "tacho fault";
    case 0x7303:
      return "resolver 1 fault";
    case 0x7304:
      return "resolver 2 fault";
    case 0x7305:
      return "incremental sensor 1 fault";
    case 0x7306:
      return "incremental sensor 2 fault";
    case 0x7307:
      return "incremental sensor 3 fault";
    case 0x7310:
      return "speed";
    case 0x7320:
      return "position";
    case 0x7500:
      return "communication";
    case 0x8000:
      return "monitoring";
    case 0x8100:
      return "communication";
    case 0x8110:
      return "CAN overrun (objects lost)";
    case 0x8120:
      return "CAN in error passive mode";
    case 0x8130:
      return "life guard error or heartbeat error";
    case 0x8140:
      return "recovered from bus off";
    case 0x8150:
      return "CAN-ID collision";
    case 0x8200:
      return "protocol error";
    case 0x8210:
      return "PDO not processed due to length error";
    case 0x8220:
      return "PDO length exceeded";
    case 0x8250:
      return "RPDO timeout";
    case 0x8300:
      return "torque control";
    case 0x8311:
      return "excess torque";
    case 0x8400:
      return "velocity speed controller";
    case 0x8500:
      return "position controller";
    case 0x8600:
      return "positioning controller";
    case 0x8611:
      return "following error";
    case 0x8612:
      return "reference limit";
    case 0x9000:
      return "external error";
    case 0xF000:
      return "additional functions";
    case 0xFF00:
      return "device specific (manufacturer)";
    default:
      return nullptr;
  }
}

std::string emcy_text(std::uint16_t code) {
  const char* t = emcy_code_text(code);
  std::string s = "EMCY " + hex(code, 4);
  if (t != nullptr) s += std::string(" ") + t;
  return s;
}

Result<Emcy> decode_emcy(const can::Frame& f, double t_s) {
  if (f.len != 8 || f.remote || f.error)
    return make_error("EMCY frame " + hex(f.id, 3) + " of " + std::to_string(f.len) +
                      " bytes (8 expected)");
  Emcy e;
  e.t_s = t_s;
  e.code = static_cast<std::uint16_t>(get_le(f.payload(), 0, 2));
  e.register_ = f.data[2];
  for (std::size_t i = 0; i < 5; ++i) e.manufacturer[i] = f.data[3 + i];
  e.text = emcy_text(e.code);
  return e;
}

can::Frame emcy_frame(std::uint8_t node, std::uint16_t code, std::uint8_t reg,
                      std::array<std::uint8_t, 5> manufacturer) {
  can::Frame f = data_frame(kEmcyBase + node, 8);
  put_le(f.data, 0, 2, code);
  f.data[2] = reg;
  for (std::size_t i = 0; i < 5; ++i) f.data[3 + i] = manufacturer[i];
  return f;
}

// ---- SDO client ----

std::string SdoResult::describe() const {
  std::string s =
      (upload ? "read " : "write ") + hex(index, 4) + ":" + hex(subindex, 2).substr(2) + ": ";
  if (ok()) return s + "done";
  s += describe_sdo_abort(abort);
  s += aborted_by_server ? " (aborted by the drive)" : " (aborted by the host)";
  return s;
}

void SdoClient::download(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                         Callback done) {
  queue_.push_back(Transfer{index, sub, false, std::move(data), std::move(done)});
}

void SdoClient::upload(std::uint16_t index, std::uint8_t sub, Callback done) {
  queue_.push_back(Transfer{index, sub, true, {}, std::move(done)});
}

void SdoClient::download_urgent(std::uint16_t index, std::uint8_t sub,
                                std::vector<std::uint8_t> data, Callback done) {
  Transfer t{index, sub, false, std::move(data), std::move(done)};
  t.urgent = true;
  const auto after =
      std::find_if(queue_.begin(), queue_.end(), [](const Transfer& q) { return !q.urgent; });
  queue_.insert(after, std::move(t));
}

can::Frame SdoClient::request() const {
  can::Frame f = data_frame(kSdoRxBase + node_, 8);
  if (active_) {
    put_le(f.data, 1, 2, active_->index);
    f.data[3] = active_->sub;
  }
  return f;
}

void SdoClient::start(double now_s, std::vector<can::Frame>& out) {
  if (active_ || queue_.empty()) return;
  active_ = std::move(queue_.front());
  queue_.pop_front();
  Transfer& t = *active_;
  t.deadline = now_s + timeout_s_;
  if (!t.upload && t.data.empty()) {
    // nothing to write: CiA 301 has no 0-byte download (a segmented one
    // would carry a segment of 7 unused bytes); refused without a frame
    finish(abort_code::kLength, false, now_s, out);
    return;
  }
  can::Frame f = request();
  if (t.upload) {
    f.data[0] = 0x40;  // initiate upload request (ccs 2)
  } else if (!t.data.empty() && t.data.size() <= 4) {
    // initiate download, expedited, size indicated: n = 4 - size bytes unused
    f.data[0] = static_cast<std::uint8_t>(0x23 | ((4 - t.data.size()) << 2));
    std::copy(t.data.begin(), t.data.end(), f.data.begin() + 4);
  } else {
    f.data[0] = 0x21;  // initiate download, segmented, size indicated
    put_le(f.data, 4, 4, t.data.size());
    t.segmented = true;
  }
  out.push_back(f);
}

void SdoClient::send_segment(std::vector<can::Frame>& out) {
  Transfer& t = *active_;
  can::Frame f = data_frame(kSdoRxBase + node_, 8);
  if (t.upload) {
    f.data[0] = static_cast<std::uint8_t>(0x60 | (t.toggle ? 0x10 : 0));  // ccs 3
  } else {
    const std::size_t n = std::min<std::size_t>(7, t.data.size() - t.offset);
    const bool last = t.offset + n == t.data.size();
    // ccs 0: toggle, n = 7 - bytes carried, c = no more segments
    f.data[0] = static_cast<std::uint8_t>((t.toggle ? 0x10 : 0) | ((7 - n) << 1) | (last ? 1 : 0));
    std::copy_n(t.data.begin() + static_cast<std::ptrdiff_t>(t.offset), n, f.data.begin() + 1);
    t.offset += n;
  }
  out.push_back(f);
}

void SdoClient::finish(std::uint32_t code, bool by_server, double now_s,
                       std::vector<can::Frame>& out) {
  Transfer t = std::move(*active_);
  active_.reset();
  SdoResult r;
  r.index = t.index;
  r.subindex = t.sub;
  r.upload = t.upload;
  r.abort = code;
  r.aborted_by_server = by_server;
  if (t.upload && code == 0) r.data = std::move(t.data);
  if (t.done) t.done(r);
  start(now_s, out);
}

void SdoClient::abort_active(std::uint32_t code, double now_s, std::vector<can::Frame>& out) {
  can::Frame f = request();
  f.data[0] = 0x80;
  put_le(f.data, 4, 4, code);
  out.push_back(f);
  ++counts_.aborts_sent;
  finish(code, false, now_s, out);
}

void SdoClient::cancel_all(std::vector<can::Frame>& out, std::uint32_t code) {
  std::deque<Transfer> dropped;
  dropped.swap(queue_);
  if (active_) {
    can::Frame f = request();
    f.data[0] = 0x80;
    put_le(f.data, 4, 4, code);
    out.push_back(f);
    ++counts_.aborts_sent;
    dropped.push_front(std::move(*active_));
    active_.reset();
  }
  // every caller hears how its transfer ended; a callback may queue anew
  for (Transfer& t : dropped) {
    if (!t.done) continue;
    SdoResult r;
    r.index = t.index;
    r.subindex = t.sub;
    r.upload = t.upload;
    r.abort = code;
    t.done(r);
  }
}

void SdoClient::fail_queued(std::uint32_t code) {
  std::deque<Transfer> dropped;
  dropped.swap(queue_);
  for (Transfer& t : dropped)  // urgent ones stay, first, before a callback queues anew
    if (t.urgent) queue_.push_back(std::move(t));
  for (Transfer& t : dropped) {
    if (t.urgent || !t.done) continue;
    SdoResult r;
    r.index = t.index;
    r.subindex = t.sub;
    r.upload = t.upload;
    r.abort = code;
    t.done(r);
  }
}

void SdoClient::held(double from_s, double to_s) {
  if (!active_) return;
  const double since = active_->deadline - timeout_s_;  // when it went out
  active_->deadline += std::max(0.0, to_s - std::max(from_s, since));
}

void SdoClient::tick(double now_s, std::vector<can::Frame>& out) {
  if (active_ && now_s >= active_->deadline) {
    ++counts_.timeouts;
    abort_active(abort_code::kTimeout, now_s, out);
  }
  start(now_s, out);
}

bool SdoClient::on_frame(const can::Frame& f, double now_s, std::vector<can::Frame>& out) {
  if (f.id != kSdoTxBase + node_ || f.extended || f.remote || f.error || f.fd) return false;
  if (f.len != 8) {
    ++counts_.malformed;
    return true;
  }
  if (!active_) {
    ++counts_.unexpected;
    return true;
  }
  Transfer& t = *active_;
  const std::uint8_t b0 = f.data[0];
  const std::uint8_t scs = b0 >> 5;
  if (scs == 4) {  // abort transfer
    // an abort names its transfer's object; one for another (a late answer
    // to a transfer already ended) must not end the one under way
    if (get_le(f.payload(), 1, 2) != t.index || f.data[3] != t.sub) {
      ++counts_.unexpected;
      return true;
    }
    ++counts_.aborts_received;
    finish(get_le(f.payload(), 4, 4), true, now_s, out);
    return true;
  }
  const bool same_object = get_le(f.payload(), 1, 2) == t.index && f.data[3] == t.sub;
  if (!t.initiated && !same_object) {
    // An initiate response names its object: one for another is a late
    // answer to a transfer that already ended (timed out, aborted), not
    // this one's; counted, skipped, and this transfer waits on for its own
    ++counts_.unexpected;
    ++counts_.late;
    return true;
  }
  t.deadline = now_s + timeout_s_;
  if (!t.initiated) {
    if (!t.upload) {
      if (scs != 3) {
        abort_active(abort_code::kCommandSpecifier, now_s, out);
        return true;
      }
      t.initiated = true;
      if (!t.segmented) {
        finish(0, false, now_s, out);
      } else {
        send_segment(out);
      }
      return true;
    }
    if (scs != 2) {
      abort_active(abort_code::kCommandSpecifier, now_s, out);
      return true;
    }
    t.initiated = true;
    const bool expedited = (b0 & 0x02) != 0, size_indicated = (b0 & 0x01) != 0;
    if (expedited) {
      const std::size_t n = size_indicated ? 4 - ((b0 >> 2) & 0x03) : 4;
      t.data.assign(f.data.begin() + 4, f.data.begin() + 4 + static_cast<std::ptrdiff_t>(n));
      finish(0, false, now_s, out);
      return true;
    }
    t.segmented = true;
    t.size_known = size_indicated;
    t.expected = size_indicated ? get_le(f.payload(), 4, 4) : 0;
    if (t.size_known && t.expected > kMaxUpload) {
      abort_active(0x05040005, now_s, out);
      return true;
    }
    send_segment(out);
    return true;
  }
  // a segment's response: the toggle bit must be the one we sent
  const bool toggle = (b0 & 0x10) != 0;
  if (!t.upload) {
    if (scs != 1) {
      abort_active(abort_code::kCommandSpecifier, now_s, out);
      return true;
    }
    if (toggle != t.toggle) {
      abort_active(abort_code::kToggle, now_s, out);
      return true;
    }
    t.toggle = !t.toggle;
    if (t.offset == t.data.size()) {
      finish(0, false, now_s, out);
    } else {
      send_segment(out);
    }
    return true;
  }
  if (scs != 0) {
    abort_active(abort_code::kCommandSpecifier, now_s, out);
    return true;
  }
  if (toggle != t.toggle) {
    abort_active(abort_code::kToggle, now_s, out);
    return true;
  }
  const std::size_t n = 7 - ((b0 >> 1) & 0x07);
  t.data.insert(t.data.end(), f.data.begin() + 1,
                f.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
  if (t.data.size() > kMaxUpload) {
    abort_active(0x05040005, now_s, out);
    return true;
  }
  if ((b0 & 0x01) != 0) {  // no more segments
    if (t.size_known && t.data.size() != t.expected) {
      abort_active(abort_code::kLength, now_s, out);
    } else {
      finish(0, false, now_s, out);
    }
    return true;
  }
  t.toggle = !t.toggle;
  send_segment(out);
  return true;
}

}  // namespace turncal::canopen
