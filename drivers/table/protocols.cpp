// The table protocols' drivers, a row each, in the order of the
// configuration's kTableProtocols (config.hpp): what [table] protocol
// names is made, and checked before a run, by its row here.
#include <array>
#include <stdexcept>
#include <string>
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

/// The row of the configured protocol; nullptr for a name no row has.
const TableFactory* factory_of(const CanConfig& can) {
  for (const TableFactory& f : kTableFactories)
    if (f.name == can.table.name) return &f;
  return nullptr;
}

std::string no_driver(const CanConfig& can) {
  return "[table] protocol = \"" + can.table.name + "\": no driver of that protocol";
}

}  // namespace

Status check_table(const CanConfig& can, const RoleMap& roles) {
  const TableFactory* f = factory_of(can);
  if (f == nullptr) return make_error(no_driver(can));
  return f->check != nullptr ? f->check(can, roles) : Status{Ok{}};
}

Devices make_devices(const CanConfig& can, const RoleMap& roles, Plausibility plausibility,
                     double time_scale) {
  // The configuration reader accepts no other name; a configuration made
  // otherwise with one is a program's error, thrown, never a table of
  // another protocol.
  const TableFactory* f = factory_of(can);
  if (f == nullptr) throw std::invalid_argument(no_driver(can));
  return {make_ins(can.ins, roles, plausibility, time_scale), f->make(can, roles, plausibility)};
}

}  // namespace turncal::drivers
