// turncald's control clients (clients.hpp): accepting them, reading their
// requests and answering them (control.hpp's dispatch), the watchers'
// status, and dropping those that are done, idle or behind.
#include "clients.hpp"

#include <sys/ioctl.h>
#include <systemd/sd-event.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <memory>
#include <string>
#include <tuple>

namespace turncal::daemon {

using nlohmann::json;

// ---- control clients ----

void Daemon::broadcast_watch() {
  if (report_busy) return;  // a run's end is heard once its report is on disk
  if (std::none_of(clients.begin(), clients.end(), [](const auto& c) { return c->watching; }))
    return;
  const json s = status();
  for (auto& c : clients)
    if (c->watching) c->reply(s);
  // clients are dropped in reap_clients(), never here: a request being
  // served may have called this
}

/// Drops the clients that are done, broken, idle or that leave replies unread.
void Daemon::reap_clients() {
  const std::uint64_t now = monotonic_us();
  const auto idle = static_cast<std::uint64_t>(cfg.daemon.client_idle_s * 1e6);
  for (auto& c : clients) {
    int unread = 0;
    if (c->unread_since_us != 0 && now - c->unread_since_us > idle) {
      warn("control client dropped: its replies were left unread for " +
           std::to_string(static_cast<int>(cfg.daemon.client_idle_s)) + " s");
      c->broken = true;
    } else if (!c->in.empty() && now - c->partial_since_us > idle &&
               ::ioctl(c->fd, FIONREAD, &unread) == 0 && unread == 0) {
      // a line never finished (a watcher's too) would hold a reload off;
      // one whose end waits in the socket, unread by us, is not the
      // client's doing
      warn("control client dropped: a request left unfinished for " +
           std::to_string(static_cast<int>(cfg.daemon.client_idle_s)) + " s");
      c->broken = true;
    } else if (!c->watching && c->out.empty() && now - c->last_request_us > idle) {
      info("control client dropped: no request for " +
           std::to_string(static_cast<int>(cfg.daemon.client_idle_s)) + " s");
      c->broken = true;
    }
  }
  std::erase_if(clients, [](const auto& c) { return c->done(); });
}

/// At max_clients, one client closed to let a new one in: of the peer
/// (uid) that holds the most connections, so that one peer's flood costs
/// that peer alone; of those, a watcher last, one with replies still going
/// out last, one with a request line begun last, then the one idle
/// longest. A connection accepted under kFreshGraceUs ago that has not
/// spoken yet is closed only for a newcomer of another uid than one
/// holding more connections than the newcomer's would: an operator's
/// abort, connected, is read before a flood can push it out, and a flood
/// of one uid cannot lock the others out. False: none can go.
bool Daemon::make_room(long long newcomer_uid) {
  std::erase_if(clients, [](const auto& c) { return c->done(); });  // dead slots first
  if (clients.size() < cfg.daemon.max_clients) return true;
  const std::uint64_t now = monotonic_us();
  std::map<long long, std::size_t> held;
  for (const auto& c : clients) ++held[c->uid];
  const std::size_t newcomer_holds = held[newcomer_uid] + 1;
  auto key = [&](const Client& c) {
    // smaller goes first
    return std::make_tuple(-static_cast<long long>(held[c.uid]), c.watching, !c.out.empty(),
                           !c.in.empty(), c.last_request_us);
  };
  Client* victim = nullptr;
  for (const auto& c : clients) {
    const bool fresh = !c->ever_read && now - c->accepted_us < kFreshGraceUs;
    if (c->close_after || (fresh && held[c->uid] <= newcomer_holds)) continue;
    if (victim == nullptr || key(*c) < key(*victim)) victim = c.get();
  }
  if (victim == nullptr) return false;
  const std::uint64_t idle_us = now - victim->last_request_us;
  const std::string why =
      "control connection closed to make room for a new one: " + std::to_string(clients.size()) +
      " open (max_clients), " + std::to_string(held[victim->uid]) + " of them uid " +
      std::to_string(victim->uid) + "'s; this one " + (victim->watching ? "watching, " : "") +
      "idle for " + std::to_string(idle_us / 1000000) + " s";
  // told why, if it reads at all, and if no reply of ours is half sent
  // (a line in the middle of one would garble both)
  if (victim->out.empty()) {
    const std::string line = json({{"ok", false}, {"error", why}}).dump() + "\n";
    (void)!::send(victim->fd, line.data(), line.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
  }
  info(why);
  std::erase_if(clients, [&](const auto& p) { return p.get() == victim; });
  return true;
}

void Daemon::handle_request(Client& c, const std::string& line) {
  View v;
  v.status = [this] { return status(); };
  v.running = running();
  v.index = &state->index();
  v.read_report = [this](const std::string& id) { return state->read_report(id); };
  Outcome o = dispatch(line, v);
  if (o.watch) c.watching = true;
  if (o.action) {
    if (const auto* s = std::get_if<StartRequest>(&*o.action)) {
      o.reply = start(*s);
    } else if (const auto* a = std::get_if<AbortRequest>(&*o.action); a != nullptr && report_busy) {
      o.reply = {{"ok", false},
                 {"error", "run " + run_id + " has ended; its report is being written"}};
    } else if (a != nullptr) {
      engine->abort(clock.now_ns(), a->reason, out);
      after_engine();
      o.reply = {{"ok", true}, {"run_id", run_id}};
    }
  }
  c.reply(o.reply);
}

int Daemon::on_client(sd_event_source*, int fd, uint32_t revents, void* u) {
  auto* c = static_cast<Client*>(u);
  Daemon& d = *c->d;
  guarded(
      &d, "a control request",
      [&] {
        if (revents & EPOLLOUT) c->flush();
        if (revents & EPOLLERR) c->broken = true;
        // a client that wrote and closed: what it wrote is still read and
        // answered (the read then sees the end and closes it)
        if ((revents & (EPOLLIN | EPOLLHUP)) && !c->close_after && !c->broken) {
          char buf[4096];
          const ssize_t n = ::recv(fd, buf, sizeof buf, MSG_DONTWAIT);
          if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
            // the client closed: what it asked is answered, then it is dropped
            c->close_after = true;
          } else if (n > 0) {
            c->ever_read = true;
            c->last_request_us = monotonic_us();
            if (c->in.empty()) c->partial_since_us = c->last_request_us;
            c->in.append(buf, static_cast<std::size_t>(n));
            std::size_t nl;
            while (!c->close_after && !c->broken && (nl = c->in.find('\n')) != std::string::npos) {
              const std::string line = c->in.substr(0, nl);
              c->in.erase(0, nl + 1);
              c->partial_since_us = c->last_request_us;  // what follows began in this read
              if (line.size() > kMaxRequest) {
                c->reply({{"ok", false}, {"error", "request too large"}});
                c->close_after = true;
              } else {
                d.handle_request(*c, line);
              }
            }
            if (c->in.empty()) c->partial_since_us = 0;
            if (!c->close_after && c->in.size() > kMaxRequest) {
              c->reply({{"ok", false},
                        {"error",
                         "request too large (over " + std::to_string(kMaxRequest) + " bytes)"}});
              c->close_after = true;
            }
          }
        }
        if (c->close_after) c->in.clear();
        c->flush();  // sends what is left, and sets the events still wanted
      },
      false);
  // the one place a client is freed while its own callback runs: after it
  if (c->done()) std::erase_if(d.clients, [&](const auto& p) { return p.get() == c; });
  return 0;
}

int Daemon::on_accept_again(sd_event_source*, uint64_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  if (const int rc = d->listen_src.set_enabled(SD_EVENT_ON); rc < 0) {
    // tried again in a second; a run goes on meanwhile. Only with no way
    // to try again, and no run, does the daemon exit (its socket starts it
    // anew on the next request)
    d->warn(std::string("cannot listen for control connections again (sd-event: ") +
            std::strerror(-rc) + "); trying again in 1 s");
    std::uint64_t now = 0;
    if (sd_event_now(d->ev, CLOCK_MONOTONIC, &now) < 0 ||
        d->accept_again.set_time(now + kAcceptBackoffUs) < 0 ||
        d->accept_again.set_enabled(SD_EVENT_ONESHOT) < 0) {
      // no way to listen again: the daemon exits once idle (on_timer), and
      // its socket starts it anew on the next request
      d->error("cannot arm the retry of the control socket's listener: turncald exits once idle");
      d->listener_lost = true;
    }
  }
  return 0;
}

int Daemon::on_accept(sd_event_source*, int fd, uint32_t, void* u) {
  auto* d = static_cast<Daemon*>(u);
  return guarded(d, "accept", [&] {
    const int cfd = ::accept4(fd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (cfd < 0) {
      if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
        // the pending connection stays readable: without a pause the loop spins
        d->warn(std::string("cannot accept a control connection: ") + std::strerror(errno) +
                "; accepting again in 1 s");
        std::uint64_t now = 0;
        // the listener is paused only when the timer that resumes it is set
        // (else the accept is tried again at once: a busy loop, not a deaf one)
        if (sd_event_now(d->ev, CLOCK_MONOTONIC, &now) >= 0 &&
            d->accept_again.set_time(now + kAcceptBackoffUs) >= 0 &&
            d->accept_again.set_enabled(SD_EVENT_ONESHOT) >= 0 &&
            d->listen_src.set_enabled(SD_EVENT_OFF) < 0)
          d->warn("cannot pause the control socket's listener");
      }
      return;
    }
    struct ucred cred {};
    socklen_t len = sizeof cred;
    const bool known = ::getsockopt(cfd, SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0;
    if (known)
      d->info("control connection from pid " + std::to_string(cred.pid) + " uid " +
              std::to_string(cred.uid) + " gid " + std::to_string(cred.gid));
    // Full: room is made rather than the newcomer refused, or clients that
    // connect and never ask anything would lock the operator out, and an
    // abort with them
    if (d->clients.size() >= d->cfg.daemon.max_clients &&
        !d->make_room(known ? static_cast<long long>(cred.uid) : -1)) {
      const std::string msg =
          "{\"ok\":false,\"error\":\"too many control connections (" +
          std::to_string(d->cfg.daemon.max_clients) +
          "), none to close now: each new and not yet heard from; try again in a second\"}\n";
      (void)!::send(cfd, msg.data(), msg.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      ::close(cfd);
      d->warn("control connection refused: " + std::to_string(d->clients.size()) +
              " open, each new and not yet heard from");
      return;
    }
    auto c = std::make_unique<Client>();
    c->d = d;
    c->fd = cfd;
    c->uid = known ? static_cast<long long>(cred.uid) : -1;
    c->last_request_us = monotonic_us();
    c->accepted_us = c->last_request_us;
    if (sd_event_add_io(d->ev, c->src.out(), cfd, EPOLLIN, on_client, c.get()) < 0) {
      d->warn("cannot watch a control connection");
      return;  // the destructor closes it
    }
    d->clients.push_back(std::move(c));
  });
}

}  // namespace turncal::daemon
