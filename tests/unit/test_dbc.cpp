#include <doctest/doctest.h>

#include <cmath>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "turncal/can/dbc.hpp"

using namespace turncal::can;

namespace {

Signal make_signal(std::uint32_t start, std::uint32_t len, ByteOrder order,
                   bool is_signed = false) {
  Signal s;
  s.name = "S";
  s.start_bit = start;
  s.length = len;
  s.order = order;
  s.is_signed = is_signed;
  REQUIRE(s.finalize());
  return s;
}

const char* kSmall = R"(VERSION "1"

NS_ :
	NS_DESC_
	CM_
	BA_DEF_

BS_:

BU_: A B

BO_ 100 Engine: 8 A
 SG_ Speed : 0|16@1+ (0.1,0) [0|6553.5] "km/h" B
 SG_ Temp : 23|8@0- (1,-40) [-40|215] "degC" B,A
 SG_ Flag : 63|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 2147484000 Ext: 8 B
 SG_ F32 : 0|32@1- (1,0) [0|0] "" A
 SG_ Mux M : 32|8@1+ (1,0) [0|255] "" A
 SG_ Low m0 : 40|16@1+ (1,0) [0|65535] "" A
 SG_ High m1 : 40|24@1+ (2,1) [0|0] "" A

BO_ 200 Wide: 64 A
 SG_ D64 : 0|64@1- (1,0) [0|0] "" B
 SG_ Tail : 504|8@1+ (1,0) [0|255] "" B

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_ "GenMsgCycleTime" BO_ 100 10;
CM_ "database comment";
CM_ BO_ 100 "engine data";
CM_ SG_ 100 Speed "vehicle
speed";
VAL_ 100 Flag 0 "off" 1 "on" ;
SIG_VALTYPE_ 2147484000 F32 : 1;
SIG_VALTYPE_ 200 D64 : 2;
)";

}  // namespace

TEST_SUITE("dbc") {
  TEST_CASE("Intel and Motorola layouts match hand-worked vectors") {
    const std::uint8_t data[8] = {0x12, 0x34, 0x56, 0x78, 0x9A, 0xBC, 0xDE, 0xF0};
    SUBCASE("Intel byte") {
      CHECK(extract_raw(make_signal(0, 8, ByteOrder::LittleEndian), data) == 0x12);
    }
    SUBCASE("Intel 16 across bytes") {
      CHECK(extract_raw(make_signal(0, 16, ByteOrder::LittleEndian), data) == 0x3412);
    }
    SUBCASE("Intel unaligned nibble pair") {
      CHECK(extract_raw(make_signal(4, 8, ByteOrder::LittleEndian), data) == 0x41);
    }
    SUBCASE("Intel 64") {
      CHECK(extract_raw(make_signal(0, 64, ByteOrder::LittleEndian), data) ==
            0xF0DEBC9A78563412ull);
    }
    SUBCASE("Motorola byte") {
      CHECK(extract_raw(make_signal(7, 8, ByteOrder::BigEndian), data) == 0x12);
    }
    SUBCASE("Motorola 16") {
      CHECK(extract_raw(make_signal(7, 16, ByteOrder::BigEndian), data) == 0x1234);
    }
    SUBCASE("Motorola low nibble") {
      CHECK(extract_raw(make_signal(3, 4, ByteOrder::BigEndian), data) == 0x2);
    }
    SUBCASE("Motorola across bytes") {
      // bits 3..0 of byte 0 (0x2), then bits 7..4 of byte 1 (0x3)
      CHECK(extract_raw(make_signal(3, 8, ByteOrder::BigEndian), data) == 0x23);
    }
    SUBCASE("Motorola 64") {
      CHECK(extract_raw(make_signal(7, 64, ByteOrder::BigEndian), data) == 0x123456789ABCDEF0ull);
    }
    SUBCASE("sign extension") {
      const Signal s = make_signal(4, 4, ByteOrder::LittleEndian, true);  // high nibble of 0x12: 1
      CHECK(raw_to_integer(s, extract_raw(s, data)) == 1);
      const Signal t = make_signal(56, 8, ByteOrder::LittleEndian, true);  // 0xF0 = -16
      CHECK(raw_to_integer(t, extract_raw(t, data)) == -16);
    }
  }

  TEST_CASE("a small database parses with every section") {
    auto r = parse_dbc(kSmall, "small.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    const Database& db = *r;
    CHECK(db.version == "1");
    CHECK(db.nodes == std::vector<std::string>{"A", "B"});
    REQUIRE(db.messages.size() == 3);
    const Message* eng = db.find("Engine");
    REQUIRE(eng != nullptr);
    CHECK(eng->id == 100);
    CHECK_FALSE(eng->extended);
    CHECK(eng->comment == "engine data");
    const Signal* temp = eng->find_signal("Temp");
    REQUIRE(temp != nullptr);
    CHECK(temp->order == ByteOrder::BigEndian);
    CHECK(temp->is_signed);
    CHECK(temp->offset == -40);
    CHECK(temp->unit == "degC");
    CHECK(temp->receivers == std::vector<std::string>{"B", "A"});
    CHECK(eng->find_signal("Speed")->comment == "vehicle\nspeed");
    CHECK(eng->find_signal("Flag")->values.at(1) == "on");
    const Message* ext = db.find(352, true);
    REQUIRE(ext != nullptr);
    CHECK(ext->name == "Ext");
    CHECK(ext->find_signal("F32")->type == ValueType::Float32);
    CHECK(ext->multiplexor()->name == "Mux");
    CHECK(ext->find_signal("High")->mux == MuxRole::Multiplexed);
    CHECK(ext->find_signal("High")->mux_value == 1);
    const Message* wide = db.find("Wide");
    REQUIRE(wide != nullptr);
    CHECK(wide->fd);
    CHECK(wide->find_signal("D64")->type == ValueType::Float64);
  }

  TEST_CASE("frames decode and encode through the codec") {
    auto db = parse_dbc(kSmall, "small.dbc");
    REQUIRE(db.ok());
    FrameCodec codec(*db);
    const Message* ext = db->find("Ext");
    SUBCASE("multiplexed signals follow the multiplexor") {
      const std::vector<double> in = {-1.5, 1, 7, 201};  // F32, Mux, Low, High
      Frame f = FrameCodec::encode(*ext, in);
      CHECK(f.extended);
      std::vector<double> out(4);
      REQUIRE(codec.decode(f, out) == DecodeStatus::Ok);
      CHECK(out[0] == -1.5);
      CHECK(out[1] == 1);
      CHECK(std::isnan(out[2]));
      CHECK(out[3] == 201);
    }
    SUBCASE("a frame of the wrong length is refused, counted and skipped") {
      Frame good = FrameCodec::encode(*db->find("Engine"), std::vector<double>{1, 2, 0});
      Frame bad = good;
      bad.len = 7;
      std::vector<double> out(3);
      DecodeCounts counts;
      for (const Frame* f : {&good, &bad, &good}) counts.add(codec.decode(*f, out));
      CHECK(counts.ok == 2);
      CHECK(counts.length_mismatch == 1);
      CHECK(counts.malformed() == 1);
      CHECK(out[0] == doctest::Approx(1));  // the good frame after the bad one decoded
    }
    SUBCASE("unknown IDs and error frames are not data") {
      Frame f;
      f.id = 0x7FF;
      f.len = 8;
      std::vector<double> out(3);
      CHECK(codec.decode(f, out) == DecodeStatus::UnknownId);
      f.error = true;
      CHECK(codec.decode(f, out) == DecodeStatus::NotData);
    }
    SUBCASE("a value that does not fit its signal is refused, never saturated") {
      const Signal* speed = db->find("Engine")->find_signal("Speed");  // u16, 0.1, [0|6553.5]
      CHECK(*physical_to_raw(*speed, 12.34) == 123);
      CHECK(*physical_to_raw(*speed, 6553.5) == 0xFFFF);
      CHECK(*physical_to_raw(*speed, 0) == 0);
      CHECK(*physical_to_raw(*speed, -0.04) == 0);  // within half a step: rounds to the end
      for (double v : {1e9, 6553.6, -5.0, -0.06, std::nan(""), HUGE_VAL}) {
        CAPTURE(v);
        CHECK_FALSE(fits(*speed, v));
        const auto r = physical_to_raw(*speed, v);
        REQUIRE_FALSE(r.ok());
        CHECK(r.error().message.find("does not fit signal Speed (0.0 to 6553.5 km/h)") !=
              std::string::npos);
      }
      // the frame codec names the message too; the unchecked path clamps
      const std::vector<double> values = {1e9, 2, 0};
      const auto f = FrameCodec::encode_checked(*db->find("Engine"), values);
      REQUIRE_FALSE(f.ok());
      CHECK(f.error().message == "1000000000 km/h does not fit Engine.Speed (0.0 to 6553.5 km/h)");
      const std::vector<double> good = {12.3, 2, 0};
      REQUIRE(FrameCodec::encode_checked(*db->find("Engine"), good).ok());
      CHECK(extract_raw(*speed, FrameCodec::encode(*db->find("Engine"), values).payload()) ==
            0xFFFF);
    }
    SUBCASE("the DBC's [min|max] narrows the raw range; [0|0] gives none") {
      // s8 with offset -40 carries -168 to 87; the file says [-40|215]: -40 to 87
      const Signal* temp = db->find("Engine")->find_signal("Temp");
      CHECK(physical_range(*temp).lo == -40);
      CHECK(physical_range(*temp).hi == 87);
      CHECK(fits(*temp, -40));
      CHECK(fits(*temp, 87));
      CHECK_FALSE(fits(*temp, -41));
      CHECK_FALSE(fits(*temp, 88));
      const Signal* f32 = db->find("Ext")->find_signal("F32");
      CHECK(fits(*f32, -1.5));
      CHECK_FALSE(fits(*f32, 1e39));                            // beyond a float
      const Signal* low = db->find("Ext")->find_signal("Low");  // u16, [0|65535]
      CHECK(fits(*low, 65535));
      const Signal* high = db->find("Ext")->find_signal("High");  // u24, factor 2, offset 1, [0|0]
      CHECK(physical_range(*high).hi == 2.0 * 16777215 + 1);
      CHECK(fits(*high, 2.0 * 16777215 + 1));
      CHECK_FALSE(fits(*high, 2.0 * 16777216 + 1));
      Signal narrow = *low;
      narrow.minimum = 10;
      narrow.maximum = 20;
      CHECK(fits(narrow, 10));
      CHECK(fits(narrow, 20));
      CHECK_FALSE(fits(narrow, 21));
      CHECK_FALSE(fits(narrow, 9));
      CHECK(describe_range(narrow) == "10 to 20");
    }
  }

  TEST_CASE("the reference stand DBC parses") {
    auto r = load_dbc(std::string(TURNCAL_SOURCE_DIR) + "/config/reference-stand.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    CHECK(r->messages.size() == 8);
    const Message* enc = r->find(0x201, false);
    REQUIRE(enc != nullptr);
    CHECK(enc->name == "TBL_Encoder");
    const Signal* angle = enc->find_signal("Angle");
    REQUIRE(angle != nullptr);
    CHECK(angle->factor * 4294967296.0 == 360.0);  // 2^-32 rev in degrees, exactly
    CHECK(r->find("HOST_Heartbeat")->size == 2);
    CHECK(r->find("INS_Status")->find_signal("Mode")->values.at(2) == "navigating");
  }

  TEST_CASE("malformed files give errors with file and line") {
    struct Case {
      const char* text;
      std::uint32_t line;
    };
    const Case cases[] = {
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n SG_ T : 60|8@1+ (1,0) [0|1] \"\" B\n",
         3},
        {"BO_ 1 M: 8 A\n SG_ S : 0|65@1+ (1,0) [0|1] \"\" B\n", 2},
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@2+ (1,0) [0|1] \"\" B\n", 2},
        {"BO_ 1 M: 9 A\n", 1},
        {"BO_ 1 M: 8 A\nBO_ 1 N: 8 A\n", 2},
        {"\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n", 2},
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"unterminated\n", 2},
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\nSIG_VALTYPE_ 1 S : 1;\n", 3},
        {"BO_ 1 M: 8 A\n SG_ S m1 : 0|8@1+ (1,0) [0|1] \"\" B\n", 2},
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (0,0) [0|1] \"\" B\n", 2},
        {"BO_ 4000 M: 8 A\n", 1},
        {"VERSION \"x\"\nFOO_ bar;\n", 2},
    };
    for (const Case& c : cases) {
      CAPTURE(c.text);
      auto r = parse_dbc(c.text, "bad.dbc");
      REQUIRE_FALSE(r.ok());
      CHECK(r.error().where.file == "bad.dbc");
      CHECK(r.error().where.line == c.line);
    }
  }

  TEST_CASE("unknown sections are skipped and stale references ignored") {
    const char* text =
        "BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n"
        "BA_DEF_ SG_ \"X\" ENUM \"a\",\"b\";\nBA_DEF_DEF_ \"X\" \"a\";\n"
        "EV_ E: 0 [0|1] \"\" 0 1 DUMMY_NODE_VECTOR0 A;\nSG_MUL_VAL_ 1 S S 0-0;\n"
        "VAL_TABLE_ T 1 \"x\" 0 \"y\";\nVAL_ E 0 \"a\";\nCM_ SG_ 99 Nope \"stale\";\n"
        "BO_TX_BU_ 1 : A,B;\n";
    auto r = parse_dbc(text, "ok.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    CHECK(r->messages.size() == 1);
  }

  TEST_CASE("property: random layouts encode and decode as inverses, through DBC text") {
    std::mt19937_64 rng(0x7c0ffee);
    int signals_checked = 0;
    for (int trial = 0; trial < 400; ++trial) {
      const bool fd = trial % 4 == 0;
      const std::uint32_t size = fd ? 64 : 8;
      std::vector<bool> used(size * 8, false);
      std::ostringstream dbc;
      dbc << "BO_ " << (fd ? 0x80000000u + 0x1234567u : 0x123u) << " M: " << size << " A\n";
      std::vector<Signal> layout;
      for (int attempt = 0; attempt < 40 && layout.size() < 12; ++attempt) {
        Signal s;
        s.name = "S" + std::to_string(layout.size());
        s.length = static_cast<std::uint32_t>(1 + rng() % 64);
        s.order = (rng() % 2) ? ByteOrder::LittleEndian : ByteOrder::BigEndian;
        s.start_bit = static_cast<std::uint32_t>(rng() % (size * 8));
        s.is_signed = (rng() % 2) != 0;
        if (!s.finalize() || s.end_byte() > size) continue;
        // occupancy: insert all ones into an empty payload and look
        std::vector<std::uint8_t> probe(size, 0);
        insert_raw(s, probe, ~0ull);
        bool clash = false;
        int bits = 0;
        for (std::uint32_t b = 0; b < size * 8; ++b) {
          if ((static_cast<unsigned>(probe[b / 8]) >> (b % 8)) & 1u) {
            ++bits;
            clash = clash || used[b];
          }
        }
        REQUIRE(bits == static_cast<int>(s.length));
        if (clash) continue;
        for (std::uint32_t b = 0; b < size * 8; ++b)
          if ((static_cast<unsigned>(probe[b / 8]) >> (b % 8)) & 1u) used[b] = true;
        dbc << " SG_ " << s.name << " : " << s.start_bit << "|" << s.length << "@"
            << (s.order == ByteOrder::LittleEndian ? 1 : 0) << (s.is_signed ? "-" : "+")
            << " (1,0) [0|0] \"\" B\n";
        layout.push_back(s);
      }
      auto db = parse_dbc(dbc.str(), "random.dbc");
      REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
      const Message& m = db->messages.at(0);
      CHECK(m.extended == fd);
      REQUIRE(m.signals.size() == layout.size());
      std::vector<std::uint64_t> raws;
      std::vector<std::uint8_t> payload(size);
      for (auto& b : payload) b = static_cast<std::uint8_t>(rng());
      for (std::size_t i = 0; i < layout.size(); ++i) {
        CHECK(m.signals[i].first_byte == layout[i].first_byte);
        CHECK(m.signals[i].span == layout[i].span);
        CHECK(m.signals[i].shift == layout[i].shift);
        const std::uint64_t mask = layout[i].length == 64 ? ~0ull : (1ull << layout[i].length) - 1;
        raws.push_back(rng() & mask);
        insert_raw(m.signals[i], payload, raws.back());
      }
      for (std::size_t i = 0; i < layout.size(); ++i) {
        const Signal& s = m.signals[i];
        CHECK(extract_raw(s, payload) == raws[i]);
        if (s.length <= 52) {  // exactly representable in a double
          CHECK(*physical_to_raw(s, raw_to_physical(s, raws[i])) == raws[i]);
        }
        ++signals_checked;
      }
      // the whole-frame codec agrees with the per-signal one
      Frame f;
      f.id = m.id;
      f.extended = m.extended;
      f.fd = m.fd;
      f.len = static_cast<std::uint8_t>(size);
      std::copy(payload.begin(), payload.end(), f.data.begin());
      FrameCodec codec(*db);
      std::vector<double> phys(m.signals.size());
      REQUIRE(codec.decode(f, phys) == DecodeStatus::Ok);
      const Frame g = FrameCodec::encode(m, phys);
      for (std::size_t i = 0; i < m.signals.size(); ++i)
        if (m.signals[i].length <= 52) CHECK(extract_raw(m.signals[i], g.payload()) == raws[i]);
    }
    CHECK(signals_checked > 1500);
  }

  TEST_CASE("float signals round trip") {
    auto db = parse_dbc(kSmall, "small.dbc");
    REQUIRE(db.ok());
    const Signal* d64 = db->find("Wide")->find_signal("D64");
    std::vector<std::uint8_t> payload(64, 0);
    for (double v : {0.0, -1.0, 3.141592653589793, 1e300, -2.5e-300}) {
      insert_raw(*d64, payload, *physical_to_raw(*d64, v));
      CHECK(raw_to_physical(*d64, extract_raw(*d64, payload)) == v);
    }
  }
}
