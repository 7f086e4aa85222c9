// libFuzzer target: the DBC parser, and the codec over whatever it accepts.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include "turncal/can/dbc.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto db = turncal::can::parse_dbc(text, "fuzz.dbc");
  if (!db.ok()) {
    if (db.error().where.line == 0) std::abort();  // every parse error has a line
    return 0;
  }
  for (const auto& w : db->warnings)
    if (w.where.line == 0) std::abort();  // every warning has a line too
  turncal::can::FrameCodec codec(*db);
  for (const auto& m : db->messages) {
    turncal::can::Frame f;
    f.id = m.id;
    f.extended = m.extended;
    f.fd = m.fd;
    f.len = static_cast<std::uint8_t>(m.size);
    for (std::size_t i = 0; i < f.len; ++i) f.data[i] = static_cast<std::uint8_t>(size + i * 131);
    std::vector<double> values(m.signals.size());
    if (codec.decode(f, values) != turncal::can::DecodeStatus::Ok) std::abort();
    for (std::size_t i = 0; i < values.size(); ++i)  // an unusable signal is never decoded
      if (!m.signals[i].usable && !std::isnan(values[i])) std::abort();
    const turncal::can::Frame g = turncal::can::FrameCodec::encode(m, values);
    if (g.len != f.len) std::abort();
  }
  return 0;
}
