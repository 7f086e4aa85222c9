// libFuzzer target: the candump log line parser. What it accepts must
// format and parse back to the same record.
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
