// What the drivers of DBC-described devices share.
#pragma once

#include "turncal/config.hpp"
#include "turncal/device.hpp"
#include "turncal/unwrap.hpp"

namespace turncal::drivers {

/// The range of a role's signal, its DBC value times `to_si`.
SignalSpan span_of(const RoleMap& roles, Role r, double to_si);
/// A host frame (a command, the heartbeat) as a recording holds it.
HostCommandSample host_command(const FrameView& f, Role r);

}  // namespace turncal::drivers
