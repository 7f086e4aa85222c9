#include "turncal/drivers/socketcan.hpp"

#include <fcntl.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <linux/if_link.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <optional>

namespace turncal::socketcan {
namespace {

constexpr std::size_t kBatch = Socket::kBatchFrames;
constexpr std::size_t kCmsgSpace =
    CMSG_SPACE(sizeof(struct timespec)) + CMSG_SPACE(sizeof(std::uint32_t));

Error sys_error(const std::string& iface, const char* what, int err) {
  return make_error(iface + ": " + what + ": " + std::strerror(err));
}

void to_kernel(const can::Frame& f, canfd_frame& k) {
  std::memset(&k, 0, sizeof k);
  if (f.error) {
    k.can_id = (f.id & CAN_ERR_MASK) | CAN_ERR_FLAG;
  } else if (f.extended) {
    k.can_id = (f.id & CAN_EFF_MASK) | CAN_EFF_FLAG;
  } else {
    k.can_id = f.id & CAN_SFF_MASK;
  }
  if (f.remote) k.can_id |= CAN_RTR_FLAG;
  k.len = f.len;
  if (f.fd) k.flags = static_cast<__u8>((f.brs ? CANFD_BRS : 0) | (f.esi ? CANFD_ESI : 0));
  std::memcpy(k.data, f.data.data(), f.len);
}

void from_kernel(const canfd_frame& k, bool fd, can::Frame& f) {
  f = can::Frame{};
  f.error = (k.can_id & CAN_ERR_FLAG) != 0;
  f.extended = !f.error && (k.can_id & CAN_EFF_FLAG) != 0;
  f.remote = (k.can_id & CAN_RTR_FLAG) != 0;
  f.id = f.error      ? (k.can_id & CAN_ERR_MASK)
         : f.extended ? (k.can_id & CAN_EFF_MASK)
                      : (k.can_id & CAN_SFF_MASK);
  f.fd = fd;
  f.brs = fd && (k.flags & CANFD_BRS) != 0;
  f.esi = fd && (k.flags & CANFD_ESI) != 0;
  const std::size_t max = fd ? CANFD_MAX_DLEN : CAN_MAX_DLEN;
  f.len = static_cast<std::uint8_t>(k.len > max ? max : k.len);
  if (!f.remote) std::memcpy(f.data.data(), k.data, f.len);
}

bool interface_up(int fd, const std::string& name) {
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, name.c_str(), IFNAMSIZ - 1);
  return ::ioctl(fd, SIOCGIFFLAGS, &ifr) == 0 && (ifr.ifr_flags & IFF_UP) != 0;
}

}  // namespace

std::int64_t realtime_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

Socket::Socket(Socket&& o) noexcept
    : opt_(std::move(o.opt_)),
      fd_(std::exchange(o.fd_, -1)),
      link_(o.link_),
      ifindex_(o.ifindex_),
      last_ovfl_(o.last_ovfl_),
      txq_(std::move(o.txq_)),
      stats_(o.stats_),
      busy_errno_(o.busy_errno_) {}

Socket& Socket::operator=(Socket&& o) noexcept {
  if (this != &o) {
    close_socket();
    opt_ = std::move(o.opt_);
    fd_ = std::exchange(o.fd_, -1);
    link_ = o.link_;
    ifindex_ = o.ifindex_;
    last_ovfl_ = o.last_ovfl_;
    txq_ = std::move(o.txq_);
    stats_ = o.stats_;
    busy_errno_ = o.busy_errno_;
  }
  return *this;
}

Socket::~Socket() {
  close_socket();
}

void Socket::close_socket() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

Result<Socket> Socket::open(Options options) {
  if (options.interface.empty() || options.interface.size() >= IFNAMSIZ)
    return make_error("'" + options.interface + "' is not an interface name");
  Socket s(std::move(options));
  TURNCAL_TRY(s.open_socket());
  return s;
}

Status Socket::open_socket() {
  const std::string& name = opt_.interface;
  const unsigned index = ::if_nametoindex(name.c_str());
  if (index == 0) return sys_error(name, "no such CAN interface", errno);
  if (opt_.require_virtual) {
    if (Status v = require_virtual_can(name, index); !v)
      return make_error(v.error().describe() + ": not opened");
  }
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) return sys_error(name, "socket(PF_CAN)", errno);
  auto fail = [&](const char* what) {
    const int err = errno;
    ::close(fd);
    return sys_error(name, what, err);
  };
  const int one = 1;
  if (opt_.fd && ::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &one, sizeof one) != 0)
    return fail("CAN_RAW_FD_FRAMES");
  if ((opt_.receive_own || opt_.confirm) &&
      ::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, &one, sizeof one) != 0)
    return fail("CAN_RAW_RECV_OWN_MSGS");
  if (!opt_.filters.empty()) {
    std::vector<can_filter> filters;
    for (const Filter& f : opt_.filters) {
      can_filter k{};
      k.can_id = f.extended ? ((f.id & CAN_EFF_MASK) | CAN_EFF_FLAG) : (f.id & CAN_SFF_MASK);
      k.can_mask = f.mask != 0
                       ? (f.mask | CAN_EFF_FLAG | CAN_RTR_FLAG)
                       : ((f.extended ? CAN_EFF_MASK : CAN_SFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG);
      filters.push_back(k);
    }
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                     static_cast<socklen_t>(filters.size() * sizeof(can_filter))) != 0)
      return fail("CAN_RAW_FILTER");
  }
  if (opt_.error_frames) {
    const can_err_mask_t mask = CAN_ERR_MASK;
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &mask, sizeof mask) != 0)
      return fail("CAN_RAW_ERR_FILTER");
  }
  if (::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof one) != 0)
    return fail("SO_TIMESTAMPNS");
  if (::setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof one) != 0) return fail("SO_RXQ_OVFL");
  if (opt_.rcvbuf_bytes > 0 &&
      ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &opt_.rcvbuf_bytes, sizeof opt_.rcvbuf_bytes) != 0)
    return fail("SO_RCVBUF");
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) return fail("bind");
  fd_ = fd;
  ifindex_ = index;
  last_ovfl_ = 0;
  link_ = LinkState::Up;
  return Status{Ok{}};
}

void Socket::link_event(RxBatch& out, can::BusEventKind kind) {
  out.events.push_back(
      can::BusEvent{opt_.clock != nullptr ? opt_.clock->now_ns() : realtime_ns(), kind, 0});
}

Result<std::size_t> Socket::receive(RxBatch& out, std::size_t max_batches) {
  if (down_on_write_) {
    // the write consumed the socket's NETDEV_DOWN error (the kernel's send
    // path reads and clears it): the link went down all the same, and the
    // receive below will not say so
    down_on_write_ = false;
    if (link_ == LinkState::Up && fd_ >= 0) {
      link_event(out, can::BusEventKind::InterfaceDown);
      link_ = LinkState::Down;
    }
  }
  drained_ = true;
  if (fd_ < 0) return std::size_t{0};
  std::array<canfd_frame, kBatch> frames;
  std::array<iovec, kBatch> iov;
  std::array<mmsghdr, kBatch> msgs;
  alignas(cmsghdr) std::array<std::array<char, kCmsgSpace>, kBatch> ctrl;
  std::size_t total = 0;
  for (std::size_t batch = 0; batch < max_batches; ++batch) {
    for (std::size_t i = 0; i < kBatch; ++i) {
      iov[i] = iovec{&frames[i], sizeof(canfd_frame)};
      std::memset(&msgs[i], 0, sizeof(mmsghdr));
      msgs[i].msg_hdr.msg_iov = &iov[i];
      msgs[i].msg_hdr.msg_iovlen = 1;
      msgs[i].msg_hdr.msg_control = ctrl[i].data();
      msgs[i].msg_hdr.msg_controllen = kCmsgSpace;
    }
    const int n = ::recvmmsg(fd_, msgs.data(), kBatch, MSG_DONTWAIT, nullptr);
    if (n < 0) {
      const int err = errno;
      if (err == EAGAIN || err == EWOULDBLOCK || err == EINTR) break;
      if (err == ENETDOWN) {  // raw_notifier: NETDEV_DOWN; the binding stays
        if (link_ == LinkState::Up) link_event(out, can::BusEventKind::InterfaceDown);
        link_ = LinkState::Down;
        continue;  // the error is reported once; frames may follow
      }
      if (err == ENODEV) {  // NETDEV_UNREGISTER: the socket is unbound for good
        link_event(out, can::BusEventKind::InterfaceGone);
        link_ = LinkState::Gone;
        close_socket();
        break;
      }
      return sys_error(opt_.interface, "recvmmsg", err);
    }
    if (link_ == LinkState::Down && n > 0) {
      link_ = LinkState::Up;
      link_event(out, can::BusEventKind::InterfaceBack);
    }
    if (opt_.clock != nullptr && n > 0) opt_.clock->observe();  // a step since the last batch
    for (int i = 0; i < n; ++i) {
      const mmsghdr& m = msgs[static_cast<std::size_t>(i)];
      const auto len = m.msg_len;
      if (len != CAN_MTU && len != CANFD_MTU) continue;  // not a CAN frame: ignored
      can::TimedFrame tf;
      from_kernel(frames[static_cast<std::size_t>(i)], len == CANFD_MTU, tf.frame);
      for (cmsghdr* c = CMSG_FIRSTHDR(&m.msg_hdr); c != nullptr;
           c = CMSG_NXTHDR(const_cast<msghdr*>(&m.msg_hdr), c)) {
        if (c->cmsg_level != SOL_SOCKET) continue;
        if (c->cmsg_type == SCM_TIMESTAMPNS) {
          timespec ts{};
          std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
          tf.time_ns = static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
        } else if (c->cmsg_type == SO_RXQ_OVFL) {
          std::uint32_t drops = 0;
          std::memcpy(&drops, CMSG_DATA(c), sizeof drops);
          stats_.rx_dropped += drops - last_ovfl_;  // cumulative counter, wraps
          last_ovfl_ = drops;
        }
      }
      if (opt_.clock == nullptr) {
        if (tf.time_ns == 0) tf.time_ns = realtime_ns();
      } else {
        tf.time_ns = tf.time_ns == 0 ? opt_.clock->now_ns() : opt_.clock->from_realtime(tf.time_ns);
      }
      if (opt_.confirm && (m.msg_hdr.msg_flags & MSG_CONFIRM) != 0) {
        ++stats_.tx_confirmed;  // our own frame, echoed: it went out
        out.confirmed.push_back(tf);
        out.echoed.push_back(true);
        continue;
      }
      if (tf.frame.error) {
        ++stats_.rx_error_frames;
        for (const auto& e : can::decode_error_frame(tf)) out.events.push_back(e);
        continue;
      }
      ++stats_.rx_frames;
      out.frames.push_back(tf);
      out.echoed.push_back(false);
      ++total;
    }
    if (static_cast<std::size_t>(n) < kBatch) break;
    if (batch + 1 == max_batches) drained_ = false;  // full to the last batch: more may wait
  }
  return total;
}

Socket::TxResult Socket::write_frame(const can::Frame& f) {
  canfd_frame k;
  to_kernel(f, k);
  const std::size_t size = f.fd ? CANFD_MTU : CAN_MTU;
  for (;;) {
    const ssize_t n = ::write(fd_, &k, size);
    if (n == static_cast<ssize_t>(size)) return TxResult::Sent;
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == ENOBUFS)) {
      busy_errno_ = errno == ENOBUFS ? ENOBUFS : EAGAIN;
      return TxResult::Busy;
    }
    if (n < 0 && errno == ENETDOWN) down_on_write_ = true;
    return TxResult::Failed;
  }
}

Status Socket::sendable(const can::Frame& f) const {
  if (f.fd && !opt_.fd)
    return make_error(opt_.interface + ": CAN FD frame on a socket opened for classic CAN");
  if (f.len > (f.fd ? can::kMaxFdLen : can::kMaxClassicLen))
    return make_error(opt_.interface + ": frame payload too long");
  return Status{Ok{}};
}

std::optional<TxOutcome> Socket::write_now(const can::Frame& f) {
  switch (write_frame(f)) {
    case TxResult::Sent:
      ++stats_.tx_frames;
      return TxOutcome::Sent;
    case TxResult::Failed:
      ++stats_.tx_failed;
      return TxOutcome::Dropped;
    case TxResult::Busy:
      break;
  }
  return std::nullopt;
}

Result<TxOutcome> Socket::send_urgent(const can::Frame& f) {
  if (auto ok = sendable(f); !ok) return ok.error();
  stats_.tx_superseded += std::erase_if(
      txq_, [&](const can::Frame& q) { return q.id == f.id && q.extended == f.extended; });
  if (fd_ < 0) {
    ++stats_.tx_failed;
    return TxOutcome::Dropped;
  }
  if (const auto done = write_now(f)) return *done;
  if (txq_.size() >= opt_.tx_queue_limit && !txq_.empty()) {
    txq_.pop_back();
    ++stats_.tx_overflow;
  }
  txq_.push_front(f);
  ++stats_.tx_queued;
  return TxOutcome::Queued;
}

Result<TxOutcome> Socket::send(const can::Frame& f) {
  if (auto ok = sendable(f); !ok) return ok.error();
  if (fd_ < 0) {
    ++stats_.tx_failed;
    return TxOutcome::Dropped;
  }
  if (txq_.empty()) {
    if (const auto done = write_now(f)) return *done;
  }
  if (txq_.size() >= opt_.tx_queue_limit) {
    ++stats_.tx_overflow;
    return TxOutcome::Dropped;
  }
  txq_.push_back(f);
  ++stats_.tx_queued;
  return TxOutcome::Queued;
}

std::size_t Socket::flush() {
  while (!txq_.empty() && fd_ >= 0) {
    const TxResult r = write_frame(txq_.front());
    if (r == TxResult::Busy) break;
    if (r == TxResult::Sent)
      ++stats_.tx_frames;
    else
      ++stats_.tx_failed;
    txq_.pop_front();
  }
  if (fd_ < 0 && !txq_.empty()) {  // gone: what waits can never go
    stats_.tx_failed += txq_.size();
    txq_.clear();
  }
  return txq_.size();
}

bool Socket::try_recover(RxBatch& out) {
  if (link_ == LinkState::Up) return true;
  if (link_ == LinkState::Down) {
    // Still bound: the link is back when the same interface is up again.
    const unsigned index = ::if_nametoindex(opt_.interface.c_str());
    if (index == ifindex_ && interface_up(fd_, opt_.interface)) {
      link_ = LinkState::Up;
      link_event(out, can::BusEventKind::InterfaceBack);
      return true;
    }
    if (index == ifindex_) return false;
    // Removed (and perhaps re-created) while down: start over.
    close_socket();
    link_ = LinkState::Gone;
  }
  if (!open_socket()) return false;
  ++stats_.recoveries;
  if (!interface_up(fd_, opt_.interface)) {  // re-created but not up yet
    link_ = LinkState::Down;
    return false;
  }
  link_event(out, can::BusEventKind::InterfaceBack);
  return true;
}

Result<std::string> link_kind_of_answer(std::span<const char> answer, const std::string& interface,
                                        unsigned index) {
  // walked by hand: the NLMSG_/RTA_ macros' casts and mixed signedness
  // are what this build's warnings refuse
  const auto align4 = [](std::size_t x) { return (x + 3) & ~std::size_t{3}; };
  const auto no_answer = [&](const char* why) {
    return make_error(interface + ": RTM_GETLINK: " + why);
  };
  const char* const begin = answer.data();
  const char* const end = answer.data() + answer.size();
  // [p, end) from an offset that may run past it: never a pointer beyond end
  const auto advance = [](const char* p, std::size_t by, const char* stop) {
    return static_cast<std::size_t>(stop - p) < by ? stop : p + by;
  };
  enum class Attr { Found, Absent, Malformed };
  // the attributes in [p, to): the payload of the first of type `type`
  const auto find_attr = [&](const char* p, const char* to, unsigned short type,
                             const char*& payload, std::size_t& len) {
    while (p < to) {
      if (to - p < static_cast<std::ptrdiff_t>(sizeof(rtattr))) return Attr::Malformed;
      rtattr a{};
      std::memcpy(&a, p, sizeof a);
      if (a.rta_len < sizeof(rtattr) || static_cast<std::ptrdiff_t>(a.rta_len) > to - p)
        return Attr::Malformed;
      if ((a.rta_type & NLA_TYPE_MASK) == type) {
        payload = advance(p, align4(sizeof(rtattr)), p + a.rta_len);
        len = static_cast<std::size_t>(p + a.rta_len - payload);
        return Attr::Found;
      }
      p = advance(p, align4(a.rta_len), to);
    }
    return Attr::Absent;
  };
  const char* p = begin;
  while (end - p >= static_cast<std::ptrdiff_t>(sizeof(nlmsghdr))) {
    nlmsghdr h{};
    std::memcpy(&h, p, sizeof h);
    if (h.nlmsg_len < sizeof(nlmsghdr) || static_cast<std::ptrdiff_t>(h.nlmsg_len) > end - p)
      return no_answer("a message's length is out of bounds");
    const char* msg_end = p + h.nlmsg_len;
    const char* data = advance(p, align4(sizeof(nlmsghdr)), msg_end);
    if (h.nlmsg_type == NLMSG_ERROR) {
      if (msg_end - data < static_cast<std::ptrdiff_t>(sizeof(nlmsgerr)))
        return no_answer("an error message cut short");
      nlmsgerr e{};
      std::memcpy(&e, data, sizeof e);
      if (e.error == 0) return no_answer("no answer for the interface");  // an acknowledgement
      return sys_error(interface, "RTM_GETLINK", -e.error);
    }
    if (h.nlmsg_type == RTM_NEWLINK) {
      if (msg_end - data < static_cast<std::ptrdiff_t>(sizeof(ifinfomsg)))
        return no_answer("a link message cut short");
      ifinfomsg ifi{};
      std::memcpy(&ifi, data, sizeof ifi);
      // the interface asked for by its index, not another that took its name
      if (index != 0 && ifi.ifi_index != static_cast<int>(index))
        return no_answer("the answer is for another interface");
      const char* attrs = advance(data, align4(sizeof(ifinfomsg)), msg_end);
      const char* info = nullptr;
      std::size_t info_len = 0;
      switch (find_attr(attrs, msg_end, IFLA_LINKINFO, info, info_len)) {
        case Attr::Malformed:
          return no_answer("a malformed attribute");
        case Attr::Absent:
          return std::string();  // a device driver's interface: no link kind
        case Attr::Found:
          break;
      }
      const char* kind = nullptr;
      std::size_t kind_len = 0;
      switch (find_attr(info, info + info_len, IFLA_INFO_KIND, kind, kind_len)) {
        case Attr::Malformed:
          return no_answer("a malformed link info");
        case Attr::Absent:
          return std::string();
        case Attr::Found:
          break;
      }
      return std::string(kind, ::strnlen(kind, kind_len));
    }
    p = advance(p, align4(h.nlmsg_len), end);
  }
  if (p != end) return no_answer("a message cut short");
  return no_answer("no answer for the interface");
}

Result<std::string> link_kind(const std::string& interface) {
  if (interface.empty() || interface.size() >= IFNAMSIZ)
    return make_error("'" + interface + "' is not an interface name");
  const unsigned index = ::if_nametoindex(interface.c_str());
  if (index == 0) return sys_error(interface, "no such interface", errno);
  return link_kind(interface, index);
}

Result<std::string> link_kind(const std::string& interface, unsigned index) {
  const int fd = ::socket(AF_NETLINK, SOCK_RAW | SOCK_CLOEXEC, NETLINK_ROUTE);
  if (fd < 0) return sys_error(interface, "socket(AF_NETLINK)", errno);
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct {
    nlmsghdr nh;
    ifinfomsg ifi;
  } req{};
  req.nh.nlmsg_len = NLMSG_LENGTH(sizeof(ifinfomsg));
  req.nh.nlmsg_type = RTM_GETLINK;
  req.nh.nlmsg_flags = NLM_F_REQUEST;
  req.nh.nlmsg_seq = 1;
  req.ifi.ifi_family = AF_UNSPEC;
  req.ifi.ifi_index = static_cast<int>(index);
  if (::send(fd, &req, req.nh.nlmsg_len, 0) != static_cast<ssize_t>(req.nh.nlmsg_len))
    return sys_error(interface, "RTM_GETLINK", errno);
  alignas(nlmsghdr) std::array<char, 16384> buf{};
  const ssize_t n = ::recv(fd, buf.data(), buf.size(), 0);
  if (n < 0) return sys_error(interface, "RTM_GETLINK answer", errno);
  return link_kind_of_answer(std::span<const char>(buf.data(), static_cast<std::size_t>(n)),
                             interface, index);
}

bool is_virtual_kind(std::string_view kind) {
  return kind == "vcan" || kind == "vxcan";
}

Status require_virtual_can(const std::string& interface, unsigned index) {
  auto kind = index != 0 ? link_kind(interface, index) : link_kind(interface);
  if (!kind)
    return make_error(kind.error().describe() + " (cannot tell whether it is a virtual CAN bus)");
  if (!is_virtual_kind(*kind))
    return make_error(
        interface + " is not a virtual CAN bus (" +
        (kind->empty() ? std::string("a device's interface") : "its kind is " + *kind) + ")");
  return Status{Ok{}};
}

}  // namespace turncal::socketcan
