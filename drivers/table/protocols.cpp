// The table protocols' drivers, a row each, in the order of the
// configuration's kTableProtocols (config.hpp): what [table] protocol
// names is made, and checked before a run, by its row here.
#include <array>
#include <stdexcept>
#include <string_view>

#include "turncal/drivers/reference.hpp"

namespace turncal::drivers {

namespace {

struct TableFactory {
  std::string_view name;
  std::unique_ptr<TableDriver> (*make)(const CanConfig& can, const RoleMap& roles,
                                       Plausibility plausibility);
  /// Whether the configuration and the DBC fit the protocol, or why not;
  /// nullptr: what the configuration reader checked is all.
  Status (*check)(const CanConfig& can, const RoleMap& roles);
};

constexpr std::array<TableFactory, kTableProtocols.size()> kTableFactories = {{
    {"reference",
     [](const CanConfig&, const RoleMap& roles, Plausibility plausibility) {
       return make_reference_table(roles, plausibility);
     },
     nullptr},
    {"cia402",
     [](const CanConfig& can, const RoleMap& roles, Plausibility) {
       return make_cia402_table(can.table.cia402, roles);
     },
     check_cia402_table},
}};

constexpr bool factories_match() {
  for (std::size_t i = 0; i < kTableProtocols.size(); ++i)
    if (kTableFactories[i].name != kTableProtocols[i]) return false;
  return true;
}
static_assert(factories_match(), "kTableFactories' rows are not kTableProtocols'");

/// The row of the configured protocol. The configuration reader accepts no
/// other name; a configuration made otherwise with one is a program's
/// error, thrown, never a table of another protocol.
const TableFactory& factory_of(const CanConfig& can) {
  for (const TableFactory& f : kTableFactories)
    if (f.name == can.table.name) return f;
  throw std::invalid_argument("[table] protocol = \"" + can.table.name +
                              "\": no driver of that protocol");
}

}  // namespace

Status check_table(const CanConfig& can, const RoleMap& roles) {
  for (const TableFactory& f : kTableFactories)
    if (f.name == can.table.name) return f.check != nullptr ? f.check(can, roles) : Status{Ok{}};
  return make_error("[table] protocol = \"" + can.table.name + "\": no driver of that protocol");
}

Devices make_devices(const CanConfig& can, const RoleMap& roles, Plausibility plausibility,
                     double time_scale) {
  return {make_ins(can.ins, roles, plausibility, time_scale),
          factory_of(can).make(can, roles, plausibility)};
}

}  // namespace turncal::drivers
