#include <doctest/doctest.h>

#include <fstream>
#include <string>

#include "turncal/config.hpp"

using namespace turncal;

namespace {
const std::string kSrc = TURNCAL_SOURCE_DIR;

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

  TEST_CASE("an empty file gives the reference stand") {
    auto cfg = parse_config("", "/x/turncal.toml");
    REQUIRE(cfg.ok());
    CHECK(cfg->can.table_interface == "vcan0");
    CHECK(cfg->can.dbc_files.at(0) == "/x/reference-stand.dbc");
    CHECK(cfg->can.roles[static_cast<std::size_t>(Role::TableAck)].message == "TBL_Status");
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

  TEST_CASE("a missing DBC file is named") {
    auto cfg = parse_config("[can]\ndbc = [\"nope.dbc\"]\n", "/tmp/stand.toml");
    REQUIRE(cfg.ok());
    auto db = load_databases(cfg->can);
    REQUIRE_FALSE(db.ok());
    CHECK(db.error().where.file == "/tmp/nope.dbc");
  }
}
