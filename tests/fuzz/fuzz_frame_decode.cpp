// libFuzzer target: the frame decoders (signal codec, error frames) on
// arbitrary frames, by the reference stand's DBC or by a file of layouts
// it lacks (Motorola, CAN FD, IEEE floats, 64-bit, multiplexed, unusable
// signals); each value the codec gives is the one its signal's own extract
// gives, bit for bit.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/can/bus_event.hpp"
#include "turncal/can/dbc.hpp"

namespace {
std::unique_ptr<turncal::can::Database> load(const std::string& relative) {
  auto r = turncal::can::load_dbc(std::string(turncal::build::source_dir) + "/" + relative);
  if (!r.ok()) std::abort();
  return std::make_unique<turncal::can::Database>(std::move(r).value());
}
const turncal::can::Database& reference() {
  static const auto db = load("config/reference-stand.dbc");
  return *db;
}
const turncal::can::Database& layouts() {
  static const auto db = load("tests/fuzz/data/decode-layouts.dbc");
  return *db;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const turncal::can::FrameCodec by_reference(reference());
  static const turncal::can::FrameCodec by_layouts(layouts());
  if (size < 6) return 0;
  turncal::can::TimedFrame tf;
  turncal::can::Frame& f = tf.frame;
  std::uint32_t id = 0;
  std::memcpy(&id, data, 4);
  const std::uint8_t flags = data[4];
  const bool of_layouts = (flags & 16) != 0;
  const turncal::can::Database& db = of_layouts ? layouts() : reference();
  const turncal::can::FrameCodec& codec = of_layouts ? by_layouts : by_reference;
  f.extended = (flags & 1) != 0;
  f.fd = (flags & 2) != 0;
  f.remote = (flags & 4) != 0;
  f.error = (flags & 8) != 0;
  f.id = id & (f.extended || f.error ? turncal::can::kExtIdMask : turncal::can::kStdIdMask);
  const std::size_t max = f.fd ? turncal::can::kMaxFdLen : turncal::can::kMaxClassicLen;
  f.len = static_cast<std::uint8_t>(data[5] % (max + 1));
  if ((flags & 32) != 0) {
    // aimed: a frame of one of the database's messages, as its sender makes
    // it (a random ID seldom is one)
    const turncal::can::Message& m = db.messages[id % db.messages.size()];
    f.id = m.id;
    f.extended = m.extended;
    f.fd = m.fd;
    f.len = static_cast<std::uint8_t>(m.size);
  }
  // the input's bytes past the length too: the codec's 8-byte loads must
  // drop whatever lies past a signal
  const std::size_t n = std::min<std::size_t>(f.data.size(), size - 6);
  std::memcpy(f.data.data(), data + 6, n);
  std::vector<double> values(codec.max_signals());
  const turncal::can::Message* m = nullptr;
  const auto st = codec.decode(f, values, &m);
  if (st == turncal::can::DecodeStatus::Ok && (m == nullptr || m->size != f.len)) std::abort();
  if (st == turncal::can::DecodeStatus::Ok) {
    for (std::size_t i = 0; i < m->signals.size(); ++i) {
      const turncal::can::Signal& sig = m->signals[i];
      if (!m->carries(i, f.payload())) {
        if (!std::isnan(values[i])) std::abort();
        continue;
      }
      const double want =
          turncal::can::raw_to_physical(sig, turncal::can::extract_raw(sig, f.payload()));
      if (std::memcmp(&want, &values[i], sizeof want) != 0) std::abort();
    }
  }
  (void)turncal::can::decode_error_frame(tf);
  return 0;
}
