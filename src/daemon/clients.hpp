// turncald's control clients: one connection on the control socket, its
// request lines read, its replies queued until the socket takes them.
#pragma once

#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>

#include "daemon.hpp"
#include "event_source.hpp"

namespace turncal::daemon {

struct Client {
  Daemon* d;
  int fd;
  EventSource src;
  std::string in;
  bool watching = false;
  /// The peer's user, by SO_PEERCRED; -1: not known.
  long long uid = -1;
  std::uint64_t accepted_us = 0;      ///< monotonic
  bool ever_read = false;             ///< a byte of it read: it has spoken
  std::uint64_t last_request_us = 0;  ///< monotonic; at accept until its first request
  std::uint64_t unread_since_us = 0;  ///< monotonic; 0: nothing waits
  /// monotonic: when the unfinished request line in `in` began (its first
  /// byte read); 0 while `in` is empty
  std::uint64_t partial_since_us = 0;
  ~Client() {
    src.reset();  // no callback for a closed descriptor
    ::close(fd);
  }
  std::string out;           ///< replies the socket has not taken yet
  bool broken = false;       ///< gone, or so far behind that it is dropped
  bool close_after = false;  ///< dropped once its replies are sent
  /// Queues a reply and sends what the socket takes; the rest goes when the
  /// socket is writable again (EPOLLOUT), so a large report is never cut.
  void reply(const nlohmann::json& j) {
    if (broken) return;
    if (out.size() > kMaxQueued) {  // a watcher that stopped reading
      broken = true;
      return;
    }
    out += j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
    flush();
  }
  void flush() {
    while (!out.empty() && !broken) {
      const ssize_t n = ::send(fd, out.data(), out.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) break;
      if (n <= 0) {
        broken = true;
        break;
      }
      out.erase(0, static_cast<std::size_t>(n));
    }
    if (out.empty())
      unread_since_us = 0;
    else if (unread_since_us == 0)
      unread_since_us = monotonic_us();
    // a client being closed is not read any more (EPOLLIN would fire
    // forever); one whose events cannot be set is dropped (reap_clients)
    if (src && src.set_io_events((close_after || broken ? 0U : EPOLLIN) |
                                 (out.empty() || broken ? 0U : EPOLLOUT)) < 0)
      broken = true;
  }
  [[nodiscard]] bool done() const { return broken || (close_after && out.empty()); }
};

}  // namespace turncal::daemon
