// turncal.toml validated into plain structs at the edge (style.md, 10).
// Errors name file, line and key. No toml++ in this header.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/result.hpp"

namespace turncal {

/// What a CAN signal means to turncal. Each role names one signal of one
/// message of the DBC ("Message.Signal").
enum class Role : std::uint8_t {
  InsVelEast,          ///< INS velocity East, m/s
  InsVelEastTimeTag,   ///< INS time tag of the East sample
  InsVelNorth,         ///< INS velocity North, m/s
  InsVelNorthTimeTag,  ///< INS time tag of the North sample
  InsMode,             ///< INS mode (idle, aligning, navigating, fault)
  InsStatusTimeTag,    ///< INS time tag of the status frame
  InsAlignRemaining,   ///< alignment time left, s
  InsTime,             ///< INS device time of a separate time frame ([ins] time = "time-frame")
  InsCommand,          ///< command to the INS
  InsCommandAlignDuration,  ///< alignment duration, s
  InsCommandHeading,        ///< initial heading of axis z2, deg clockwise from North
  InsCommandSeq,            ///< sequence number of the INS command
  EncoderAngle,             ///< table angle, deg counter-clockwise seen from above
  EncoderTimeTag,           ///< table clock time tag of the encoder sample
  TableState,               ///< table state
  TableAck,                 ///< sequence number of the last accepted table command
  TableFault,               ///< table fault code
  TableRate,                ///< table rate, deg/s
  TableCommand,             ///< command to the table
  TableCommandSeq,          ///< sequence number of the table command
  TableCommandTarget,       ///< target angle, deg
  TableCommandRateLimit,    ///< rate limit, deg/s
  HeartbeatCounter,         ///< host heartbeat rolling counter
  HeartbeatState,           ///< host state in the heartbeat
  // a CiA 402 drive's process data ([table] protocol = "cia402"), as its PDOs map them
  TableControlword,     ///< controlword 0x6040 in RPDO1 (u16, unscaled)
  TableTargetPosition,  ///< target position 0x607A in RPDO1 (s32 counts, unscaled)
  TableStatusword,      ///< statusword 0x6041 in TPDO1 (u16, unscaled)
  TablePositionActual,  ///< position actual 0x6064 in TPDO1 (s32 counts, unscaled)
  TableVelocityActual,  ///< velocity actual 0x606C in TPDO2 (s32 counts/s), if mapped
};
inline constexpr std::size_t kRoleCount = static_cast<std::size_t>(Role::TableVelocityActual) + 1;

/// Configuration key of a role ("ins_vel_east", ...).
std::string_view role_key(Role role);
/// True for roles the host sends (commands, heartbeat).
bool role_is_output(Role role);
/// Which device a role belongs to: true for the INS, false for the table side.
bool role_is_ins(Role role);

struct SignalRef {
  std::string message;
  std::string signal;
  SourcePos where;  ///< the key in the configuration, for errors found later
  [[nodiscard]] bool empty() const { return message.empty(); }
};

/// Where an INS velocity sample's device time comes from ([ins] time).
enum class InsTimeSource : std::uint8_t {
  Tag,        ///< a time tag in each velocity frame (the reference INS)
  TimeFrame,  ///< a separate device time frame (role ins_time) just before the velocity
  Receive,    ///< none: the kernel receive time, on a clock of the nominal rate fitted to it
};

/// The INS's output layout ([ins]): velocity in navigation axes, each
/// component a role (in one frame or two), its sign and its time.
struct InsLayout {
  InsTimeSource time = InsTimeSource::Tag;
  /// +1, or -1 for an INS whose signal counts the other way (West, South).
  double east_sign = 1;
  double north_sign = 1;
  /// Nominal velocity rate, Hz (time = "receive": the clock's period); 0: none.
  double velocity_rate_hz = 0;
  /// A time frame stamps the velocity that follows it within this, real s.
  double time_frame_max_age_s = 0.005;
};

/// A CiA 402 servo drive in profile position mode ([table.cia402]), the
/// settings of the CANopen master (drivers/cia402.hpp) in SI units; the
/// file gives them in ms, deg/s^2 and counts.
struct Cia402Settings {
  std::uint8_t node_id = 1;               ///< the drive's CANopen node
  std::uint8_t host_node_id = 127;        ///< ours, for our heartbeat (0x700 + host)
  double counts_per_revolution = 131072;  ///< encoder counts per motor turn
  double gear_ratio = 1;                  ///< motor turns per table turn
  /// The drive's position counts rise as the table turns clockwise seen
  /// from above (counts_increase = "clockwise"): the table angle is
  /// counter-clockwise (can-icd.md, model.md), so every count is negated.
  bool counts_clockwise = false;
  double profile_acceleration_rps2 = 0.17453292519943295;    ///< 0x6083, 10 deg/s^2
  double profile_deceleration_rps2 = 0.17453292519943295;    ///< 0x6084, 10 deg/s^2
  double quick_stop_deceleration_rps2 = 1.5707963267948966;  ///< 0x6085, 90 deg/s^2
  std::int16_t quick_stop_option_code = 6;                   ///< 0x605A
  std::int16_t abort_connection_option_code =
      3;                                   ///< 0x6007: 1 fault, 2 disable voltage, 3 quick stop
  double host_heartbeat_period_s = 0.1;    ///< our heartbeat
  double host_heartbeat_timeout_s = 0.5;   ///< the drive's consumer time (0x1016:01)
  double drive_heartbeat_period_s = 0.1;   ///< the drive's producer time (0x1017)
  double drive_heartbeat_timeout_s = 0.3;  ///< how long we wait for it
  double sync_period_s = 0;                ///< > 0: we produce SYNC and TPDO1 follows it
  double tpdo_event_timer_s = 0.01;        ///< TPDO1's event timer when the mapping is written
  bool configure_mapping = false;          ///< write the PDO mappings from the DBC's layout
  bool velocity_pdo = false;            ///< velocity actual from TPDO2 (role table_velocity_actual)
  bool change_set_immediately = false;  ///< controlword bit 5 with every set-point
  double sdo_timeout_s = 0.5;
  double boot_timeout_s = 2.0;  ///< from the NMT reset to the drive's boot-up
  /// EMCY codes that only warn, as ranges (both ends in); none given (no
  /// key): the master's defaults (drivers/cia402.hpp, kDefaultEmcyWarnings);
  /// an empty list: every code a fault.
  std::optional<std::vector<std::pair<std::uint16_t, std::uint16_t>>> emcy_warnings;
};

/// The turntable protocols [table] protocol may name, each once: the
/// configuration reads its [table.NAME] section by this table's row
/// (config.cpp), and the devices' factory makes its driver by its own row
/// of the same name (drivers/table/protocols.cpp); static_asserts hold both
/// to this order. A new protocol is its driver's file and a row in each.
/// (Two tables, not one: the configuration is below the drivers.)
inline constexpr std::array<std::string_view, 2> kTableProtocols = {
    "reference",  ///< can-icd.md's TBL_* frames
    "cia402",     ///< a CiA 402 drive, its CANopen master ours
};

/// The turntable's protocol ([table]).
struct TableProtocol {
  /// "reference": can-icd.md's TBL_* frames; "cia402": a CiA 402 drive.
  std::string name = "reference";
  Cia402Settings cia402;  ///< [table.cia402], when name is "cia402"
  [[nodiscard]] bool is_cia402() const { return name == "cia402"; }
};

struct CanConfig {
  std::string ins_interface = "vcan0";
  std::string table_interface = "vcan0";
  std::vector<std::filesystem::path> dbc_files;  ///< absolute, or relative to the config file
  bool fd = false;                               ///< open the sockets for CAN FD
  std::uint32_t tx_queue_frames = 256;           ///< send queue bound per socket, frames
  std::uint32_t rx_buffer_bytes = 0;             ///< SO_RCVBUF, bytes; 0: kernel default
  /// INS velocity beyond this (either component) is no still INS's error but
  /// a garbled frame: counted and skipped, m/s.
  double max_ins_velocity_mps = 1000;
  /// A stream with more than this fraction of its frames implausible fails
  /// the run.
  double implausible_fraction = 0.01;
  /// A role given as "" is none; the roles the INS layout and the table
  /// protocol do not use are not resolved.
  std::array<SignalRef, kRoleCount> roles;
  InsLayout ins;
  TableProtocol table;
};

/// The table's limits on the stand; every table command is checked
/// against them before it goes out.
struct StandLimits {
  double max_rate_rps = 0.5235987755982988;    ///< 30 deg/s
  double max_accel_rps2 = 0.5235987755982988;  ///< 30 deg/s^2
  double angle_min_rad = -1e9;                 ///< multi-turn table angle, as the host unwraps it
  double angle_max_rad = 1e9;
  /// The host's own checks of the encoder: a move may pass its target, the
  /// table may stop off it, or drift with no move commanded, by this much
  /// at most (0.1 deg); more is a fault and a quick stop.
  double position_tolerance_rad = 0.0017453292519943296;
  [[nodiscard]] bool contains(double angle_rad) const {
    return angle_rad >= angle_min_rad && angle_rad <= angle_max_rad;
  }
};

/// The range of [stand] time_scale, and of a report's time_base.scale that
/// a replay takes: a stand run at most ten thousand times faster or a
/// thousand times slower than real time.
inline constexpr double kMinTimeScale = 1e-3;
inline constexpr double kMaxTimeScale = 1e4;

/// The stand's mounting and limits ([stand]).
struct StandConfig {
  double heading_offset_rad = 0;  ///< heading of z2 = heading_offset - table angle
  StandLimits limits;
  /// Stand seconds per real second: 1 on a real stand; N for a virtual
  /// stand run N times faster than real time.
  double time_scale = 1;
  /// On a stand faster than real time (time_scale > 1), every wait for the
  /// stand's answer lasts this much real time longer, ms: a stall of the
  /// host's machine (which the time scale makes N times longer in stand
  /// time) is then no device's fault. Not applied at time_scale 1 or less.
  double real_time_floor_ms = 1000;
  /// The INS under test when the operator names none at start (a fixture
  /// that holds one unit); empty: none. Reports are indexed by it.
  std::string unit;
};

struct DaemonConfig {
  std::filesystem::path state_directory = "/var/lib/turncal";  ///< logs and reports
  std::filesystem::path socket = "/run/turncal/control.sock";  ///< unless socket-activated
  std::string socket_group;  ///< group of the control socket; empty: the daemon's
  std::filesystem::path
      profile;  ///< the plan a start runs unless it names one (set by parse_config)
  /// Where a plan a start names without a path comes from (set by
  /// parse_config: "profiles" beside the configuration file by default).
  std::filesystem::path profiles_directory;
  bool observe = false;  ///< follow a stand someone else drives
  double heartbeat_hz = 10;
  std::uint32_t max_clients =
      16;  ///< control connections at once; a new one closes another (make_room), or is refused
  /// A control client that leaves replies unread this long, or sends nothing
  /// and watches nothing this long, is dropped (real seconds).
  double client_idle_s = 60;
  /// Disk space reserved for a run's report when it starts, MiB: a disk that
  /// fills during the run can still say why.
  double report_reserve_mib = 8;
  /// Retention, applied before a run starts: run logs older than this (days)
  /// are removed, their reports kept; 0 keeps them all.
  double keep_logs_days = 0;
  /// Retention: the oldest run logs are removed (reports kept) until all
  /// logs take at most this much, MiB; 0: no limit.
  double max_logs_mib = 0;
  /// A stream is lost after 10 periods unseen and never sooner than this,
  /// real milliseconds: the host's scheduling latency.
  double stale_floor_ms = 50;
};

/// Pass/fail of one estimate, in display units (deg/h, ppm, ug, mm).
struct Tolerance {
  std::string parameter;  ///< model.md's name, or df_eff_1, df_eff_2
  double max_abs = std::numeric_limits<double>::infinity();  ///< |estimate| at most this
  double max_sigma =
      std::numeric_limits<double>::infinity();  ///< its standard deviation at most this
};

struct Config {
  std::filesystem::path source;  ///< the file it came from
  CanConfig can;
  StandConfig stand;
  DaemonConfig daemon;
  std::vector<Tolerance> tolerances;
};

/// Display unit of a parameter of the report ("deg/h", "ppm", "ug", "mm")
/// and the factor from SI to it; an empty unit for an unknown name (the
/// parameter table, turncal/estimation/params.hpp).
std::pair<std::string_view, double> display_unit(std::string_view parameter);

/// The reference stand's roles (can-icd.md); the defaults of [can.roles].
std::array<SignalRef, kRoleCount> reference_roles();

/// Parses TOML text; `file` names it in errors; relative DBC paths are
/// resolved against `file`'s folder.
Result<Config> parse_config(std::string_view text, const std::string& file);
/// Reads and parses a configuration file.
Result<Config> load_config(const std::string& path);

/// The factor from a velocity signal's DBC unit to m/s ("m/s", "cm/s",
/// "mm/s", "km/h", "ft/s", "kn"; none: m/s), or an error naming the unit.
Result<double> velocity_unit(const can::Signal& sig);
/// A time signal's unit and its wrap: tag * to_us is microseconds, and an
/// unsigned integer tag wraps every range_us.
struct TimeScale {
  double to_us = 1;
  double range_us = 4294967296.0;
};
/// ... from its DBC unit ("us", "ms", "s"; none: us), or an error.
Result<TimeScale> time_unit(const can::Signal& sig);

/// Whether the INS layout and the table protocol of `cfg` use the role.
bool role_used(const CanConfig& cfg, Role role);

struct RoleMap;
/// The INS velocity and time roles whose signal has no unit in the DBC,
/// each a sentence saying what it is read as (m/s, microseconds): a DBC
/// without units is usable, but the user should know what was assumed.
std::vector<std::string> unitless_role_warnings(const RoleMap& roles);

/// A role resolved against a DBC database (null members: not used).
struct ResolvedRole {
  const can::Message* message = nullptr;
  const can::Signal* signal = nullptr;
  std::size_t signal_index = 0;  ///< index in message->signals
};

/// Every role resolved; the database must outlive it.
struct RoleMap {
  std::array<ResolvedRole, kRoleCount> roles;
  [[nodiscard]] const ResolvedRole& operator[](Role r) const {
    return roles[static_cast<std::size_t>(r)];
  }
  [[nodiscard]] bool has(Role r) const { return (*this)[r].signal != nullptr; }
  /// IDs (with the extended flag) of the messages turncal receives on the
  /// INS interface (ins = true) or the table interface.
  [[nodiscard]] std::vector<std::pair<std::uint32_t, bool>> receive_ids(bool ins) const;
  /// A frame of the message that carries `any` (one of its roles), with
  /// the given role signals set (physical values, DBC units) and every
  /// other signal 0.
  [[nodiscard]] can::Frame encode(Role any,
                                  std::initializer_list<std::pair<Role, double>> values) const;
  /// The same for a frame to a device: only the given role signals are set
  /// (every other signal's bits are 0), and a value that does not fit its
  /// signal is an error naming it and its range, never saturated.
  [[nodiscard]] Result<can::Frame> encode_checked(
      Role any, std::initializer_list<std::pair<Role, double>> values) const;
};

/// Merges the DBC files of a configuration into one database; a message
/// defined in two files is an error naming both.
Result<can::Database> load_databases(const CanConfig& cfg);
/// Checks every role the configuration uses against the database: the
/// message exists, the signal is in it, a role the layout needs is given.
/// Errors cite the configuration key.
Result<RoleMap> resolve_roles(const CanConfig& cfg, const can::Database& db);

}  // namespace turncal
