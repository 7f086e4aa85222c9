#include <doctest/doctest.h>

#include <unistd.h>
#include <cmath>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>

#include "turncal/build_paths.hpp"
#include "turncal/config.hpp"

using namespace turncal;

namespace {
const std::string kSrc = turncal::build::source_dir;

Error parse_error(const std::string& text) {
  auto r = parse_config(text, "/etc/turncal/turncal.toml");
  REQUIRE_FALSE(r.ok());
  return r.error();
}
}  // namespace

TEST_SUITE("config") {
  TEST_CASE("the shipped turncal.toml loads and its roles resolve against the reference DBC") {
    auto cfg = load_config(kSrc + "/config/turncal.toml");
    REQUIRE_MESSAGE(cfg.ok(), (cfg.ok() ? "" : cfg.error().describe()));
    CHECK(cfg->can.ins_interface == "vcan0");
    REQUIRE(cfg->can.dbc_files.size() == 1);
    CHECK(cfg->can.dbc_files[0].filename() == "reference-stand.dbc");
    auto db = load_databases(cfg->can);
    REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
    auto roles = resolve_roles(cfg->can, *db);
    REQUIRE_MESSAGE(roles.ok(), (roles.ok() ? "" : roles.error().describe()));
    CHECK((*roles)[Role::EncoderAngle].message->id == 0x201);
    CHECK((*roles)[Role::InsVelNorth].signal->name == "VelN");
    auto ins_ids = roles->receive_ids(true);
    auto tbl_ids = roles->receive_ids(false);
    CHECK(ins_ids.size() == 3);  // INS_Status, INS_VelE, INS_VelN
    CHECK(tbl_ids.size() == 2);  // TBL_Encoder, TBL_Status
  }

  TEST_CASE("[table] protocol: one of the protocol table's names, its section its own") {
    const std::string file = "/etc/turncal/turncal.toml";
    for (std::string_view name : kTableProtocols) {
      CAPTURE(name);
      auto c = parse_config("[table]\nprotocol = \"" + std::string(name) + "\"\n", file);
      REQUIRE_MESSAGE(c.ok(), (c.ok() ? "" : c.error().describe()));
      CHECK(c->can.table.name == name);
    }
    auto unknown = parse_config("[table]\nprotocol = \"canopen\"\n", file);
    REQUIRE_FALSE(unknown.ok());
    CHECK(unknown.error().describe() ==
          "/etc/turncal/turncal.toml:2:12: key 'table.protocol': 'canopen' is none of "
          "\"reference\", \"cia402\"");
    auto other =
        parse_config("[table]\nprotocol = \"reference\"\n[table.cia402]\nnode_id = 2\n", file);
    REQUIRE_FALSE(other.ok());
    CHECK(other.error().message ==
          "key 'table.cia402': [table.cia402] is for protocol = \"cia402\", and protocol is "
          "\"reference\"");
    auto scalar = parse_config("[table]\nprotocol = \"cia402\"\ncia402 = 3\n", file);
    REQUIRE_FALSE(scalar.ok());
    CHECK(scalar.error().message == "key 'table.cia402': expected a table");
    auto key = parse_config("[table]\nprotocol = \"cia402\"\nreference = 1\n", file);
    REQUIRE_FALSE(key.ok());
    CHECK(key.error().message == "unknown key 'table.reference'");
    auto cia = parse_config("[table]\nprotocol = \"cia402\"\n[table.cia402]\nnode_id = 5\n", file);
    REQUIRE_MESSAGE(cia.ok(), (cia.ok() ? "" : cia.error().describe()));
    CHECK(cia->can.table.cia402.node_id == 5);
  }

  TEST_CASE("an empty file gives the reference stand") {
    auto cfg = parse_config("", "/x/turncal.toml");
    REQUIRE(cfg.ok());
    CHECK(cfg->can.table_interface == "vcan0");
    CHECK(cfg->can.dbc_files.at(0) == "/x/reference-stand.dbc");
    CHECK(cfg->can.roles[static_cast<std::size_t>(Role::TableAck)].message == "TBL_Status");
    CHECK(cfg->daemon.stale_floor_ms == 50);
  }

  TEST_CASE("errors name file, line and key") {
    SUBCASE("wrong type") {
      Error e = parse_error("[can]\nins_interface = 3\n");
      CHECK(e.where.file == "/etc/turncal/turncal.toml");
      CHECK(e.where.line == 2);
      CHECK(e.message.find("can.ins_interface") != std::string::npos);
    }
    SUBCASE("unknown key") {
      Error e = parse_error("[can]\n\nins_interfce = \"can0\"\n");
      CHECK(e.where.line == 3);
      CHECK(e.message.find("can.ins_interfce") != std::string::npos);
    }
    SUBCASE("bad interface name") {
      Error e = parse_error("[can]\ntable_interface = \"a/b\"\n");
      CHECK(e.where.line == 2);
      CHECK(e.message.find("can.table_interface") != std::string::npos);
    }
    SUBCASE("TOML syntax") {
      Error e = parse_error("[can]\nfd = tru\n");
      CHECK(e.where.line == 2);
    }
    SUBCASE("out of range") {
      Error e = parse_error("[can]\ntx_queue_frames = 0\n");
      CHECK(e.message.find("can.tx_queue_frames") != std::string::npos);
      CHECK(e.where.line == 2);
      e = parse_error("[daemon]\nheartbeat_hz = 10\nstale_floor_ms = 5000\n");
      CHECK(e.message.find("daemon.stale_floor_ms") != std::string::npos);
      CHECK(e.where.line == 3);
    }
    SUBCASE("role not Message.Signal") {
      Error e = parse_error("[can.roles]\nencoder_angle = \"TBL_Encoder\"\n");
      CHECK(e.where.line == 2);
      CHECK(e.message.find("can.roles.encoder_angle") != std::string::npos);
    }
    SUBCASE("unknown role") {
      Error e = parse_error("[can.roles]\nencoder_angel = \"A.B\"\n");
      CHECK(e.message.find("encoder_angel") != std::string::npos);
    }
    SUBCASE("a control socket that names no file") {
      for (const char* bad : {"", "/run/turncal/"}) {
        CAPTURE(bad);
        Error e = parse_error(std::string("[daemon]\n\nsocket = \"") + bad + "\"\n");
        CHECK(e.where.line == 3);
        CHECK(e.message.find("daemon.socket") != std::string::npos);
        CHECK(e.message.find("names no file") != std::string::npos);
      }
    }
  }

  TEST_CASE("a role that names a missing signal is refused at its key") {
    auto cfg = parse_config("[can]\ndbc = [\"" + kSrc +
                                "/config/reference-stand.dbc\"]\n[can.roles]\n\n"
                                "encoder_angle = \"TBL_Encoder.Angel\"\n",
                            "stand.toml");
    REQUIRE(cfg.ok());
    auto db = load_databases(cfg->can);
    REQUIRE(db.ok());
    auto roles = resolve_roles(cfg->can, *db);
    REQUIRE_FALSE(roles.ok());
    CHECK(roles.error().where.file == "stand.toml");
    CHECK(roles.error().where.line == 5);
    CHECK(roles.error().message.find("Angel") != std::string::npos);
  }

  TEST_CASE("a role may not name an unusable signal; what no role uses only warns") {
    std::ifstream in(kSrc + "/config/reference-stand.dbc");
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string current = ss.str();
    const auto dir = std::filesystem::temp_directory_path() /
                     ("turncal-test-roles-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    auto load = [&](const std::string& text) {
      std::ofstream(dir / "stand.dbc") << text;
      auto cfg = parse_config(
          "[can]\ndbc = [\"stand.dbc\"]\n[can.roles]\n"
          "encoder_angle = \"TBL_Encoder.Angle\"\n",
          (dir / "turncal.toml").string());
      REQUIRE(cfg.ok());
      auto db = load_databases(cfg->can);
      REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
      return std::make_pair(std::move(*cfg), std::move(*db));
    };
    const std::string angle = " SG_ Angle : 32|32@1+";
    const auto angle_at = current.find(angle);
    REQUIRE(angle_at != std::string::npos);
    const auto angle_line = static_cast<std::uint32_t>(
        std::count(current.begin(), current.begin() + static_cast<std::ptrdiff_t>(angle_at), '\n') +
        1);
    SUBCASE("a signal no role uses that does not fit: a warning, the roles resolve") {
      const std::string text = current +
                               "\nBO_ 1000 Vendor_Extra: 4 TBL\n"
                               " SG_ Beyond : 24|16@1+ (1,0) [0|0] \"\" HOST\n";
      auto [cfg, db] = load(text);
      REQUIRE(db.warnings.size() == 1);
      CHECK(db.warnings[0].where.file == (dir / "stand.dbc").string());
      CHECK(db.warnings[0].text.find("Vendor_Extra.Beyond") != std::string::npos);
      auto roles = resolve_roles(cfg.can, db);
      REQUIRE_MESSAGE(roles.ok(), (roles.ok() ? "" : roles.error().describe()));
    }
    SUBCASE("the role's own signal does not fit: an error at its DBC line, naming the key") {
      std::string text = current;
      text.replace(angle_at, angle.size(), " SG_ Angle : 40|32@1+");
      auto [cfg, db] = load(text);
      auto roles = resolve_roles(cfg.can, db);
      REQUIRE_FALSE(roles.ok());
      CHECK(roles.error().where.file == (dir / "stand.dbc").string());
      CHECK(roles.error().where.line == angle_line);
      CHECK(roles.error().message.find("can.roles.encoder_angle") != std::string::npos);
      CHECK(roles.error().message.find("turncal.toml:4") != std::string::npos);
      CHECK(roles.error().message.find("does not fit") != std::string::npos);
    }
    SUBCASE("an SG_ line of the role's message that cannot be read: an error at that line") {
      std::string text = current;
      const std::string time_tag = " SG_ TimeTag : 0|32@1+";
      const auto at = text.find(time_tag, angle_at - 200);  // TBL_Encoder's, before Angle
      REQUIRE(at < angle_at);
      text.replace(at, time_tag.size(), " SG_ TimeTag : 0|32@3+");
      auto [cfg, db] = load(text);
      auto roles = resolve_roles(cfg.can, db);
      REQUIRE_FALSE(roles.ok());
      CHECK(roles.error().where.file == (dir / "stand.dbc").string());
      CHECK(roles.error().where.line == angle_line - 1);
      CHECK(roles.error().message.find("can.roles.encoder_") != std::string::npos);
      CHECK(roles.error().message.find("was not read whole, so no role may be in it: SG_ line "
                                       "of message 'TBL_Encoder' not read") != std::string::npos);
    }
    SUBCASE("a role's message left out (its ID defined twice): an error naming why") {
      std::string text = current + "\nBO_ 513 TBL_Again: 8 TBL\n";
      auto [cfg, db] = load(text);
      const can::Message* enc = db.find("TBL_Encoder");
      REQUIRE(enc != nullptr);
      INFO("TBL_Encoder's ID: " << enc->id);
      REQUIRE_FALSE(db.left_out.empty());
      auto roles = resolve_roles(cfg.can, db);
      REQUIRE_FALSE(roles.ok());
      CHECK(roles.error().message.find("can.roles.encoder_") != std::string::npos);
      CHECK(roles.error().message.find("is defined again, by message 'TBL_Again'") !=
            std::string::npos);
    }
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a reference-protocol DBC must state ICD revision 2; an older one is refused") {
    std::ifstream in(kSrc + "/config/reference-stand.dbc");
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string current = ss.str();
    auto replaced = [](std::string text, const std::string& from, const std::string& to) {
      for (auto at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
        text.replace(at, from.size(), to);
      return text;
    };
    // the file as ICD revision 1 had it
    const std::string old = replaced(
        replaced(current, "\"turncal reference stand ICD 2\"", "\"turncal reference stand 1.0\""),
        "Target : 16|32@1- (1E-005,0) [-21474.83648|21474.83647]",
        "Target : 16|32@1- (1E-006,0) [-2147.483648|2147.483647]");
    REQUIRE(old != current);
    const auto dir = std::filesystem::temp_directory_path() /
                     ("turncal-test-config-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    auto load = [&](const std::string& name, const std::string& text,
                    const std::string& roles = "") {
      std::ofstream(dir / name) << text;
      auto cfg = parse_config("[can]\ndbc = [\"" + name + "\"]\n" + roles,
                              (dir / "turncal.toml").string());
      REQUIRE(cfg.ok());
      return load_databases(cfg->can);
    };
    SUBCASE("the shipped DBC states revision 2 and loads") {
      auto db = load("current.dbc", current);
      REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
      CHECK(db->version == "turncal reference stand ICD 2");
      CHECK(db->find("TBL_Command")->find_signal("Target")->factor == 1e-5);
    }
    SUBCASE("a revision 1 file (kept as a conffile, say) is refused, naming it") {
      auto db = load("old.dbc", old);
      REQUIRE_FALSE(db.ok());
      CHECK(db.error().where.file == (dir / "old.dbc").string());
      CHECK(db.error().where.line == 1);
      CHECK(db.error().message.find("VERSION \"turncal reference stand 1.0\" does not state ICD "
                                    "revision 2") != std::string::npos);
      CHECK(db.error().message.find("ten times") != std::string::npos);
      CHECK(db.error().describe().find("old.dbc:1: ") != std::string::npos);
    }
    SUBCASE("no VERSION, another revision, or a revision that is not plain are refused") {
      for (const std::string& v : {std::string("turncal reference stand ICD 1"),
                                   std::string("turncal reference stand ICD 3"),
                                   std::string("turncal reference stand ICD 2.1"),
                                   std::string("turncal reference stand 2"), std::string("ICD2")}) {
        CAPTURE(v);
        CHECK_FALSE(load("v.dbc", replaced(current, "turncal reference stand ICD 2", v)).ok());
      }
      auto none =
          load("none.dbc", replaced(current, "VERSION \"turncal reference stand ICD 2\"", ""));
      REQUIRE_FALSE(none.ok());
      CHECK(none.error().message.find("it has no VERSION") != std::string::npos);
      CHECK(load("v.dbc", replaced(current, "turncal reference stand ICD 2", "stand ICD 2 (2024)"))
                .ok());
    }
    SUBCASE("a stand whose table commands are not TBL_Command is not held to the reference ICD") {
      const std::string own = replaced(old, "TBL_Command", "Drive_Command");
      const std::string roles =
          "[can.roles]\ntable_command = \"Drive_Command.Command\"\n"
          "table_command_seq = \"Drive_Command.Seq\"\n"
          "table_command_target = \"Drive_Command.Target\"\n"
          "table_command_rate_limit = \"Drive_Command.RateLimit\"\n";
      auto db = load("own.dbc", own, roles);
      REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
    }
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a missing DBC file is named") {
    auto cfg = parse_config("[can]\ndbc = [\"nope.dbc\"]\n", "/tmp/stand.toml");
    REQUIRE(cfg.ok());
    auto db = load_databases(cfg->can);
    REQUIRE_FALSE(db.ok());
    CHECK(db.error().where.file == "/tmp/nope.dbc");
  }
}

TEST_CASE("config: [stand], [daemon] and [tolerances]") {
  const std::string file = "/etc/turncal/turncal.toml";
  auto c = parse_config(R"([stand]
heading_offset_deg = 90
max_rate_dps = 20
angle_min_deg = -10
angle_max_deg = 370
time_scale = 50
[daemon]
state_directory = "/tmp/x"
profile = "p.toml"
[tolerances]
nu0_1 = { max_abs = 0.5, max_sigma = 0.01 }
r2 = { max_sigma = 1 }
)",
                        file);
  REQUIRE_MESSAGE(c.ok(), c.error().describe());
  CHECK(c->stand.heading_offset_rad == doctest::Approx(std::numbers::pi / 2));
  CHECK(c->stand.limits.max_rate_rps == doctest::Approx(20 * std::numbers::pi / 180));
  CHECK(c->stand.limits.angle_max_rad == doctest::Approx(370 * std::numbers::pi / 180));
  CHECK(c->stand.time_scale == 50);
  CHECK(c->daemon.state_directory == "/tmp/x");
  CHECK(c->daemon.profile == "/etc/turncal/p.toml");
  REQUIRE(c->tolerances.size() == 2);
  CHECK(c->tolerances[0].parameter == "nu0_1");
  CHECK(c->tolerances[0].max_abs == 0.5);
  CHECK(std::isinf(c->tolerances[1].max_abs));
  CHECK(display_unit("theta_23").first == "ppm");
  CHECK(display_unit("df_eff_2").second == doctest::Approx(1 / 9.80665e-6));

  auto bad = parse_config("[tolerances]\nnu0_4 = { max_abs = 1 }\n", file);
  REQUIRE_FALSE(bad.ok());
  CHECK(bad.error().describe() ==
        "/etc/turncal/turncal.toml:2:1: unknown key 'tolerances.nu0_4': not a parameter of the "
        "report");
  auto limits = parse_config("[stand]\nangle_min_deg = 10\nangle_max_deg = 5\n", file);
  REQUIRE_FALSE(limits.ok());
  CHECK(limits.error().describe().find(":3:") != std::string::npos);
  CHECK(limits.error().describe().find("stand.angle_max_deg") != std::string::npos);
  // the shipped file: every key its default
  auto shipped = load_config(std::string(turncal::build::source_dir) + "/config/turncal.toml");
  REQUIRE_MESSAGE(shipped.ok(), shipped.error().describe());
  CHECK(shipped->stand.heading_offset_rad == 0);
  CHECK(shipped->stand.time_scale == 1);
  CHECK(shipped->daemon.profile.filename() == "tactical.toml");
  CHECK(shipped->tolerances.empty());
}

TEST_CASE("config: one soft limit alone that crosses the other's default names its own key") {
  auto c = parse_config("[stand]\nangle_min_deg = 1000000\n", "t.toml");
  REQUIRE_FALSE(c.ok());
  CHECK(c.error().describe() ==
        "t.toml:2:17: key 'stand.angle_min_deg': must be below angle_max_deg");
}

TEST_CASE("config: [table] protocol = \"cia402\" and [table.cia402]") {
  SUBCASE("the shipped CiA 402 stand loads; only the drive's roles resolve") {
    auto cfg = load_config(kSrc + "/config/stands/cia402/turncal.toml");
    REQUIRE_MESSAGE(cfg.ok(), (cfg.ok() ? "" : cfg.error().describe()));
    REQUIRE(cfg->can.table.is_cia402());
    const Cia402Settings& c = cfg->can.table.cia402;
    CHECK(c.node_id == 1);
    CHECK(c.host_node_id == 127);
    CHECK(c.quick_stop_deceleration_rps2 ==
          doctest::Approx(90 * std::numbers::pi / 180).epsilon(1e-12));
    CHECK(c.host_heartbeat_timeout_s == doctest::Approx(0.5).epsilon(1e-12));
    auto db = load_databases(cfg->can);
    REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
    auto roles = resolve_roles(cfg->can, *db);
    REQUIRE_MESSAGE(roles.ok(), (roles.ok() ? "" : roles.error().describe()));
    CHECK((*roles)[Role::TableStatusword].message->id == 0x181);
    CHECK((*roles)[Role::TableControlword].message->id == 0x201);
    CHECK_FALSE(roles->has(Role::EncoderAngle));         // the reference table's: not used
    CHECK_FALSE(roles->has(Role::HeartbeatCounter));     // ... nor its heartbeat
    CHECK_FALSE(roles->has(Role::TableVelocityActual));  // velocity_pdo is off
    // the statusword's message is received, the controlword's sent
    const auto tbl = roles->receive_ids(false);
    CHECK(tbl.size() == 1);
    CHECK(tbl.at(0).first == 0x181);
    CHECK(role_is_output(Role::TableControlword));
    CHECK(role_is_output(Role::TableTargetPosition));
    CHECK_FALSE(role_is_output(Role::TableStatusword));
    CHECK_FALSE(role_is_ins(Role::TableVelocityActual));
    CHECK(role_is_ins(Role::InsCommandSeq));
  }
  SUBCASE("the reference protocol does not use the drive's roles, nor cia402 the reference's") {
    auto ref = parse_config("", "/x/turncal.toml");
    REQUIRE(ref.ok());
    CHECK_FALSE(role_used(ref->can, Role::TableStatusword));
    CHECK(role_used(ref->can, Role::EncoderAngle));
    auto cia = parse_config("[table]\nprotocol = \"cia402\"\n", "/x/turncal.toml");
    REQUIRE(cia.ok());
    CHECK(role_used(cia->can, Role::TableStatusword));
    CHECK_FALSE(role_used(cia->can, Role::EncoderAngle));
    CHECK_FALSE(role_used(cia->can, Role::TableVelocityActual));
    auto vel = parse_config("[table]\nprotocol = \"cia402\"\n[table.cia402]\nvelocity_pdo = true\n",
                            "/x/turncal.toml");
    REQUIRE(vel.ok());
    CHECK(role_used(vel->can, Role::TableVelocityActual));
  }
  SUBCASE("defaults, and values in the file's units") {
    auto cfg = parse_config(
        "[table]\nprotocol = \"cia402\"\n[table.cia402]\nnode_id = 5\nsync_period_ms = 150\n"
        "profile_acceleration_dps2 = 20\nconfigure_mapping = true\ncounts_increase = "
        "\"clockwise\"\n",
        "/x/turncal.toml");
    REQUIRE_MESSAGE(cfg.ok(), (cfg.ok() ? "" : cfg.error().describe()));
    const Cia402Settings& c = cfg->can.table.cia402;
    CHECK(c.node_id == 5);
    CHECK(c.sync_period_s == doctest::Approx(0.15).epsilon(1e-12));
    CHECK(c.profile_acceleration_rps2 ==
          doctest::Approx(20 * std::numbers::pi / 180).epsilon(1e-12));
    CHECK(c.configure_mapping);
    CHECK_FALSE(c.velocity_pdo);
    CHECK(c.counts_per_revolution == 131072);
    CHECK(c.counts_clockwise);
    CHECK(c.drive_heartbeat_timeout_s == doctest::Approx(0.3).epsilon(1e-12));
  }
  SUBCASE("a drive role not given is named by its key") {
    auto cfg = load_config(kSrc + "/config/stands/cia402/turncal.toml");
    REQUIRE(cfg.ok());
    cfg->can.roles[static_cast<std::size_t>(Role::TableStatusword)] =
        SignalRef{"", "", {"f", 3, 1}};
    auto db = load_databases(cfg->can);
    REQUIRE(db.ok());
    auto roles = resolve_roles(cfg->can, *db);
    REQUIRE_FALSE(roles.ok());
    CHECK(roles.error().message.find("can.roles.table_statusword") != std::string::npos);
    CHECK(roles.error().where.line == 3);
  }
  struct Bad {
    const char* text;
    const char* key;
    int line;
  };
  const std::string head = "[table]\nprotocol = \"cia402\"\n[table.cia402]\n";
  for (const Bad& b : {
           Bad{"node_id = 0\n", "table.cia402.node_id", 4},
           Bad{"node_id = 128\n", "table.cia402.node_id", 4},
           Bad{"host_node_id = 1\n", "table.cia402.host_node_id", 4},
           Bad{"counts_per_revolution = 0\n", "table.cia402.counts_per_revolution", 4},
           Bad{"gear_ratio = -2\n", "table.cia402.gear_ratio", 4},
           Bad{"counts_increase = \"cw\"\n", "table.cia402.counts_increase", 4},
           Bad{"quick_stop_deceleration_dps2 = 0\n", "table.cia402.quick_stop_deceleration_dps2",
               4},
           Bad{"quick_stop_option_code = 9\n", "table.cia402.quick_stop_option_code", 4},
           Bad{"abort_connection_option_code = 0\n", "table.cia402.abort_connection_option_code",
               4},
           Bad{"abort_connection_option_code = 2\n", "table.cia402.abort_connection_option_code",
               4},
           Bad{"quick_stop_option_code = 0\n", "table.cia402.quick_stop_option_code", 4},
           Bad{"host_heartbeat_ms = 100\nhost_heartbeat_consumer_ms = 100\n",
               "table.cia402.host_heartbeat_consumer_ms", 5},
           Bad{"drive_heartbeat_ms = 400\n", "table.cia402.drive_heartbeat_ms", 4},
           Bad{"sync_period_ms = -1\n", "table.cia402.sync_period_ms", 4},
           Bad{"sdo_timeout_ms = 0\n", "table.cia402.sdo_timeout_ms", 4},
           Bad{"velocity_pdo = 1\n", "table.cia402.velocity_pdo", 4},
           Bad{"nodeid = 1\n", "table.cia402.nodeid", 4},
           Bad{"emcy_warnings = \"0x4210\"\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x4210\",\n \"4210\"]\n", "table.cia402.emcy_warnings", 5},
           Bad{"emcy_warnings = [\"0x42G0\"]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [0x4210]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x4FFF-0x4000\"]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x0000-0x4FFF\"]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x0001-0xFFFF\"]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x8130\"]\n", "table.cia402.emcy_warnings", 4},
           Bad{"emcy_warnings = [\"0x8600-0x86FF\"]\n", "table.cia402.emcy_warnings", 4},
       }) {
    CAPTURE(b.text);
    Error e = parse_error(head + b.text);
    CHECK(e.where.file == "/etc/turncal/turncal.toml");
    CHECK(e.where.line == b.line);
    CHECK(e.message.find(b.key) != std::string::npos);
  }
  SUBCASE("the EMCY codes that only warn: codes and ranges; none; the master's defaults") {
    auto c = parse_config(head + "emcy_warnings = [\"0x4210\", \"0x8110-0x812f\"]\n",
                          "/etc/turncal/turncal.toml");
    REQUIRE(c.ok());
    const auto& w = c->can.table.cia402.emcy_warnings;
    REQUIRE(w.has_value());
    REQUIRE(w->size() == 2);
    CHECK((*w)[0] == std::pair<std::uint16_t, std::uint16_t>{0x4210, 0x4210});
    CHECK((*w)[1] == std::pair<std::uint16_t, std::uint16_t>{0x8110, 0x812F});
    auto none = parse_config(head + "emcy_warnings = []\n", "/etc/turncal/turncal.toml");
    REQUIRE(none.ok());
    REQUIRE(none->can.table.cia402.emcy_warnings.has_value());
    CHECK(none->can.table.cia402.emcy_warnings->empty());
    auto dflt = parse_config(head, "/etc/turncal/turncal.toml");
    REQUIRE(dflt.ok());
    CHECK_FALSE(dflt->can.table.cia402.emcy_warnings.has_value());
    Error e = parse_error(head + "emcy_warnings = [\"0x4FFF-0x4000\"]\n");
    CHECK(e.message.find("ends before it begins") != std::string::npos);
    Error f = parse_error(head + "emcy_warnings = [\"4210\"]\n");
    CHECK(f.message.find("not \"4210\"") != std::string::npos);
  }
  SUBCASE("the drive's ramps above the stand's acceleration") {
    Error e =
        parse_error("[stand]\nmax_accel_dps2 = 20\n" + head + "profile_deceleration_dps2 = 25\n");
    CHECK(e.where.line == 6);
    CHECK(e.message.find("table.cia402.profile_deceleration_dps2") != std::string::npos);
    CHECK(e.message.find("exceed the stand's max_accel_dps2 of 20 deg/s^2") != std::string::npos);
    // the default ramp (10 deg/s^2) under a stand's limit of 5: named at the limit
    Error f = parse_error("[stand]\nmax_accel_dps2 = 5\n" + head);
    CHECK(f.where.line == 2);
    CHECK(f.message.find("profile_acceleration_dps2") != std::string::npos);
  }
  SUBCASE("a SYNC period shorter than the daemon's timer that sends it") {
    Error e = parse_error(head + "sync_period_ms = 20\n");  // heartbeat_hz 10: 100 ms
    CHECK(e.where.line == 4);
    CHECK(e.message.find("table.cia402.sync_period_ms") != std::string::npos);
    CHECK(e.message.find("100 ms") != std::string::npos);
    // at the timer's period it is accepted
    CHECK(parse_config("[daemon]\nheartbeat_hz = 50\n" + head + "sync_period_ms = 20\n",
                       "/etc/turncal/turncal.toml")
              .ok());
  }
  SUBCASE("TPDO1 rarer than half the drive heartbeat timeout, a resolution too coarse") {
    // drive_heartbeat_timeout_ms 300 by default: 150 ms at the most
    Error e = parse_error(head + "sync_period_ms = 200\n");
    CHECK(e.where.line == 4);
    CHECK(e.message.find("key 'table.cia402.sync_period_ms': TPDO1's period of 200 ms") == 0);
    CHECK(parse_config(head + "sync_period_ms = 200\ndrive_heartbeat_timeout_ms = 400\n",
                       "/etc/turncal/turncal.toml")
              .ok());
    Error f = parse_error(head + "configure_mapping = true\ntpdo_event_timer_ms = 160\n");
    CHECK(f.where.line == 5);
    CHECK(f.message.find("table.cia402.tpdo_event_timer_ms") != std::string::npos);
    // the drive's own event timer is its configuration's, not ours
    CHECK(parse_config(head + "tpdo_event_timer_ms = 160\n", "/etc/turncal/turncal.toml").ok());
    Error g = parse_error(head + "counts_per_revolution = 4096\ngear_ratio = 2\n");
    CHECK(g.where.line == 4);
    CHECK(g.message.find("8192 counts per table turn") != std::string::npos);
    CHECK(parse_config(head + "counts_per_revolution = 4096\ngear_ratio = 4\n",
                       "/etc/turncal/turncal.toml")
              .ok());
  }
  SUBCASE("an unknown protocol, and [table.cia402] for the reference protocol") {
    Error e = parse_error("[table]\nprotocol = \"canopen\"\n");
    CHECK(e.where.line == 2);
    CHECK(e.message.find("\"cia402\"") != std::string::npos);
    Error f = parse_error("[table]\nprotocol = \"reference\"\n[table.cia402]\nnode_id = 2\n");
    CHECK(f.where.line == 3);
    CHECK(f.message.find("table.cia402") != std::string::npos);
  }
}
