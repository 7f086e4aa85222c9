// The reference stand's devices (can-icd.md), one driver each: the INS that
// sends its East and North velocity in two frames, each with its own time
// tag, and the table that speaks TBL_Command / TBL_Status / TBL_Encoder.
// Both read their frames through the configuration's roles and the DBC.
#pragma once

#include <memory>

#include "turncal/config.hpp"
#include "turncal/device.hpp"

namespace turncal::drivers {

/// `roles` (and the database it points into) must outlive the driver.
/// The INS of `layout`; `time_scale`: stand seconds per real second.
std::unique_ptr<InsDriver> make_ins(const InsLayout& layout, const RoleMap& roles,
                                    Plausibility plausibility, double time_scale);
/// The devices a configuration names: the INS of its layout, the table
/// of its [table] protocol (drivers/table/protocols.cpp, a row each).
struct Devices {
  std::unique_ptr<InsDriver> ins;
  std::unique_ptr<TableDriver> table;
};
Devices make_devices(const CanConfig& can, const RoleMap& roles, Plausibility plausibility,
                     double time_scale);
std::unique_ptr<InsDriver> make_reference_ins(const RoleMap& roles, Plausibility plausibility);
std::unique_ptr<TableDriver> make_reference_table(const RoleMap& roles, Plausibility plausibility);
/// A CiA 402 drive's table ([table] protocol = "cia402", cia402_table.cpp):
/// the CANopen master of drivers/cia402.hpp behind the TableDriver
/// interface, its PDO layouts from the roles. Settings or layouts that do
/// not fit leave the master inert: start() latches a configuration fault
/// that says why (check_cia402_table() says it before a run).
std::unique_ptr<TableDriver> make_cia402_table(const Cia402Settings& settings,
                                               const RoleMap& roles);
/// Whether the settings and the DBC's PDO layouts fit a CiA 402 drive, or
/// why not (the configuration key where one is to blame).
Status check_cia402_table(const CanConfig& can, const RoleMap& roles);
/// Whether the configuration and the DBC fit the table's protocol (its
/// row's check), or why not: before a run, and in turncalctl check.
Status check_table(const CanConfig& can, const RoleMap& roles);

}  // namespace turncal::drivers
