// An sd-event source, owned: disabled and released when the handle goes
// (or is reset), so no callback ever runs for a freed owner; every call on
// it returns what sd-event said, for the caller to check (a negative
// errno; sd-event's own convention).
#pragma once

#include <systemd/sd-event.h>

#include <cstdint>
#include <utility>

namespace turncal::daemon {

class EventSource {
 public:
  EventSource() = default;
  ~EventSource() { reset(); }
  EventSource(const EventSource&) = delete;
  EventSource& operator=(const EventSource&) = delete;
  EventSource(EventSource&& o) noexcept : s_(std::exchange(o.s_, nullptr)) {}
  EventSource& operator=(EventSource&& o) noexcept {
    if (this != &o) {
      reset();
      s_ = std::exchange(o.s_, nullptr);
    }
    return *this;
  }

  /// Where sd_event_add_* puts the new source (the old one released first).
  sd_event_source** out() {
    reset();
    return &s_;
  }
  void reset() { s_ = sd_event_source_disable_unref(s_); }
  [[nodiscard]] explicit operator bool() const { return s_ != nullptr; }
  [[nodiscard]] sd_event_source* get() const { return s_; }

  [[nodiscard]] int set_enabled(int how) const { return sd_event_source_set_enabled(s_, how); }
  /// SD_EVENT_OFF, ON or ONESHOT; a released source is off.
  [[nodiscard]] int enabled(int& how) const {
    how = SD_EVENT_OFF;
    return s_ == nullptr ? 0 : sd_event_source_get_enabled(s_, &how);
  }
  [[nodiscard]] int set_io_events(std::uint32_t events) const {
    return sd_event_source_set_io_events(s_, events);
  }
  [[nodiscard]] int set_time(std::uint64_t usec) const {
    return sd_event_source_set_time(s_, usec);
  }
  [[nodiscard]] int set_priority(std::int64_t priority) const {
    return sd_event_source_set_priority(s_, priority);
  }

 private:
  sd_event_source* s_ = nullptr;
};

}  // namespace turncal::daemon
