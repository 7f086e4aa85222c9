// libFuzzer target: the candump log line parser. What it accepts must
// format and parse back to the same record; and its fast way with the
// usual lines must give what the careful way gives, record or error.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "turncal/can/candump.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string_view text(reinterpret_cast<const char*>(data), size);
  while (!text.empty()) {
    const auto nl = text.find('\n');
    const std::string_view line = text.substr(0, nl);
    text = nl == std::string_view::npos ? std::string_view{} : text.substr(nl + 1);
    turncal::can::LogRecord fast, careful;
    const turncal::Status a = turncal::can::parse_log_line(line, fast);
    const turncal::Status b = turncal::can::detail::parse_log_line_careful(line, careful);
    if (a.ok() != b.ok()) std::abort();
    if (a.ok() && (fast.time_ns != careful.time_ns || fast.interface != careful.interface ||
                   !(fast.frame == careful.frame) || fast.frame.data != careful.frame.data))
      std::abort();
    turncal::can::LogRecord usual;
    if (turncal::can::detail::parse_usual_line(line, usual) &&
        (!b.ok() || usual.time_ns != careful.time_ns || usual.interface != careful.interface ||
         !(usual.frame == careful.frame) || usual.frame.data != careful.frame.data))
      std::abort();
    if (!a.ok() && (a.error().message != b.error().message ||
                    a.error().where.column != b.error().where.column))
      std::abort();
    auto rec = turncal::can::parse_log_line(line);
    if (!rec.ok()) continue;
    const std::string out = turncal::can::format_log_line(*rec);
    auto back = turncal::can::parse_log_line(std::string_view(out).substr(0, out.size() - 1));
    if (!back.ok()) std::abort();
    if (back->time_ns / 1000 != rec->time_ns / 1000) std::abort();
    if (back->interface != rec->interface) std::abort();
    if (!rec->frame.remote && !(back->frame == rec->frame)) std::abort();
  }
  return 0;
}
