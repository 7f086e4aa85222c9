#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include <cstdio>
#include <cstdlib>

int main(int argc, char** argv) {
  const char* env = std::getenv("TURNCAL_VCAN_ENV");
  std::printf("hil tier: %s, interfaces %s and %s\n", env != nullptr ? env : "unknown",
              std::getenv("TURNCAL_HIL_IF0") ? std::getenv("TURNCAL_HIL_IF0") : "tchil0",
              std::getenv("TURNCAL_HIL_IF1") ? std::getenv("TURNCAL_HIL_IF1") : "tchil1");
  doctest::Context ctx(argc, argv);
  return ctx.run();
}
