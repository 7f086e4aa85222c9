// Helpers of the hil tier: the vcan interfaces the runner made, shell
// commands, and waiting for frames.
#pragma once

#include <poll.h>

#include <chrono>
#include <cstdlib>
#include <string>

#include "turncal/drivers/socketcan.hpp"

namespace hil {

inline std::string if0() {
  const char* v = std::getenv("TURNCAL_HIL_IF0");
  return v != nullptr ? v : "tchil0";
}
inline std::string if1() {
  const char* v = std::getenv("TURNCAL_HIL_IF1");
  return v != nullptr ? v : "tchil1";
}

/// Runs a shell command; returns its exit status.
inline int sh(const std::string& cmd) {
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

inline turncal::socketcan::Socket open(turncal::socketcan::Options o) {
  auto s = turncal::socketcan::Socket::open(std::move(o));
  if (!s.ok()) throw std::runtime_error(s.error().describe());
  return std::move(s).value();
}

inline turncal::socketcan::Socket open(const std::string& iface, bool fd = false) {
  turncal::socketcan::Options o;
  o.interface = iface;
  o.fd = fd;
  return open(std::move(o));
}

/// Polls and receives until `want` frames arrived or `timeout` passed.
inline turncal::socketcan::RxBatch receive(
    turncal::socketcan::Socket& s, std::size_t want,
    std::chrono::milliseconds timeout = std::chrono::milliseconds(2000)) {
  turncal::socketcan::RxBatch out;
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (out.frames.size() < want && std::chrono::steady_clock::now() < end) {
    pollfd p{s.fd(), POLLIN, 0};
    if (s.fd() >= 0)
      ::poll(&p, 1, 50);
    else
      ::poll(nullptr, 0, 50);
    auto r = s.receive(out);
    if (!r.ok()) throw std::runtime_error(r.error().describe());
  }
  return out;
}

inline turncal::can::Frame frame(std::uint32_t id, std::initializer_list<std::uint8_t> bytes,
                                 bool ext = false) {
  turncal::can::Frame f;
  f.id = id;
  f.extended = ext;
  for (auto b : bytes) f.data[f.len++] = b;
  return f;
}

}  // namespace hil
