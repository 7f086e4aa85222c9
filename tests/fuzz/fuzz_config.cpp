// libFuzzer target: turncal.toml, plans and their --set overrides. The
// input is split at the first NUL: before it, the TOML text (read as a
// configuration and as a plan); after it, override lines ("section.key=V").
// Every error names a line; nothing throws or crashes.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>
#include <vector>

#include "turncal/config.hpp"
#include "turncal/plan.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view all(reinterpret_cast<const char*>(data), size);
  const std::size_t nul = all.find('\0');
  const std::string_view text = all.substr(0, nul);
  std::vector<std::string> overrides;
  if (nul != std::string_view::npos) {
    std::string_view rest = all.substr(nul + 1);
    while (!rest.empty() && overrides.size() < 8) {
      const std::size_t nl = rest.find('\n');
      overrides.emplace_back(rest.substr(0, nl));
      rest = nl == std::string_view::npos ? std::string_view() : rest.substr(nl + 1);
    }
  }
  (void)turncal::parse_config(text, "fuzz.toml");
  (void)turncal::parse_plan(text, "fuzz-plan.toml", overrides);
  return 0;
}
