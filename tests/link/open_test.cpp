#include <chrono>
#include <string>

#include <gtest/gtest.h>

#include <ecat/link/open.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/link/xdp_link.hpp>

namespace ecat::link {
namespace {

using namespace std::chrono_literals;

constexpr const char* kForms =
    "accepted forms: raw:IFACE[,busy_poll=US][,spin], raw:PRIMARY,SECONDARY, "
    "xdp:IFACE[,queue=N][,busy_poll=US][,spin][,native|,generic][,copy|,zero_copy], "
    "udp:HOST:PORT, udp:[IPV6]:PORT, udp:HOST";

void expect_invalid(const std::string& spec, const std::string& why) {
  auto r = open_link(spec);
  ASSERT_FALSE(r.ok()) << spec;
  EXPECT_EQ(r.error().code(), Errc::invalid_argument) << spec;
  EXPECT_EQ(r.error().message(), "invalid link '" + spec + "': " + why + " (" + kForms + ")");
}

TEST(OpenLinkTest, MalformedSpecsNameTheSpecAndTheForms) {
  expect_invalid("", "no kind prefix");
  expect_invalid("eth0", "no kind prefix");
  expect_invalid("tcp:1.2.3.4", "unknown kind 'tcp'");
  expect_invalid("raw:", "no interface after 'raw:'");
  expect_invalid("raw:,spin", "no interface after 'raw:'");
  expect_invalid("raw:eth0,fast=1", "unknown raw link option 'fast'");
  expect_invalid("raw:eth0,spin=1", "unknown raw link option 'spin'");
  expect_invalid("raw:eth0,busy_poll=", "busy_poll='' is not a number from 0 to 1000000");
  expect_invalid("raw:eth0,busy_poll=-5", "busy_poll='-5' is not a number from 0 to 1000000");
  expect_invalid("xdp:", "no interface after 'xdp:'");
  expect_invalid("xdp:eth0,queue=4096", "queue='4096' is not a number from 0 to 4095");
  expect_invalid("xdp:eth0,queue=x", "queue='x' is not a number from 0 to 4095");
  expect_invalid("xdp:eth0,busy_poll=1e3", "busy_poll='1e3' is not a number from 0 to 1000000");
  expect_invalid("xdp:eth0,zerocopy", "unknown xdp link option 'zerocopy'");
  expect_invalid("udp:", "no host after 'udp:'");
  expect_invalid("udp::34980", "the host is empty");
  expect_invalid("udp:host:", "port '' is not a number from 1 to 65535");
  expect_invalid("udp:host:0", "port '0' is not a number from 1 to 65535");
  expect_invalid("udp:host:65536", "port '65536' is not a number from 1 to 65535");
  expect_invalid("udp:host:12ab", "port '12ab' is not a number from 1 to 65535");
  expect_invalid("udp:host:-1", "port '-1' is not a number from 1 to 65535");
  expect_invalid("udp:[::1", "'[' without a closing ']'");
  expect_invalid("udp:[::1]34980", "expected ':PORT' after ']'");
  expect_invalid("udp:[::1]:", "port '' is not a number from 1 to 65535");
  expect_invalid("udp:[example.com]:1", "'example.com' inside brackets is not an IPv6 address");
  expect_invalid("udp:fe80::1::2:3:4", "an IPv6 address with a port must be written in brackets");
}

TEST(OpenLinkTest, RedundantSpecs) {
  const std::string why = "a redundant ring is raw:PRIMARY,SECONDARY, two interfaces";
  expect_invalid("raw:eth0,", why);
  expect_invalid("raw:,eth1", "no interface after 'raw:'");
  expect_invalid("raw:eth0,eth1,spin",
                 "busy_poll and spin apply to a single raw port, not a redundant ring");
  expect_invalid("raw:eth0,eth1,eth2", why);
  auto same = open_link("raw:ecat-none9,ecat-none9");
  ASSERT_FALSE(same.ok());
  EXPECT_EQ(same.error().code(), Errc::invalid_argument);
  EXPECT_NE(same.error().message().find("two interfaces"), std::string::npos);
  auto missing = open_link("raw:ecat-none8,ecat-none9");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  EXPECT_NE(missing.error().describe().find("primary port"), std::string::npos);
  auto udp = open_link("udp:127.0.0.1:34980,127.0.0.2:34980");
  ASSERT_FALSE(udp.ok());
  EXPECT_EQ(udp.error().code(), Errc::unsupported);
  EXPECT_NE(udp.error().message().find("raw:PRIMARY,SECONDARY"), std::string::npos);
}

TEST(OpenLinkTest, SimIsNotAvailableYet) {
  auto r = open_link("sim:ring.yaml");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::unsupported);
  EXPECT_NE(r.error().message().find("'sim:ring.yaml'"), std::string::npos);
  EXPECT_NE(r.error().message().find("not available yet"), std::string::npos);
}

TEST(OpenLinkTest, RawWithMissingInterfaceIsNotFound) {
  auto r = open_link("raw:ecat-none9");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
  EXPECT_EQ(r.error().message(), "network interface 'ecat-none9' does not exist (see `ip link`)");
}

TEST(OpenLinkTest, RawOptionsReachTheLink) {
  // Parsed, then the interface is looked up: the options themselves were accepted.
  auto r = open_link("raw:ecat-none9,busy_poll=50,spin");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
}

TEST(OpenLinkTest, XdpWithMissingInterfaceIsNotFoundOrNotBuilt) {
  auto r = open_link("xdp:ecat-none9,queue=1,busy_poll=20,spin,generic,copy");
  ASSERT_FALSE(r.ok());
  if (xdp_link_available()) {
    EXPECT_EQ(r.error().code(), Errc::not_found);
    EXPECT_EQ(r.error().message(), "network interface 'ecat-none9' does not exist (see `ip link`)");
  } else {
    EXPECT_EQ(r.error().code(), Errc::unsupported);
    EXPECT_NE(r.error().message().find("no AF_XDP link"), std::string::npos);
  }
}

TEST(OpenLinkTest, RawWithOverlongNameIsInvalid) {
  auto r = open_link("raw:this-name-is-too-long-for-linux");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
}

// The UDP forms open a client that really talks to a server.
void expect_udp_round_trip(const std::string& spec_host, const std::string& server_address,
                           bool with_port) {
  auto server = UdpLink::serve(server_address, with_port ? 0 : wire::kEtherCatUdpPort);
  if (!server.ok())
    GTEST_SKIP() << "cannot serve on " << server_address << ": " << server.error().describe();
  const std::string port = std::to_string((*server)->local_port());
  const std::string spec = with_port ? "udp:" + spec_host + ":" + port : "udp:" + spec_host;
  auto link = open_link(spec);
  ASSERT_TRUE(link.ok()) << spec << ": " << link.error().describe();
  const std::array<std::uint8_t, 4> frame{1, 2, 3, 4};
  ASSERT_TRUE((*link)->send(frame).ok());
  auto got = (*server)->receive(2s);
  ASSERT_TRUE(got.ok() && got->has_value()) << spec;
  EXPECT_EQ((*got)->frame.size(), 4u);
  EXPECT_EQ((*got)->frame[3], 4);
  const std::string bracketed =
      server_address.find(':') != std::string::npos ? "[" + server_address + "]" : server_address;
  EXPECT_EQ((*link)->name(), "udp:" + bracketed + ":" + port);
}

TEST(OpenLinkTest, UdpHostPort) {
  expect_udp_round_trip("127.0.0.1", "127.0.0.1", true);
}
TEST(OpenLinkTest, UdpNamePort) {
  expect_udp_round_trip("localhost", "127.0.0.1", true);
}
TEST(OpenLinkTest, UdpBracketedIPv6Port) {
  expect_udp_round_trip("[::1]", "::1", true);
}

TEST(OpenLinkTest, UdpDefaultPort) {
  // Uses the fixed port 34980, so it skips when something (another test run) holds it.
  expect_udp_round_trip("127.0.0.1", "127.0.0.1", false);
}

TEST(OpenLinkTest, UdpBareIPv6UsesDefaultPort) {
  auto link = open_link("udp:::1");
  if (!link.ok() && link.error().code() != Errc::invalid_argument) {
    GTEST_SKIP() << "no IPv6 here: " << link.error().describe();
  }
  ASSERT_TRUE(link.ok()) << link.error().describe();
  EXPECT_EQ((*link)->name(), "udp:[::1]:34980");
}

TEST(OpenLinkTest, UdpUnresolvableHostIsNotFound) {
  auto r = open_link("udp:no-such-host.invalid:1234");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
}

}  // namespace
}  // namespace ecat::link
