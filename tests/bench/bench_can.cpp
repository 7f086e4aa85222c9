// Benchmarks of the CAN layer (not tests): decode rate of the reference
// stand's frames through the DBC codec, and candump log parse and write
// rates. Prints one figure per line; scripts/bench runs it.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/can/dbc.hpp"

using namespace turncal::can;
using Clock = std::chrono::steady_clock;

namespace {

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// One second of the reference stand: 100 Hz INS_VelE and INS_VelN, 10 Hz
/// INS_Status, 200 Hz TBL_Encoder, 20 Hz TBL_Status (430 frames).
std::vector<Frame> reference_mix(const Database& db, std::size_t seconds) {
  std::mt19937_64 rng(1);
  std::vector<Frame> out;
  struct Rate {
    const char* name;
    int hz;
  };
  const Rate rates[] = {{"INS_VelE", 100},
                        {"INS_VelN", 100},
                        {"INS_Status", 10},
                        {"TBL_Encoder", 200},
                        {"TBL_Status", 20}};
  for (std::size_t s = 0; s < seconds; ++s) {
    for (int tick = 0; tick < 200; ++tick) {
      for (const Rate& r : rates) {
        if (tick % (200 / r.hz) != 0) continue;
        const Message* m = db.find(r.name);
        Frame f;
        f.id = m->id;
        f.len = static_cast<std::uint8_t>(m->size);
        for (std::size_t i = 0; i < f.len; ++i) f.data[i] = static_cast<std::uint8_t>(rng());
        out.push_back(f);
      }
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string dbc =
      argc > 1 ? argv[1] : std::string(turncal::build::source_dir) + "/config/reference-stand.dbc";
  auto db = load_dbc(dbc);
  if (!db.ok()) {
    std::fprintf(stderr, "%s\n", db.error().describe().c_str());
    return 1;
  }
  FrameCodec codec(*db);

  // -- decode
  const auto frames = reference_mix(*db, 2000);  // 860,000 frames
  double sink = 0;
  std::size_t decoded = 0;
  double best = 0;
  for (int rep = 0; rep < 5; ++rep) {
    const auto t0 = Clock::now();
    double values[8];
    for (const Frame& f : frames) {
      const Message* m = nullptr;
      if (codec.decode(f, values, &m) == DecodeStatus::Ok) {
        sink += values[0] + values[m->signals.size() - 1];
        ++decoded;
      }
    }
    const double rate = static_cast<double>(frames.size()) / seconds_since(t0);
    best = std::max(best, rate);
  }
  std::printf("decode_reference_frames_per_s %.3e  (target >= 1.0e7; %zu frames x 5, best run)\n",
              best, frames.size());

  // -- log write and parse
  const auto path = std::filesystem::temp_directory_path() /
                    ("turncal-bench-" + std::to_string(::getpid()) + ".log");
  const std::size_t lines = 2'000'000;
  {
    auto w = LogWriter::open(path.string());
    if (!w.ok()) return 1;
    const auto t0 = Clock::now();
    LogRecord r;
    r.interface = "can0";
    for (std::size_t i = 0; i < lines; ++i) {
      r.frame = frames[i % frames.size()];
      r.time_ns = 1'700'000'000'000'000'000 + static_cast<std::int64_t>(i) * 2'325'581;
      if (!w->write(r).ok()) return 1;
    }
    if (!w->close().ok()) return 1;
    std::printf("log_write_lines_per_s %.3e\n", static_cast<double>(lines) / seconds_since(t0));
  }
  best = 0;
  for (int rep = 0; rep < 3; ++rep) {
    auto rd = LogReader::open(path.string());
    if (!rd.ok()) return 1;
    LogRecord rec;
    std::size_t n = 0;
    const auto t0 = Clock::now();
    for (;;) {
      auto got = rd->next(rec);
      if (!got.ok()) {
        std::fprintf(stderr, "%s\n", got.error().describe().c_str());
        return 1;
      }
      if (!*got) break;
      sink += rec.frame.data[0];
      ++n;
    }
    best = std::max(best, static_cast<double>(n) / seconds_since(t0));
  }
  std::printf("log_parse_lines_per_s %.3e  (target >= 3.0e6; %zu lines from a file, best of 3)\n",
              best, lines);
  std::filesystem::remove(path);
  std::printf("(checksum %.1f, decoded %zu)\n", sink, decoded);
  return 0;
}
