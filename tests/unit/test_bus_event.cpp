#include <doctest/doctest.h>

#include "turncal/can/bus_event.hpp"

using namespace turncal::can;

TEST_SUITE("bus_event") {
  TEST_CASE("error frames become events") {
    TimedFrame tf;
    tf.time_ns = 42;
    tf.frame.error = true;
    tf.frame.len = 8;
    SUBCASE("bus-off and restart") {
      tf.frame.id = 0x040 | 0x100;
      auto ev = decode_error_frame(tf);
      REQUIRE(ev.size() == 2);
      CHECK(ev[0].kind == BusEventKind::BusOff);
      CHECK(ev[1].kind == BusEventKind::Restarted);
      CHECK(ev[0].time_ns == 42);
    }
    SUBCASE("controller problem carries its status bits") {
      tf.frame.id = 0x004;
      tf.frame.data[1] = 0x10 | 0x01;  // rx passive, rx overflow
      auto ev = decode_error_frame(tf);
      REQUIRE(ev.size() == 1);
      CHECK(ev[0].kind == BusEventKind::ControllerProblem);
      CHECK(ev[0].detail == 0x11);
      CHECK(describe(ev[0]) == "controller problem (rx overflow, rx passive)");
    }
    SUBCASE("a data frame has no events") {
      tf.frame.error = false;
      tf.frame.id = 0x040;
      CHECK(decode_error_frame(tf).empty());
    }
  }
}
