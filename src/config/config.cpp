#include "turncal/config.hpp"

#include "toml_reader.hpp"
#include "turncal/estimation/params.hpp"
#include "turncal/icd.hpp"

#include <toml++/toml.h>
#include <algorithm>
#include <cctype>
#include <fstream>
#include <span>
#include <sstream>
#include <tuple>

namespace turncal {
namespace {

using config_detail::pos_of;
using config_detail::Reader;

/// When a role's signal is needed.
enum class Needed : std::uint8_t {
  Always,
  InsTag,          ///< the INS's samples carry time tags ([ins] time = "tag")
  InsNorthTag,     ///< that, unless North shares East's frame and gives no tag of its own
  InsTimeFrame,    ///< the INS's time comes in a time frame
  ReferenceTable,  ///< the reference table's frames (can-icd.md) and its host heartbeat
  Cia402,          ///< a CiA 402 drive's PDOs
  Cia402Velocity,  ///< that, with velocity_pdo
};

/// Each role once: its key, the reference stand's signal, whether the
/// host sends it, when it is needed, and whether it may then be "" (none).
struct RoleRow {
  Role role;
  std::string_view key;
  std::string_view reference;  ///< MESSAGE.SIGNAL of can-icd.md; "" none by default
  bool output;
  Needed needed;
  bool optional;
};

constexpr std::array<RoleRow, kRoleCount> kRoles = {{
    {Role::InsVelEast, "ins_vel_east", "INS_VelE.VelE", false, Needed::Always, false},
    {Role::InsVelEastTimeTag, "ins_vel_east_time_tag", "INS_VelE.TimeTag", false, Needed::InsTag,
     false},
    {Role::InsVelNorth, "ins_vel_north", "INS_VelN.VelN", false, Needed::Always, false},
    {Role::InsVelNorthTimeTag, "ins_vel_north_time_tag", "INS_VelN.TimeTag", false,
     Needed::InsNorthTag, false},
    {Role::InsMode, "ins_mode", "INS_Status.Mode", false, Needed::Always, false},
    {Role::InsStatusTimeTag, "ins_status_time_tag", "INS_Status.TimeTag", false, Needed::InsTag,
     true},
    {Role::InsAlignRemaining, "ins_align_remaining", "INS_Status.AlignRemaining", false,
     Needed::Always, true},
    {Role::InsTime, "ins_time", "", false, Needed::InsTimeFrame, false},
    {Role::InsCommand, "ins_command", "INS_Command.Command", true, Needed::Always, false},
    {Role::InsCommandAlignDuration, "ins_command_align_duration", "INS_Command.AlignDuration", true,
     Needed::Always, false},
    {Role::InsCommandHeading, "ins_command_heading", "INS_Command.HeadingInit", true,
     Needed::Always, false},
    {Role::InsCommandSeq, "ins_command_seq", "INS_Command.Seq", true, Needed::Always, false},
    {Role::EncoderAngle, "encoder_angle", "TBL_Encoder.Angle", false, Needed::ReferenceTable,
     false},
    {Role::EncoderTimeTag, "encoder_time_tag", "TBL_Encoder.TimeTag", false, Needed::ReferenceTable,
     false},
    {Role::TableState, "table_state", "TBL_Status.State", false, Needed::ReferenceTable, false},
    {Role::TableAck, "table_ack", "TBL_Status.AckSeq", false, Needed::ReferenceTable, false},
    {Role::TableFault, "table_fault", "TBL_Status.Fault", false, Needed::ReferenceTable, false},
    {Role::TableRate, "table_rate", "TBL_Status.Rate", false, Needed::ReferenceTable, false},
    {Role::TableCommand, "table_command", "TBL_Command.Command", true, Needed::ReferenceTable,
     false},
    {Role::TableCommandSeq, "table_command_seq", "TBL_Command.Seq", true, Needed::ReferenceTable,
     false},
    {Role::TableCommandTarget, "table_command_target", "TBL_Command.Target", true,
     Needed::ReferenceTable, false},
    {Role::TableCommandRateLimit, "table_command_rate_limit", "TBL_Command.RateLimit", true,
     Needed::ReferenceTable, false},
    {Role::HeartbeatCounter, "heartbeat_counter", "HOST_Heartbeat.Counter", true,
     Needed::ReferenceTable, false},
    {Role::HeartbeatState, "heartbeat_state", "HOST_Heartbeat.HostState", true,
     Needed::ReferenceTable, false},
    {Role::TableControlword, "table_controlword", "", true, Needed::Cia402, false},
    {Role::TableTargetPosition, "table_target_position", "", true, Needed::Cia402, false},
    {Role::TableStatusword, "table_statusword", "", false, Needed::Cia402, false},
    {Role::TablePositionActual, "table_position_actual", "", false, Needed::Cia402, false},
    {Role::TableVelocityActual, "table_velocity_actual", "", false, Needed::Cia402Velocity, false},
}};

constexpr bool roles_in_order() {
  for (std::size_t i = 0; i < kRoles.size(); ++i)
    if (static_cast<std::size_t>(kRoles[i].role) != i) return false;
  return true;
}
static_assert(roles_in_order(), "kRoles' rows are not in the order of enum Role");

constexpr const RoleRow& role_row(Role r) {
  return kRoles[static_cast<std::size_t>(r)];
}

Status check_interface(const Reader& r, std::string_view key, const std::string& name) {
  const toml::node* n = r.table().get(key);
  if (name.empty() || name.size() > 15 || name.find('/') != std::string::npos ||
      name.find(' ') != std::string::npos) {
    const SourcePos where =
        n != nullptr ? pos_of(n->source(), r.file()) : SourcePos{r.file(), 0, 0};
    return make_error("key 'can." + std::string(key) + "': '" + name +
                          "' is not an interface name (1 to 15 characters, no '/' or space)",
                      where);
  }
  return Status{Ok{}};
}

Status read_roles(const toml::table& t, const std::string& file, CanConfig& can) {
  for (auto&& [k, v] : t) {
    std::size_t idx = kRoleCount;
    for (std::size_t i = 0; i < kRoleCount; ++i)
      if (k.str() == kRoles[i].key) idx = i;
    if (idx == kRoleCount)
      return make_error("unknown role 'can.roles." + std::string(k.str()) + "'",
                        pos_of(k.source(), file));
    const SourcePos where = pos_of(v.source(), file);
    if (!v.is_string())
      return make_error("key 'can.roles." + std::string(k.str()) + "': expected \"Message.Signal\"",
                        where);
    const std::string& s = v.as_string()->get();
    if (s.empty()) {  // none
      can.roles[idx] = SignalRef{"", "", where};
      continue;
    }
    const auto dot = s.find('.');
    if (dot == std::string::npos || dot == 0 || dot + 1 == s.size() ||
        s.find('.', dot + 1) != std::string::npos)
      return make_error(
          "key 'can.roles." + std::string(k.str()) + "': '" + s + "' is not \"Message.Signal\"",
          where);
    can.roles[idx] = SignalRef{s.substr(0, dot), s.substr(dot + 1), where};
  }
  return Status{Ok{}};
}

Result<CanConfig> read_can(const toml::table& t, const std::string& file) {
  CanConfig can;
  can.roles = reference_roles();
  for (auto& r : can.roles) r.where = SourcePos{file, 0, 0};
  Reader r(t, file, "can.");
  TURNCAL_TRY(r.no_unknown_keys({"ins_interface", "table_interface", "dbc", "fd", "tx_queue_frames",
                                 "rx_buffer_bytes", "roles", "max_ins_velocity_mps",
                                 "implausible_fraction"}));
  TURNCAL_TRY(r.string("ins_interface", can.ins_interface));
  TURNCAL_TRY(r.string("table_interface", can.table_interface));
  TURNCAL_TRY(check_interface(r, "ins_interface", can.ins_interface));
  TURNCAL_TRY(check_interface(r, "table_interface", can.table_interface));
  TURNCAL_TRY(r.boolean("fd", can.fd));
  TURNCAL_TRY(r.integer("tx_queue_frames", can.tx_queue_frames, 1, 1 << 20));
  TURNCAL_TRY(r.integer("rx_buffer_bytes", can.rx_buffer_bytes, 0, 1 << 30));
  TURNCAL_TRY(r.number("max_ins_velocity_mps", can.max_ins_velocity_mps, 1e-3, 1e6));
  TURNCAL_TRY(r.number("implausible_fraction", can.implausible_fraction, 0, 1));
  const std::filesystem::path base = std::filesystem::path(file).parent_path();
  if (const toml::node* n = t.get("dbc")) {
    const toml::array* arr = n->as_array();
    if (arr == nullptr || arr->empty())
      return r.error_at(*n, "dbc", "expected a non-empty list of DBC file names");
    for (const toml::node& e : *arr) {
      if (!e.is_string()) return r.error_at(e, "dbc", "expected a file name string");
      std::filesystem::path p(e.as_string()->get());
      can.dbc_files.push_back(p.is_absolute() ? p : base / p);
    }
  } else {
    can.dbc_files.push_back(base / "reference-stand.dbc");
  }
  if (const toml::node* n = t.get("roles")) {
    if (!n->is_table()) return r.error_at(*n, "roles", "expected a table");
    TURNCAL_TRY(read_roles(*n->as_table(), file, can));
  }
  return can;
}

}  // namespace

std::string_view role_key(Role role) {
  return role_row(role).key;
}

bool role_is_output(Role role) {
  return role_row(role).output;
}

bool role_is_ins(Role role) {
  return static_cast<std::size_t>(role) <= static_cast<std::size_t>(Role::InsCommandSeq);
}

std::array<SignalRef, kRoleCount> reference_roles() {
  std::array<SignalRef, kRoleCount> out;
  for (std::size_t i = 0; i < kRoleCount; ++i) {
    const std::string_view s = kRoles[i].reference;
    const auto dot = s.find('.');
    if (dot == std::string_view::npos) continue;  // none by default
    out[i] = SignalRef{std::string(s.substr(0, dot)), std::string(s.substr(dot + 1)), {}};
  }
  return out;
}

namespace {

constexpr double kDegRad = 0.017453292519943295;

const toml::table* section(const toml::table& root, std::string_view key, Status& st,
                           const std::string& file) {
  const toml::node* n = root.get(key);
  if (n == nullptr) return nullptr;
  if (!n->is_table()) {
    st = make_error("key '" + std::string(key) + "': expected a table", pos_of(n->source(), file));
    return nullptr;
  }
  return n->as_table();
}

/// One of `choices` for `key`, or an error listing them.
Status choice(const Reader& r, std::string_view key, std::span<const std::string_view> choices,
              std::string& out) {
  TURNCAL_TRY(r.string(key, out));
  for (std::string_view c : choices)
    if (out == c) return Status{Ok{}};
  std::string list;
  for (std::string_view c : choices) list += (list.empty() ? "\"" : ", \"") + std::string(c) + "\"";
  return r.error_at(*r.table().get(key), key, "'" + out + "' is none of " + list);
}
Status choice(const Reader& r, std::string_view key,
              std::initializer_list<std::string_view> choices, std::string& out) {
  return choice(r, key, std::span<const std::string_view>(choices.begin(), choices.size()), out);
}

Status read_ins(const toml::table& t, const std::string& file, InsLayout& ins) {
  Reader r(t, file, "ins.");
  TURNCAL_TRY(r.no_unknown_keys({"time", "velocity_axes", "east_sign", "north_sign",
                                 "velocity_rate_hz", "time_frame_max_age_ms"}));
  std::string time = "tag";
  TURNCAL_TRY(choice(r, "time", {"tag", "time-frame", "receive"}, time));
  ins.time = time == "tag"          ? InsTimeSource::Tag
             : time == "time-frame" ? InsTimeSource::TimeFrame
                                    : InsTimeSource::Receive;
  std::string axes = "navigation";
  TURNCAL_TRY(choice(r, "velocity_axes", {"navigation", "body"}, axes));
  if (axes == "body")
    return r.error_at(*t.get("velocity_axes"), "velocity_axes",
                      "velocity in body axes needs the INS's attitude to rotate it into "
                      "navigation axes, which turncal does not read; set the INS to send its "
                      "velocity in navigation axes (NED or ENU)");
  for (auto [key, out] :
       {std::pair{"east_sign", &ins.east_sign}, {"north_sign", &ins.north_sign}}) {
    TURNCAL_TRY(r.number(key, *out, -1, 1));
    if (*out != 1 && *out != -1) return r.error_at(*t.get(key), key, "must be 1 or -1");
  }
  TURNCAL_TRY(r.number("velocity_rate_hz", ins.velocity_rate_hz, 0, 10000));
  double age_ms = ins.time_frame_max_age_s * 1e3;
  TURNCAL_TRY(r.number("time_frame_max_age_ms", age_ms, 0.1, 1000));
  ins.time_frame_max_age_s = age_ms * 1e-3;
  if (ins.time == InsTimeSource::Receive && !(ins.velocity_rate_hz > 0))
    return r.error_at(*t.get("time"), "time",
                      "\"receive\" times the velocity on a clock of its nominal rate: give "
                      "ins.velocity_rate_hz");
  return Status{Ok{}};
}

/// One EMCY code of emcy_warnings: "0x" and four hex digits.
std::optional<std::uint16_t> emcy_code(std::string_view s) {
  if (s.size() != 6 || (s.substr(0, 2) != "0x" && s.substr(0, 2) != "0X")) return std::nullopt;
  std::uint32_t v = 0;
  for (const char ch : s.substr(2)) {
    const int d = std::isdigit(static_cast<unsigned char>(ch)) != 0 ? ch - '0'
                  : ch >= 'a' && ch <= 'f'                          ? ch - 'a' + 10
                  : ch >= 'A' && ch <= 'F'                          ? ch - 'A' + 10
                                                                    : -1;
    if (d < 0) return std::nullopt;
    v = v * 16 + static_cast<std::uint32_t>(d);
  }
  return static_cast<std::uint16_t>(v);
}

/// table.cia402.emcy_warnings: the EMCY codes that only warn, each "0xHHHH"
/// or a range "0xHHHH-0xHHHH"; an empty list makes every code a fault.
Status read_emcy_warnings(const Reader& r, const toml::table& t, Cia402Settings& c) {
  const toml::node* n = t.get("emcy_warnings");
  if (n == nullptr) return Status{Ok{}};
  const toml::array* a = n->as_array();
  if (a == nullptr)
    return r.error_at(*n, "emcy_warnings",
                      "expected a list of EMCY codes, as \"0x4210\" or \"0x4000-0x4FFF\"");
  std::vector<std::pair<std::uint16_t, std::uint16_t>> ranges;
  for (const toml::node& e : *a) {
    const auto* str = e.as_string();
    const std::string v = str != nullptr ? str->get() : std::string();
    const auto dash = v.find('-');
    const auto lo = emcy_code(v.substr(0, dash));
    const auto hi = dash == std::string::npos ? lo : emcy_code(v.substr(dash + 1));
    if (!lo || !hi)
      return r.error_at(e, "emcy_warnings",
                        "expected an EMCY code as \"0x4210\" or a range as \"0x4000-0x4FFF\"" +
                            (str != nullptr ? ", not \"" + v + "\"" : std::string()));
    if (*hi < *lo)
      return r.error_at(e, "emcy_warnings", "the range \"" + v + "\" ends before it begins");
    if (*lo == 0)
      return r.error_at(e, "emcy_warnings",
                        "0x0000 is the error reset, no warning: begin the range at 0x0001");
    // the codes by which the drive says it stopped for the host's sake or
    // lost the table's position: never a mere warning
    for (const std::uint16_t never : {std::uint16_t{0x8130}, std::uint16_t{0x8611}})
      if (*lo <= never && never <= *hi)
        return r.error_at(e, "emcy_warnings",
                          "\"" + v + "\" takes in " +
                              (never == 0x8130 ? "0x8130 (the drive lost "
                                                 "our heartbeat)"
                                               : "0x8611 (following "
                                                 "error)") +
                              ", which is always a fault");
    ranges.emplace_back(*lo, *hi);
  }
  c.emcy_warnings = std::move(ranges);
  return Status{Ok{}};
}

Status read_cia402(const toml::table& t, const std::string& file, Cia402Settings& c) {
  Reader r(t, file, "table.cia402.");
  TURNCAL_TRY(r.no_unknown_keys({"node_id",
                                 "host_node_id",
                                 "counts_per_revolution",
                                 "gear_ratio",
                                 "counts_increase",
                                 "profile_acceleration_dps2",
                                 "profile_deceleration_dps2",
                                 "quick_stop_deceleration_dps2",
                                 "quick_stop_option_code",
                                 "abort_connection_option_code",
                                 "host_heartbeat_ms",
                                 "host_heartbeat_consumer_ms",
                                 "drive_heartbeat_ms",
                                 "drive_heartbeat_timeout_ms",
                                 "sync_period_ms",
                                 "tpdo_event_timer_ms",
                                 "configure_mapping",
                                 "velocity_pdo",
                                 "change_set_immediately",
                                 "sdo_timeout_ms",
                                 "boot_timeout_ms",
                                 "emcy_warnings"}));
  std::uint32_t node = c.node_id, host = c.host_node_id;
  TURNCAL_TRY(r.integer("node_id", node, 1, 127));
  TURNCAL_TRY(r.integer("host_node_id", host, 1, 127));
  if (node == host)
    return r.error_at(
        *t.get(t.get("host_node_id") != nullptr ? "host_node_id" : "node_id"),
        t.get("host_node_id") != nullptr ? "host_node_id" : "node_id",
        "the drive and the host cannot be the same node (" + std::to_string(node) + ")");
  c.node_id = static_cast<std::uint8_t>(node);
  c.host_node_id = static_cast<std::uint8_t>(host);
  // counts per table turn must fit the drive's s32 position several turns over
  TURNCAL_TRY(r.number("counts_per_revolution", c.counts_per_revolution, 1, 1u << 30));
  TURNCAL_TRY(r.number("gear_ratio", c.gear_ratio, 1e-3, 1e5));
  std::string sense = c.counts_clockwise ? "clockwise" : "counter-clockwise";
  TURNCAL_TRY(choice(r, "counts_increase", {"counter-clockwise", "clockwise"}, sense));
  c.counts_clockwise = sense == "clockwise";
  for (auto [key, out] : {std::pair{"profile_acceleration_dps2", &c.profile_acceleration_rps2},
                          {"profile_deceleration_dps2", &c.profile_deceleration_rps2},
                          {"quick_stop_deceleration_dps2", &c.quick_stop_deceleration_rps2}}) {
    double dps2 = *out / kDegRad;
    TURNCAL_TRY(r.number(key, dps2, 0.01, 1e5));
    *out = dps2 * kDegRad;
  }
  std::uint32_t qs = static_cast<std::uint32_t>(c.quick_stop_option_code),
                ac = static_cast<std::uint32_t>(c.abort_connection_option_code);
  // 0x605A: 0 disable drive, 1/2 slow down/quick stop ramp then disable,
  // 5/6 the same and stay in quick stop active (CiA 402 values 0 to 8)
  TURNCAL_TRY(r.integer("quick_stop_option_code", qs, 0, 8));
  // a quick stop must brake the table, not let it coast
  if (qs == 0)
    return r.error_at(*t.get("quick_stop_option_code"), "quick_stop_option_code",
                      "0 (disable drive function) lets the table coast on a quick stop: use 1, 2 "
                      "or 5, 6 (a ramp), or 3, 4, 7, 8 (current or voltage limit)");
  // 0x6007: 0 nothing, 2 disable voltage (the table coasts): not allowed
  // here, a lost host must stop the table
  TURNCAL_TRY(r.integer("abort_connection_option_code", ac, 1, 3));
  if (ac == 2)
    return r.error_at(*t.get("abort_connection_option_code"), "abort_connection_option_code",
                      "2 (disable voltage) lets the table coast when the drive loses the host: "
                      "use 3 (quick stop) or 1 (fault, the drive's fault reaction)");
  c.quick_stop_option_code = static_cast<std::int16_t>(qs);
  c.abort_connection_option_code = static_cast<std::int16_t>(ac);
  struct Ms {
    const char* key;
    double* out;
    double lo, hi;
  };
  for (const Ms& m : {Ms{"host_heartbeat_ms", &c.host_heartbeat_period_s, 1, 65535},
                      Ms{"host_heartbeat_consumer_ms", &c.host_heartbeat_timeout_s, 1, 65535},
                      Ms{"drive_heartbeat_ms", &c.drive_heartbeat_period_s, 1, 65535},
                      Ms{"drive_heartbeat_timeout_ms", &c.drive_heartbeat_timeout_s, 1, 65535},
                      Ms{"sync_period_ms", &c.sync_period_s, 0, 10000},
                      Ms{"tpdo_event_timer_ms", &c.tpdo_event_timer_s, 1, 65535},
                      Ms{"sdo_timeout_ms", &c.sdo_timeout_s, 1, 60000},
                      Ms{"boot_timeout_ms", &c.boot_timeout_s, 1, 600000}}) {
    double ms = *m.out * 1e3;
    TURNCAL_TRY(r.number(m.key, ms, m.lo, m.hi));
    *m.out = ms * 1e-3;
  }
  // a consumer time within our period would time out between two heartbeats
  if (!(c.host_heartbeat_timeout_s > c.host_heartbeat_period_s)) {
    const char* key = t.get("host_heartbeat_consumer_ms") != nullptr ? "host_heartbeat_consumer_ms"
                                                                     : "host_heartbeat_ms";
    return r.error_at(*t.get(key), key,
                      "the drive's consumer time must be longer than our heartbeat period");
  }
  if (!(c.drive_heartbeat_timeout_s > c.drive_heartbeat_period_s)) {
    const char* key = t.get("drive_heartbeat_timeout_ms") != nullptr ? "drive_heartbeat_timeout_ms"
                                                                     : "drive_heartbeat_ms";
    return r.error_at(*t.get(key), key,
                      "the wait for the drive's heartbeat must be longer than its period");
  }
  TURNCAL_TRY(r.boolean("configure_mapping", c.configure_mapping));
  TURNCAL_TRY(r.boolean("velocity_pdo", c.velocity_pdo));
  TURNCAL_TRY(r.boolean("change_set_immediately", c.change_set_immediately));
  return read_emcy_warnings(r, t, c);
}

/// Each table protocol's [table.NAME] section (kTableProtocols' rows, in
/// their order): its reader, or none for a protocol that has none.
struct TableSection {
  std::string_view name;
  Status (*read)(const toml::table& t, const std::string& file, TableProtocol& table);
};

constexpr std::array<TableSection, kTableProtocols.size()> kTableSections = {{
    {"reference", nullptr},
    {"cia402", [](const toml::table& t, const std::string& file,
                  TableProtocol& table) { return read_cia402(t, file, table.cia402); }},
}};

constexpr bool table_sections_match() {
  for (std::size_t i = 0; i < kTableProtocols.size(); ++i)
    if (kTableSections[i].name != kTableProtocols[i]) return false;
  return true;
}
static_assert(table_sections_match(), "kTableSections' rows are not kTableProtocols'");

Status read_table(const toml::table& t, const std::string& file, TableProtocol& table) {
  Reader r(t, file, "table.");
  std::vector<std::string_view> keys = {"protocol"};
  for (const TableSection& s : kTableSections)
    if (s.read != nullptr) keys.push_back(s.name);
  TURNCAL_TRY(r.no_unknown_keys(keys));
  TURNCAL_TRY(choice(r, "protocol", kTableProtocols, table.name));
  for (const TableSection& s : kTableSections) {
    const toml::node* n = s.read != nullptr ? t.get(s.name) : nullptr;
    if (n == nullptr) continue;
    const std::string name(s.name);
    if (!n->is_table()) return r.error_at(*n, name, "expected a table");
    if (table.name != s.name)
      return r.error_at(*n, name,
                        "[table." + name + "] is for protocol = \"" + name +
                            "\", and protocol is \"" + table.name + "\"");
    TURNCAL_TRY(s.read(*n->as_table(), file, table));
  }
  return Status{Ok{}};
}

Status read_stand(const toml::table& t, const std::string& file, StandConfig& s) {
  Reader r(t, file, "stand.");
  TURNCAL_TRY(r.no_unknown_keys({"heading_offset_deg", "max_rate_dps", "max_accel_dps2",
                                 "angle_min_deg", "angle_max_deg", "time_scale", "unit",
                                 "position_tolerance_deg", "real_time_floor_ms"}));
  TURNCAL_TRY(r.string("unit", s.unit));
  StandLimits& l = s.limits;
  double off = s.heading_offset_rad / kDegRad, rate = l.max_rate_rps / kDegRad,
         acc = l.max_accel_rps2 / kDegRad, lo = -1e6, hi = 1e6,
         tol = l.position_tolerance_rad / kDegRad;
  TURNCAL_TRY(r.number("heading_offset_deg", off, -360, 360));
  TURNCAL_TRY(r.number("max_rate_dps", rate, 0.01, 1000));
  TURNCAL_TRY(r.number("max_accel_dps2", acc, 0.01, 10000));
  TURNCAL_TRY(r.number("angle_min_deg", lo, -1e6, 1e6));
  TURNCAL_TRY(r.number("angle_max_deg", hi, -1e6, 1e6));
  TURNCAL_TRY(r.number("time_scale", s.time_scale, kMinTimeScale, kMaxTimeScale));
  TURNCAL_TRY(r.number("real_time_floor_ms", s.real_time_floor_ms, 0, 60000));
  TURNCAL_TRY(r.number("position_tolerance_deg", tol, 1e-4, 10));
  if (!(lo < hi)) {
    // name whichever of the two the file sets (one alone can cross the other's default)
    const bool max_set = t.get("angle_max_deg") != nullptr;
    const char* key = max_set ? "angle_max_deg" : "angle_min_deg";
    return r.error_at(*t.get(key), key,
                      max_set ? "must be above angle_min_deg" : "must be below angle_max_deg");
  }
  s.heading_offset_rad = off * kDegRad;
  l.max_rate_rps = rate * kDegRad;
  l.max_accel_rps2 = acc * kDegRad;
  l.position_tolerance_rad = tol * kDegRad;
  if (t.get("angle_min_deg") != nullptr) l.angle_min_rad = lo * kDegRad;
  if (t.get("angle_max_deg") != nullptr) l.angle_max_rad = hi * kDegRad;
  return Status{Ok{}};
}

Status read_daemon(const toml::table& t, const std::string& file, DaemonConfig& d) {
  Reader r(t, file, "daemon.");
  TURNCAL_TRY(r.no_unknown_keys({"state_directory", "socket", "socket_group", "profile",
                                 "profiles_directory", "observe", "heartbeat_hz", "stale_floor_ms",
                                 "max_clients", "client_idle_s", "report_reserve_mib",
                                 "keep_logs_days", "max_logs_mib"}));
  std::string state = d.state_directory.string(), sock = d.socket.string(), prof, profiles;
  TURNCAL_TRY(r.string("state_directory", state));
  TURNCAL_TRY(r.string("socket", sock));
  // a socket is a file: a name, not a folder (in the working directory
  // when the name is relative)
  if (t.get("socket") != nullptr && std::filesystem::path(sock).filename().empty())
    return r.error_at(*t.get("socket"), "socket", "'" + sock + "' names no file");
  TURNCAL_TRY(r.string("socket_group", d.socket_group));
  TURNCAL_TRY(r.string("profile", prof));
  TURNCAL_TRY(r.string("profiles_directory", profiles));
  TURNCAL_TRY(r.boolean("observe", d.observe));
  TURNCAL_TRY(r.integer("max_clients", d.max_clients, 1, 256));
  TURNCAL_TRY(r.number("client_idle_s", d.client_idle_s, 1, 3600));
  TURNCAL_TRY(r.number("report_reserve_mib", d.report_reserve_mib, 0, 1024));
  TURNCAL_TRY(r.number("keep_logs_days", d.keep_logs_days, 0, 36500));
  TURNCAL_TRY(r.number("max_logs_mib", d.max_logs_mib, 0, 1e9));
  TURNCAL_TRY(r.number("heartbeat_hz", d.heartbeat_hz, 2, 100));
  TURNCAL_TRY(r.number("stale_floor_ms", d.stale_floor_ms, 0, 1000));
  const std::filesystem::path base = std::filesystem::path(file).parent_path();
  d.state_directory = state;
  d.socket = sock;
  if (!prof.empty())
    d.profile =
        std::filesystem::path(prof).is_absolute() ? std::filesystem::path(prof) : base / prof;
  if (!profiles.empty())
    d.profiles_directory = std::filesystem::path(profiles).is_absolute()
                               ? std::filesystem::path(profiles)
                               : base / profiles;
  return Status{Ok{}};
}

Status read_tolerances(const toml::table& t, const std::string& file, std::vector<Tolerance>& out) {
  for (auto&& [k, v] : t) {
    const std::string name(k.str());
    if (display_unit(name).first.empty())
      return make_error("unknown key 'tolerances." + name + "': not a parameter of the report",
                        pos_of(k.source(), file));
    if (!v.is_table())
      return make_error("key 'tolerances." + name + "': expected a table like { max_abs = 1 }",
                        pos_of(v.source(), file));
    Reader r(*v.as_table(), file, "tolerances." + name + ".");
    TURNCAL_TRY(r.no_unknown_keys({"max_abs", "max_sigma"}));
    Tolerance tol{name};
    TURNCAL_TRY(r.number("max_abs", tol.max_abs, 0, 1e12));
    TURNCAL_TRY(r.number("max_sigma", tol.max_sigma, 0, 1e12));
    out.push_back(tol);
  }
  return Status{Ok{}};
}

}  // namespace

std::pair<std::string_view, double> display_unit(std::string_view parameter) {
  return est::display_unit(parameter);
}

Result<Config> parse_config(std::string_view text, const std::string& file) {
  toml::table root;
  try {
    root = toml::parse(text, file);
  } catch (const toml::parse_error& e) {
    return make_error(std::string(e.description()), pos_of(e.source(), file));
  }
  Config cfg;
  cfg.source = file;
  cfg.daemon.profile = std::filesystem::path(file).parent_path() / "profiles" / "tactical.toml";
  cfg.daemon.profiles_directory = std::filesystem::path(file).parent_path() / "profiles";
  for (auto&& [k, v] : root) {
    if (k.str() != "can" && k.str() != "stand" && k.str() != "daemon" && k.str() != "tolerances" &&
        k.str() != "ins" && k.str() != "table")
      return make_error("unknown section or key '" + std::string(k.str()) + "'",
                        pos_of(k.source(), file));
  }
  Status st{Ok{}};
  if (const toml::table* t = section(root, "stand", st, file))
    TURNCAL_TRY(read_stand(*t, file, cfg.stand));
  TURNCAL_TRY(st);
  if (const toml::table* t = section(root, "daemon", st, file))
    TURNCAL_TRY(read_daemon(*t, file, cfg.daemon));
  TURNCAL_TRY(st);
  if (const toml::table* t = section(root, "tolerances", st, file))
    TURNCAL_TRY(read_tolerances(*t, file, cfg.tolerances));
  TURNCAL_TRY(st);
  toml::table empty;
  const toml::node* can = root.get("can");
  if (can != nullptr && !can->is_table())
    return make_error("key 'can': expected a table", pos_of(can->source(), file));
  auto c = read_can(can != nullptr ? *can->as_table() : empty, file);
  if (!c) return std::move(c).error();
  cfg.can = std::move(c).value();
  if (const toml::table* t = section(root, "ins", st, file))
    TURNCAL_TRY(read_ins(*t, file, cfg.can.ins));
  TURNCAL_TRY(st);
  if (const toml::table* t = section(root, "table", st, file))
    TURNCAL_TRY(read_table(*t, file, cfg.can.table));
  TURNCAL_TRY(st);
  // A drive's own ramps move the table, whatever a plan asks: they may not
  // exceed what the stand allows.
  if (cfg.can.table.is_cia402()) {
    // where the first key of `paths` given stands; the file alone if none
    const auto where = [&](std::initializer_list<const char*> paths) {
      for (const char* path : paths)
        if (const toml::node* n = root.at_path(path).node()) return pos_of(n->source(), file);
      return SourcePos{file, 0, 0};
    };
    const Cia402Settings& d = cfg.can.table.cia402;
    for (auto [key, path, v] :
         {std::tuple{"profile_acceleration_dps2", "table.cia402.profile_acceleration_dps2",
                     d.profile_acceleration_rps2},
          {"profile_deceleration_dps2", "table.cia402.profile_deceleration_dps2",
           d.profile_deceleration_rps2}}) {
      if (v <= cfg.stand.limits.max_accel_rps2 * (1 + 1e-9)) continue;
      char msg[200];
      std::snprintf(msg, sizeof msg,
                    "key 'table.cia402.%s': the drive's %g deg/s^2 exceed the stand's "
                    "max_accel_dps2 of %g deg/s^2",
                    key, v / kDegRad, cfg.stand.limits.max_accel_rps2 / kDegRad);
      return make_error(msg, where({path, "stand.max_accel_dps2"}));
    }
    // SYNC goes out from the daemon's timer: a shorter period would be
    // the timer's without a word
    if (d.sync_period_s > 0 && d.sync_period_s < 1 / cfg.daemon.heartbeat_hz - 1e-9) {
      char msg[200];
      std::snprintf(msg, sizeof msg,
                    "key 'table.cia402.sync_period_ms': %g ms is shorter than the daemon's "
                    "timer period (daemon.heartbeat_hz = %g: %g ms), from which SYNC goes out",
                    d.sync_period_s * 1e3, cfg.daemon.heartbeat_hz, 1e3 / cfg.daemon.heartbeat_hz);
      return make_error(msg, where({"table.cia402.sync_period_ms"}));
    }
    // TPDO1's positions are the table's rate and its rest (the master's
    // check holds the same; here with the key's line)
    const bool sync = d.sync_period_s > 0;
    if (const double period = sync ? d.sync_period_s : d.tpdo_event_timer_s;
        (sync || d.configure_mapping) && !tpdo_period_fits(period, d.drive_heartbeat_timeout_s)) {
      char msg[300];
      std::snprintf(msg, sizeof msg,
                    "key 'table.cia402.%s': TPDO1's period of %g ms is more than half the "
                    "drive heartbeat timeout (drive_heartbeat_timeout_ms = %g): the table's rate "
                    "and rest, from its positions, would be unknown between two",
                    sync ? "sync_period_ms" : "tpdo_event_timer_ms", period * 1e3,
                    d.drive_heartbeat_timeout_s * 1e3);
      return make_error(
          msg, where({sync ? "table.cia402.sync_period_ms" : "table.cia402.tpdo_event_timer_ms",
                      "table.cia402.drive_heartbeat_timeout_ms"}));
    }
    if (const double per_turn = d.counts_per_revolution * d.gear_ratio;
        per_turn < kMinCountsPerTableTurn) {
      char msg[300];
      std::snprintf(msg, sizeof msg,
                    "key 'table.cia402.counts_per_revolution': %g counts per table turn "
                    "(counts_per_revolution x gear_ratio) is under %g: a table at rest would "
                    "take over a second to tell from a count of dither",
                    per_turn, kMinCountsPerTableTurn);
      return make_error(msg,
                        where({"table.cia402.counts_per_revolution", "table.cia402.gear_ratio"}));
    }
  }
  return cfg;
}

Result<Config> load_config(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error("cannot open configuration file", SourcePos{path, 0, 0});
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_config(ss.str(), path);
}

namespace {

/// The reference stand's protocol (can-icd.md) is the one whose table
/// commands are TBL_Command: a table command role names it.
constexpr std::string_view kReferenceTableCommand = "TBL_Command";
/// Revision 2 made TBL_Command.Target 1e-5 deg (it was 1e-6 deg).
constexpr int kReferenceIcdRevision = 2;

bool reference_protocol(const CanConfig& cfg) {
  for (Role r : {Role::TableCommand, Role::TableCommandSeq, Role::TableCommandTarget,
                 Role::TableCommandRateLimit})
    if (cfg.roles[static_cast<std::size_t>(r)].message == kReferenceTableCommand) return true;
  return false;
}

/// The revision a VERSION string states as "ICD N" ("turncal reference
/// stand ICD 2"); -1 when it states none.
int icd_revision(std::string_view version) {
  for (std::size_t at = version.find("ICD"); at != std::string_view::npos;
       at = version.find("ICD", at + 1)) {
    if (at > 0 && std::isalnum(static_cast<unsigned char>(version[at - 1])) != 0) continue;
    std::size_t i = at + 3;
    if (i >= version.size() || version[i] != ' ') continue;
    while (i < version.size() && version[i] == ' ') ++i;
    const std::size_t digits = i;
    int rev = 0;
    while (i < version.size() && std::isdigit(static_cast<unsigned char>(version[i])) != 0 &&
           i - digits < 6)
      rev = rev * 10 + (version[i++] - '0');
    if (i == digits) continue;
    if (i < version.size() &&
        (std::isalnum(static_cast<unsigned char>(version[i])) != 0 || version[i] == '.'))
      continue;  // "ICD 2.1", "ICD 2b": not a plain revision
    return rev;
  }
  return -1;
}

/// A DBC that defines the reference protocol's table command must state
/// the ICD revision it follows: an older file kept in place would scale
/// every move's Target by a factor of ten.
Status check_reference_revision(const CanConfig& cfg, const can::Database& db,
                                const std::string& path) {
  if (!reference_protocol(cfg) || db.find(kReferenceTableCommand) == nullptr) return Status{Ok{}};
  if (icd_revision(db.version) == kReferenceIcdRevision) return Status{Ok{}};
  const std::string rev = std::to_string(kReferenceIcdRevision);
  const std::string stated = db.version_line == 0 ? "it has no VERSION"
                                                  : "its VERSION \"" + db.version +
                                                        "\" does not state ICD revision " + rev;
  return make_error(
      "this DBC describes the reference stand's " + std::string(kReferenceTableCommand) + " but " +
          stated + " (as VERSION \"turncal reference stand ICD " + rev +
          "\" does): since revision " + rev +
          " TBL_Command.Target is 1e-5 deg, not 1e-6 deg, and a file of an older revision " +
          "would move the table ten times too far",
      SourcePos{path, db.version_line, 0});
}

}  // namespace

Result<can::Database> load_databases(const CanConfig& cfg) {
  can::Database merged;
  std::vector<std::string> origin;
  for (const auto& path : cfg.dbc_files) {
    auto db = can::load_dbc(path.string());
    if (!db) return std::move(db).error();
    TURNCAL_TRY(check_reference_revision(cfg, *db, path.string()));
    if (merged.version.empty()) merged.version = db->version;
    for (auto& n : db->nodes) merged.nodes.push_back(n);
    merged.node_long_names.merge(db->node_long_names);
    for (auto& w : db->warnings) merged.warnings.push_back(std::move(w));
    for (auto& w : db->left_out) merged.left_out.push_back(std::move(w));
    for (auto& m : db->messages) {
      for (std::size_t i = 0; i < merged.messages.size(); ++i) {
        const can::Message& o = merged.messages[i];
        if ((o.id == m.id && o.extended == m.extended) || o.name == m.name)
          return make_error(
              "message '" + m.name + "' is defined in both " + origin[i] + " and " + path.string(),
              SourcePos{path.string(), m.line, 0});
      }
      merged.messages.push_back(std::move(m));
      origin.push_back(path.string());
    }
  }
  return merged;
}

Result<double> velocity_unit(const can::Signal& sig) {
  const std::string& u = sig.unit;
  if (u.empty() || u == "m/s" || u == "m/sec" || u == "mps") return 1.0;
  if (u == "cm/s") return 0.01;
  if (u == "mm/s") return 1e-3;
  if (u == "km/h" || u == "kph") return 1 / 3.6;
  if (u == "ft/s" || u == "fps") return 0.3048;
  if (u == "kn" || u == "kt" || u == "knot" || u == "knots") return 1852.0 / 3600.0;
  return make_error("unit '" + u +
                    "' is no velocity unit turncal knows (m/s, cm/s, mm/s, km/h, ft/s, kn)");
}

Result<TimeScale> time_unit(const can::Signal& sig) {
  const std::string& u = sig.unit;
  TimeScale s;
  if (u.empty() || u == "us" || u == "\xC2\xB5s" || u == "usec")
    s.to_us = 1;
  else if (u == "ms" || u == "msec")
    s.to_us = 1e3;
  else if (u == "s" || u == "sec")
    s.to_us = 1e6;
  else
    return make_error("unit '" + u + "' is no time unit turncal knows (us, ms, s)");
  // an unsigned integer counter wraps after 2^length steps of its factor
  s.range_us = sig.type == can::ValueType::Integer && !sig.is_signed && sig.length < 64
                   ? std::ldexp(1.0, static_cast<int>(sig.length)) * sig.factor * s.to_us
                   : std::numeric_limits<double>::infinity();
  return s;
}

std::vector<std::string> unitless_role_warnings(const RoleMap& roles) {
  std::vector<std::string> out;
  for (const Role r : {Role::InsVelEast, Role::InsVelNorth, Role::InsVelEastTimeTag,
                       Role::InsVelNorthTimeTag, Role::InsStatusTimeTag, Role::InsTime}) {
    const ResolvedRole& rr = roles[r];
    if (rr.signal == nullptr || !rr.signal->unit.empty()) continue;
    const bool speed = r == Role::InsVelEast || r == Role::InsVelNorth;
    out.push_back(rr.message->name + "." + rr.signal->name + " (role " + std::string(role_key(r)) +
                  ") has no unit in the DBC: read as " + (speed ? "m/s" : "microseconds"));
  }
  return out;
}

bool role_used(const CanConfig& cfg, Role role) {
  switch (role_row(role).needed) {
    case Needed::Always:
      return true;
    case Needed::InsTag:
      return cfg.ins.time == InsTimeSource::Tag;
    case Needed::InsNorthTag:
      // one tag serves both components of one frame
      return cfg.ins.time == InsTimeSource::Tag &&
             !(cfg.roles[static_cast<std::size_t>(Role::InsVelNorth)].message ==
                   cfg.roles[static_cast<std::size_t>(Role::InsVelEast)].message &&
               cfg.roles[static_cast<std::size_t>(Role::InsVelNorthTimeTag)].empty());
    case Needed::InsTimeFrame:
      return cfg.ins.time == InsTimeSource::TimeFrame;
    case Needed::ReferenceTable:
      return !cfg.table.is_cia402();
    case Needed::Cia402:
      return cfg.table.is_cia402();
    case Needed::Cia402Velocity:
      return cfg.table.is_cia402() && cfg.table.cia402.velocity_pdo;
  }
  return true;
}

Result<RoleMap> resolve_roles(const CanConfig& cfg, const can::Database& db) {
  // " (turncal.toml:12)": where the configuration names the role
  auto at = [](const SourcePos& p) {
    if (p.file.empty()) return std::string();
    return " (" + p.file + (p.line != 0 ? ":" + std::to_string(p.line) : std::string()) + ")";
  };
  RoleMap map;
  for (std::size_t i = 0; i < kRoleCount; ++i) {
    const Role role = static_cast<Role>(i);
    if (!role_used(cfg, role)) continue;
    const SignalRef& ref = cfg.roles[i];
    const std::string key = "can.roles." + std::string(kRoles[i].key);
    if (ref.empty()) {
      if (role_row(role).optional) continue;
      return make_error(
          "key '" + key + "': needed by the INS layout and the table protocol, but none is given",
          ref.where);
    }
    const can::Message* m = db.find(ref.message);
    if (m == nullptr) {
      for (const can::Database::LeftOut& l : db.left_out)
        if (l.message == ref.message)
          return make_error("key '" + key + "'" + at(ref.where) + ": " + l.why.text, l.why.where);
      return make_error("key '" + key + "': no message '" + ref.message + "' in the DBC",
                        ref.where);
    }
    // a message with an SG_ line that could not be read is not the
    // message the file meant: a role may not be in it
    if (!m->unread.empty())
      return make_error("key '" + key + "'" + at(ref.where) + ": message '" + m->name +
                            "' was not read whole, so no role may be in it: " + m->unread[0].text,
                        m->unread[0].where);
    const can::Signal* s = m->find_signal(ref.signal);
    if (s == nullptr)
      return make_error(
          "key '" + key + "': message '" + ref.message + "' has no signal '" + ref.signal + "'",
          ref.where);
    // what the roles do not use may be unusable; what they use may not
    if (!s->usable)
      return make_error("key '" + key + "'" + at(ref.where) + ": signal '" + m->name + "." +
                            s->name + "' cannot be used: " + s->problem,
                        SourcePos{m->file, s->line, 0});
    if (role == Role::InsVelEast || role == Role::InsVelNorth)
      if (auto k = velocity_unit(*s); !k)
        return make_error("key '" + key + "': " + k.error().message, ref.where);
    if (role == Role::InsVelEastTimeTag || role == Role::InsVelNorthTimeTag ||
        role == Role::InsStatusTimeTag || role == Role::InsTime)
      if (auto k = time_unit(*s); !k)
        return make_error("key '" + key + "': " + k.error().message, ref.where);
    map.roles[i] = ResolvedRole{m, s, static_cast<std::size_t>(s - m->signals.data())};
  }
  // One message is either sent or received by the host, never both.
  for (std::size_t i = 0; i < kRoleCount; ++i)
    for (std::size_t j = 0; j < kRoleCount; ++j)
      if (map.roles[i].message != nullptr && map.roles[i].message == map.roles[j].message &&
          role_is_output(static_cast<Role>(i)) != role_is_output(static_cast<Role>(j)))
        return make_error("key 'can.roles." + std::string(kRoles[i].key) + "': message '" +
                              map.roles[i].message->name + "' is used both to send and to receive",
                          cfg.roles[i].where);
  const ResolvedRole& east = map[Role::InsVelEast];
  const ResolvedRole& north = map[Role::InsVelNorth];
  if (cfg.ins.time != InsTimeSource::Tag && east.message != north.message)
    return make_error(
        "key 'can.roles.ins_vel_north': without time tags ([ins] time is not "
        "\"tag\") the East and North velocity must be in one frame, or the two "
        "halves of a sample cannot be told apart",
        cfg.roles[static_cast<std::size_t>(Role::InsVelNorth)].where);
  if (cfg.ins.time == InsTimeSource::TimeFrame && map[Role::InsTime].message == east.message)
    return make_error(
        "key 'can.roles.ins_time': the time frame is the velocity's own; that is "
        "[ins] time = \"tag\"",
        cfg.roles[static_cast<std::size_t>(Role::InsTime)].where);
  return map;
}

can::Frame RoleMap::encode(Role any, std::initializer_list<std::pair<Role, double>> values) const {
  const can::Message& m = *(*this)[any].message;
  std::vector<double> v(m.signals.size(), 0.0);
  for (const auto& [r, x] : values) v[(*this)[r].signal_index] = x;
  return can::FrameCodec::encode(m, v);
}

Result<can::Frame> RoleMap::encode_checked(
    Role any, std::initializer_list<std::pair<Role, double>> values) const {
  const can::Message& m = *(*this)[any].message;
  std::vector<double> v(m.signals.size(), std::numeric_limits<double>::quiet_NaN());
  for (const auto& [r, x] : values) {
    if (std::isnan(x))  // NaN would leave the signal 0: a command nobody meant
      return make_error(m.name + "." + (*this)[r].signal->name + ": the value is not a number");
    v[(*this)[r].signal_index] = x;
  }
  return can::FrameCodec::encode_checked(m, v);
}

std::vector<std::pair<std::uint32_t, bool>> RoleMap::receive_ids(bool ins) const {
  std::vector<std::pair<std::uint32_t, bool>> out;
  for (std::size_t i = 0; i < kRoleCount; ++i) {
    const Role r = static_cast<Role>(i);
    if (roles[i].message == nullptr || role_is_output(r) || role_is_ins(r) != ins) continue;
    const std::pair<std::uint32_t, bool> id{roles[i].message->id, roles[i].message->extended};
    if (std::find(out.begin(), out.end(), id) == out.end()) out.push_back(id);
  }
  return out;
}

}  // namespace turncal
