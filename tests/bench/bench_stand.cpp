// Benchmark of the virtual stand (not a test): offline generation of a
// 2-hour reference run (the tactical plan stretched to 2 h, its turn at
// 1 h) into a candump log, as turncal-sim --offline does. Target: at
// least 500 times faster than real time.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>

#include "turncal/build_paths.hpp"
#include "turncal/config.hpp"
#include "turncal/plan.hpp"
#include "turncal/sim/scripted_host.hpp"

using namespace turncal;

int main() {
  const std::string src = turncal::build::source_dir;
  auto plan = load_plan(src + "/config/profiles/tactical.toml");
  auto cfg = load_config(src + "/config/turncal.toml");
  if (!plan || !cfg) return 1;
  auto db = load_databases(cfg->can);
  if (!db) return 1;
  auto roles = resolve_roles(cfg->can, *db);
  if (!roles) return 1;
  plan->profile.duration_s = 7200;
  plan->profile.turns.at(0).start_s = 3600;
  stand::StandSetup setup;
  setup.ins.sim.latitude_rad = plan->site.latitude_rad;
  setup.ins.sim.height_m = plan->site.height_m;
  setup.ins.sim.noise = {plan->arw, plan->vrw, plan->sigma_z, 0};
  const auto path = std::filesystem::temp_directory_path() /
                    ("turncal-bench-stand-" + std::to_string(::getpid()) + ".log");
  auto log = can::LogWriter::open(path.string());
  if (!log) return 1;
  const auto t0 = std::chrono::steady_clock::now();
  if (!stand::run_offline(*plan, cfg->can, *db, *roles, setup, *log, 1.7e9)) return 1;
  if (!log->close()) return 1;
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double simulated = 2 + plan->profile.align_s + plan->profile.duration_s;
  std::printf(
      "offline_2h_run_s %.2f  (%.0f s simulated: %.0f times real time; target >= 500; "
      "log %.0f MB)\n",
      wall, simulated, simulated / wall,
      static_cast<double>(std::filesystem::file_size(path)) / 1e6);
  std::filesystem::remove(path);
  return 0;
}
