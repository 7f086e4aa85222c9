// The parser of rtnetlink's RTM_GETLINK answer, on answers made here byte
// by byte: a simulator's socket opens only an interface whose link kind it
// read as vcan or vxcan, so every answer it cannot read must count as real.
#include <doctest/doctest.h>
#include <linux/if_link.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>
#include <vector>

#include "turncal/drivers/socketcan.hpp"

using namespace turncal;

namespace {

/// Bytes of a netlink answer, each part 4-byte aligned as the kernel lays it.
struct Answer {
  std::vector<char> bytes;

  void pad() {
    while (bytes.size() % 4 != 0) bytes.push_back(0);
  }
  template <class T>
  void put(const T& v) {
    const auto* p = reinterpret_cast<const char*>(&v);
    bytes.insert(bytes.end(), p, p + sizeof v);
  }
  /// A header, its length written by end_message.
  std::size_t begin_message(unsigned short type) {
    const std::size_t at = bytes.size();
    nlmsghdr h{};
    h.nlmsg_type = type;
    h.nlmsg_seq = 1;
    put(h);
    pad();
    return at;
  }
  void end_message(std::size_t at) { set_len<nlmsghdr>(at, bytes.size() - at); }
  std::size_t begin_attr(unsigned short type) {
    const std::size_t at = bytes.size();
    rtattr a{};
    a.rta_type = type;
    put(a);
    pad();
    return at;
  }
  void end_attr(std::size_t at) {
    set_len<rtattr>(at, bytes.size() - at);
    pad();
  }
  void attr(unsigned short type, const std::string& text) {
    const std::size_t at = begin_attr(type);
    bytes.insert(bytes.end(), text.begin(), text.end());
    bytes.push_back(0);
    end_attr(at);
  }
  template <class H>
  void set_len(std::size_t at, std::size_t len) {
    H h{};
    std::memcpy(&h, bytes.data() + at, sizeof h);
    if constexpr (std::is_same_v<H, nlmsghdr>)
      h.nlmsg_len = static_cast<unsigned>(len);
    else
      h.rta_len = static_cast<unsigned short>(len);
    std::memcpy(bytes.data() + at, &h, sizeof h);
  }
  [[nodiscard]] Result<std::string> kind() const {
    return socketcan::link_kind_of_answer(bytes, "tcx0");
  }
};

/// RTM_NEWLINK for an interface, with IFLA_LINKINFO / IFLA_INFO_KIND = kind
/// (none when `with_info` is false; an empty nest when kind is empty).
Answer newlink(const std::string& kind, bool with_info = true) {
  Answer a;
  const std::size_t m = a.begin_message(RTM_NEWLINK);
  ifinfomsg ifi{};
  ifi.ifi_index = 7;
  a.put(ifi);
  a.pad();
  a.attr(IFLA_IFNAME, "tcx0");
  a.attr(IFLA_QDISC, "noqueue");
  if (with_info) {
    const std::size_t info = a.begin_attr(IFLA_LINKINFO);
    if (!kind.empty()) a.attr(IFLA_INFO_KIND, kind);
    a.end_attr(info);
  }
  a.end_message(m);
  return a;
}

Answer error_answer(int err) {
  Answer a;
  const std::size_t m = a.begin_message(NLMSG_ERROR);
  nlmsgerr e{};
  e.error = -err;
  a.put(e);
  a.end_message(m);
  return a;
}

}  // namespace

TEST_SUITE("socketcan link kind") {
  TEST_CASE("the kind of a vcan, a vxcan, a real CAN controller and other interfaces") {
    for (const char* k : {"vcan", "vxcan", "can", "dummy", "veth"}) {
      CAPTURE(k);
      const auto kind = newlink(k).kind();
      REQUIRE(kind);
      CHECK(*kind == k);
    }
    CHECK(socketcan::is_virtual_kind("vcan"));
    CHECK(socketcan::is_virtual_kind("vxcan"));
    CHECK_FALSE(socketcan::is_virtual_kind("can"));  // a USB, PCI or SPI controller
    CHECK_FALSE(socketcan::is_virtual_kind("dummy"));
    CHECK_FALSE(socketcan::is_virtual_kind(""));
    CHECK_FALSE(socketcan::is_virtual_kind("vcan0"));  // a name, not a kind
  }

  TEST_CASE("an interface without a link kind (slcan, lo): empty, so counted as real") {
    const auto none = newlink("", false).kind();
    REQUIRE(none);
    CHECK(none->empty());
    const auto empty_nest = newlink("").kind();
    REQUIRE(empty_nest);
    CHECK(empty_nest->empty());
  }

  TEST_CASE("the kernel's error, an acknowledgement, or no answer: an error, never a kind") {
    const auto enodev = error_answer(ENODEV).kind();
    REQUIRE_FALSE(enodev);
    CHECK(enodev.error().describe().find("tcx0") != std::string::npos);
    CHECK(enodev.error().describe().find(std::strerror(ENODEV)) != std::string::npos);
    const auto ack = error_answer(0).kind();
    REQUIRE_FALSE(ack);
    CHECK(ack.error().describe().find("no answer") != std::string::npos);
    CHECK_FALSE(Answer{}.kind());
  }

  TEST_CASE("a truncated or malformed answer is no answer") {
    const Answer whole = newlink("vcan");
    // cut anywhere short of the whole: the message's length overruns it
    for (std::size_t n = 0; n < whole.bytes.size(); ++n) {
      Answer cut;
      cut.bytes.assign(whole.bytes.begin(), whole.bytes.begin() + static_cast<long>(n));
      CAPTURE(n);
      const auto kind = cut.kind();
      CHECK_FALSE(kind);
    }
    // a header whose length is under its own size
    Answer bad = newlink("vcan");
    bad.set_len<nlmsghdr>(0, 4);
    CHECK_FALSE(bad.kind());
    // an attribute whose length overruns its message, or is under its own
    // header's: nothing read past it, and no answer
    for (const unsigned short len : {std::uint16_t{0xfff0}, std::uint16_t{2}}) {
      Answer over = newlink("vcan");
      over.set_len<rtattr>(sizeof(nlmsghdr) + sizeof(ifinfomsg), len);
      CAPTURE(len);
      const auto over_kind = over.kind();
      REQUIRE_FALSE(over_kind);
      CHECK(over_kind.error().describe().find("malformed") != std::string::npos);
    }
    // the kind's own attribute overrunning the link info that holds it
    Answer inner = newlink("vcan");
    const std::size_t kind_at = inner.bytes.size() - 12;  // rtattr + "vcan\0" + pad
    inner.set_len<rtattr>(kind_at, 40);
    const auto inner_kind = inner.kind();
    REQUIRE_FALSE(inner_kind);
    CHECK(inner_kind.error().describe().find("malformed link info") != std::string::npos);
    // a link message too short for its ifinfomsg
    Answer shorty;
    const std::size_t m = shorty.begin_message(RTM_NEWLINK);
    shorty.put(std::uint32_t{0});
    shorty.end_message(m);
    CHECK_FALSE(shorty.kind());
  }

  TEST_CASE("an answer for another interface than the one asked by its index is refused") {
    const Answer a = newlink("vcan");  // index 7
    const auto same = socketcan::link_kind_of_answer(a.bytes, "tcx0", 7);
    REQUIRE(same);
    CHECK(*same == "vcan");
    const auto other = socketcan::link_kind_of_answer(a.bytes, "tcx0", 8);
    REQUIRE_FALSE(other);
    CHECK(other.error().describe().find("another interface") != std::string::npos);
  }

  TEST_CASE("the first RTM_NEWLINK after other messages is the answer") {
    Answer a;
    const std::size_t m = a.begin_message(NLMSG_NOOP);
    a.put(std::uint32_t{0});
    a.end_message(m);
    const Answer link = newlink("vxcan");
    a.bytes.insert(a.bytes.end(), link.bytes.begin(), link.bytes.end());
    const auto kind = a.kind();
    REQUIRE(kind);
    CHECK(*kind == "vxcan");
  }
}
