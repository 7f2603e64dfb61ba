#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/soe.hpp>

namespace ecat::wire {
namespace {

using Vec = std::vector<std::uint8_t>;

template <class T>
void expect_error(const Result<T>& r, Errc code, const std::string& message) {
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), code);
  EXPECT_EQ(r.error().message(), message);
}

// ============================== FoE ==============================

Vec foe(const FoeMessage& m) {
  auto r = encode_foe(m);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? *r : Vec{};
}

TEST(Foe, KnownBytes) {
  EXPECT_EQ(foe(FoeReadRequest{0, "firmware.bin"}),
            (Vec{0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 'f', 'i', 'r', 'm', 'w', 'a', 'r', 'e', '.',
                 'b', 'i', 'n'}));
  EXPECT_EQ(foe(FoeWriteRequest{0x12345678, "a"}), (Vec{0x02, 0x00, 0x78, 0x56, 0x34, 0x12, 'a'}));
  EXPECT_EQ(foe(FoeData{1, {0xDE, 0xAD}}), (Vec{0x03, 0x00, 0x01, 0x00, 0x00, 0x00, 0xDE, 0xAD}));
  EXPECT_EQ(foe(FoeAck{0x0102}), (Vec{0x04, 0x00, 0x02, 0x01, 0x00, 0x00}));
  EXPECT_EQ(foe(FoeError{0x8001, "nf"}), (Vec{0x05, 0x00, 0x01, 0x80, 0x00, 0x00, 'n', 'f'}));
  EXPECT_EQ(foe(FoeBusy{10, 100}), (Vec{0x06, 0x00, 0x0A, 0x00, 0x64, 0x00}));
}

TEST(Foe, RoundTripsEveryMessage) {
  const FoeMessage messages[] = {
      FoeReadRequest{0, "firmware.bin"},
      FoeReadRequest{0xFFFFFFFF, ""},
      FoeWriteRequest{7, "app.efw"},
      FoeData{1, Vec(512, 0x33)},
      FoeData{9, {}},
      FoeAck{0},
      FoeAck{0xFFFFFFFF},
      FoeError{0x8005, "packet number wrong"},
      FoeError{0x8000, ""},
      FoeBusy{0, 0},
      FoeBusy{0xFFFF, 0xFFFF},
  };
  for (const auto& m : messages) {
    SCOPED_TRACE(to_string(opcode_of(m)));
    auto back = decode_foe(foe(m));
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, m);
  }
}

TEST(Foe, NamesStopAtNul) {
  auto m = decode_foe(Vec{0x01, 0x00, 0, 0, 0, 0, 'a', 'b', 0x00, 0x00, 0x00});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(std::get<FoeReadRequest>(*m).file_name, "ab");
}

TEST(Foe, Errors) {
  expect_error(decode_foe(Bytes{}), Errc::truncated,
               "FoE: opcode at offset 0 needs 1 byte, 0 remain");
  expect_error(decode_foe(Vec{0x01, 0x00, 0x00}), Errc::truncated,
               "FoE: password at offset 2 needs 4 bytes, 1 remains");
  expect_error(decode_foe(Vec{0x03, 0x00}), Errc::truncated,
               "FoE: packet number at offset 2 needs 4 bytes, 0 remain");
  expect_error(decode_foe(Vec{0x04, 0x00, 1, 2, 3}), Errc::truncated,
               "FoE: packet number at offset 2 needs 4 bytes, 3 remain");
  expect_error(decode_foe(Vec{0x05, 0x00, 1}), Errc::truncated,
               "FoE: error code at offset 2 needs 4 bytes, 1 remains");
  expect_error(decode_foe(Vec{0x06, 0x00, 1, 0, 2}), Errc::truncated,
               "FoE: entire at offset 4 needs 2 bytes, 1 remains");
  expect_error(decode_foe(Vec{0x07, 0x00, 0, 0, 0, 0}), Errc::malformed,
               "FoE: opcode 7 at offset 0 is not an FoE opcode (1..6)");
  expect_error(decode_foe(Vec{0x00, 0x00}), Errc::malformed,
               "FoE: opcode 0 at offset 0 is not an FoE opcode (1..6)");
  expect_error(encode_foe(FoeReadRequest{0, std::string("a\0b", 3)}), Errc::invalid_argument,
               "FoE: file name holds a NUL character");
  expect_error(encode_foe(FoeError{1, std::string("\0", 1)}), Errc::invalid_argument,
               "FoE: error text holds a NUL character");
  expect_error(encode_foe(FoeData{1, Vec(65530)}), Errc::invalid_argument,
               "FoE: 65536 bytes exceed the mailbox length limit of 65535");
}

TEST(Foe, Texts) {
  const std::pair<std::uint32_t, const char*> expected[] = {
      {0x8000, "not defined"},
      {0x8001, "file not found"},
      {0x8002, "access denied"},
      {0x8003, "disk full"},
      {0x8004, "illegal"},
      {0x8005, "packet number wrong"},
      {0x8006, "file already exists"},
      {0x8007, "no user"},
      {0x8008, "bootstrap access only"},
      {0x8009, "not in bootstrap"},
      {0x800A, "no access rights"},
      {0x800B, "program error"},
      {0x800C, "checksum error"},
      {0x800D, "unknown FoE error"},
      {0x0001, "unknown FoE error"},
  };
  for (const auto& [code, text] : expected)
    EXPECT_EQ(foe_error_text(code), text);
  EXPECT_EQ(to_string(FoeOpcode::read_request), "read request");
  EXPECT_EQ(to_string(FoeOpcode::write_request), "write request");
  EXPECT_EQ(to_string(FoeOpcode::data), "data");
  EXPECT_EQ(to_string(FoeOpcode::ack), "ack");
  EXPECT_EQ(to_string(FoeOpcode::error), "error");
  EXPECT_EQ(to_string(FoeOpcode::busy), "busy");
  EXPECT_EQ(to_string(static_cast<FoeOpcode>(7)), "reserved");
}

// ============================== EoE ==============================

Vec eoe(const EoeMessage& m) {
  auto r = encode_eoe(m);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? *r : Vec{};
}

TEST(EoeHeader, PacksEveryField) {
  const EoeHeader h{.type = EoeFrameType::fragment,
                    .port = 1,
                    .last_fragment = true,
                    .time_appended = true,
                    .time_request = true,
                    .fragment_number = 5,
                    .offset_blocks = 10,
                    .frame_number = 3};
  std::uint8_t buf[4];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_eoe_header(h, w).ok());
  // word0 = type 0 | port 1 << 4 | 0x0700; word1 = 5 | 10 << 6 | 3 << 12 = 0x3285.
  EXPECT_EQ(Vec(buf, buf + 4), (Vec{0x10, 0x07, 0x85, 0x32}));
  EXPECT_EQ(*decode_eoe_header(Bytes(buf)), h);

  const EoeHeader all{.type = static_cast<EoeFrameType>(15),
                      .port = 15,
                      .fragment_number = 63,
                      .offset_blocks = 63,
                      .frame_number = 15};
  ByteWriter w2(buf);
  ASSERT_TRUE(encode_eoe_header(all, w2).ok());
  EXPECT_EQ(Vec(buf, buf + 4), (Vec{0xFF, 0x00, 0xFF, 0xFF}));
  EXPECT_EQ(*decode_eoe_header(Bytes(buf)), all);
  EXPECT_EQ(eoe_result_of(all), 0xFFFF);
}

TEST(EoeHeader, Errors) {
  std::uint8_t buf[4];
  ByteWriter w(buf);
  expect_error(encode_eoe_header({.port = 16}, w), Errc::invalid_argument,
               "EoE header: field out of range (type 0 max 15, port 16 max 15, fragment 0 max 63, "
               "offset 0 max 63, frame 0 max 15)");
  ByteWriter w2(buf);
  expect_error(encode_eoe_header({.offset_blocks = 64}, w2), Errc::invalid_argument,
               "EoE header: field out of range (type 0 max 15, port 0 max 15, fragment 0 max 63, "
               "offset 64 max 63, frame 0 max 15)");
  std::uint8_t small[3];
  ByteWriter w3(small);
  expect_error(encode_eoe_header({}, w3), Errc::out_of_range,
               "EoE header: needs 4 bytes of buffer, 3 left");
  expect_error(decode_eoe_header(Vec{0x00, 0x01, 0x02}), Errc::truncated,
               "EoE header: fragment info at offset 2 needs 2 bytes, 1 remains");
}

TEST(Eoe, SetIpRequestBytes) {
  EoeSetIpRequest m;
  m.port = 1;
  m.parameters.mac = std::array<std::uint8_t, 6>{0x02, 0x00, 0x00, 0x00, 0x00, 0x01};
  m.parameters.ip = 0xC0A80102;  // 192.168.1.2
  m.parameters.default_gateway = 0xC0A80101;
  m.parameters.dns_name = "ab";
  Vec expected{0x12, 0x01, 0x00, 0x00,  // set IP request, port 1, last fragment
               0x2B, 0x00, 0x00, 0x00,  // MAC | IP | gateway | DNS name
               0x02, 0x00, 0x00, 0x00, 0x00, 0x01,
               0x02, 0x01, 0xA8, 0xC0,  // 192.168.1.2 little-endian
               0x01, 0x01, 0xA8, 0xC0, 'a',  'b'};
  expected.resize(expected.size() + 30, 0);
  EXPECT_EQ(eoe(m), expected);
  EXPECT_EQ(*decode_eoe(expected), EoeMessage(m));
}

TEST(Eoe, SetIpResponseCarriesTheResultInWordOne) {
  const Vec bytes{0x03, 0x01, 0x01, 0x02};
  auto m = decode_eoe(bytes);
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(*m, EoeMessage(EoeSetIpResponse{0, 0x0201}));
  EXPECT_EQ(eoe(EoeSetIpResponse{0, 0x0201}), bytes);
  EXPECT_EQ(eoe_result_text(0x0201), "no IP support");
}

TEST(Eoe, RoundTripsEveryMessage) {
  EoeIpParameters everything;
  everything.mac = std::array<std::uint8_t, 6>{1, 2, 3, 4, 5, 6};
  everything.ip = 0x0A000001;
  everything.subnet_mask = 0xFF000000;
  everything.default_gateway = 0x0A0000FE;
  everything.dns_server = 0x08080808;
  everything.dns_name = std::string(32, 'x');
  const EoeMessage messages[] = {
      EoeFragment{{.fragment_number = 0, .offset_blocks = 47, .frame_number = 9}, Vec(128, 1), {}},
      EoeFragment{{.last_fragment = true,
                   .time_appended = true,
                   .fragment_number = 4,
                   .offset_blocks = 16,
                   .frame_number = 9},
                  Vec(20, 2),
                  0xCAFEBABE},
      EoeFragment{{.time_request = true}, {}, {}},
      EoeSetIpRequest{0, {}},
      EoeSetIpRequest{15, everything},
      EoeSetIpResponse{2, 0x0000},
      EoeSetIpResponse{0, 0xFFFF},
      EoeOther{{.type = EoeFrameType::get_ip_request, .last_fragment = true}, {}},
      EoeOther{{.type = EoeFrameType::timestamp_response}, {1, 2, 3, 4}},
      EoeOther{{.type = static_cast<EoeFrameType>(12), .port = 3}, {9}},
  };
  for (const auto& m : messages) {
    auto back = decode_eoe(eoe(m));
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, m);
  }
}

TEST(Eoe, DecodeErrors) {
  expect_error(decode_eoe(Vec{0x00, 0x00}), Errc::truncated,
               "EoE header: fragment info at offset 2 needs 2 bytes, 0 remain");
  expect_error(decode_eoe(Vec{0x00, 0x03, 0x00, 0x00, 0xAA, 0xBB}), Errc::truncated,
               "EoE fragment: appended timestamp at offset 4 needs 4 bytes, 2 remain");
  expect_error(decode_eoe(Vec{0x02, 0x01, 0x00, 0x00, 0x02, 0x00}), Errc::truncated,
               "EoE set IP parameter request: included flags at offset 4 needs 4 bytes, 2 remain");
  expect_error(
      decode_eoe(Vec{0x02, 0x01, 0x00, 0x00, 0x03, 0x00, 0x00, 0x00, 1, 2, 3, 4, 5, 6, 0x01, 0x02}),
      Errc::truncated,
      "EoE set IP parameter request: IP address at offset 14 needs 4 bytes, 2 remain");
  expect_error(decode_eoe(Vec{0x02, 0x01, 0x00, 0x00, 0x20, 0x00, 0x00, 0x00, 'a'}),
               Errc::truncated,
               "EoE set IP parameter request: DNS name at offset 8 needs 32 bytes, 1 remains");
}

TEST(Eoe, EncodeErrors) {
  EoeFragment missing_time;
  missing_time.header.time_appended = true;
  expect_error(encode_eoe(missing_time), Errc::invalid_argument,
               "EoE fragment: a timestamp must be present exactly when time_appended is set");
  EoeFragment wrong_type;
  wrong_type.header.type = EoeFrameType::set_ip_request;
  expect_error(encode_eoe(wrong_type), Errc::invalid_argument,
               "EoE fragment: header type is not fragment (0)");
  EoeSetIpRequest long_name;
  long_name.parameters.dns_name = std::string(33, 'n');
  expect_error(encode_eoe(long_name), Errc::invalid_argument,
               "EoE IP parameters: DNS name must be at most 32 bytes without NUL, is 33 bytes");
  expect_error(encode_eoe(EoeSetIpRequest{16, {}}), Errc::invalid_argument,
               "EoE header: field out of range (type 2 max 15, port 16 max 15, fragment 0 max 63, "
               "offset 0 max 63, frame 0 max 15)");
  expect_error(encode_eoe(EoeOther{{.type = EoeFrameType::set_ip_response}, {}}),
               Errc::invalid_argument,
               "EoE: EoeOther cannot carry a fragment or set IP parameter frame type");
  EoeFragment big;
  big.data = Vec(65532);
  expect_error(encode_eoe(big), Errc::invalid_argument,
               "EoE: 65536 bytes exceed the mailbox length limit of 65535");
}

TEST(Eoe, Texts) {
  EXPECT_EQ(format_ipv4(0xC0A80102), "192.168.1.2");
  EXPECT_EQ(format_ipv4(0), "0.0.0.0");
  EXPECT_EQ(format_ipv4(0xFFFFFFFF), "255.255.255.255");
  EXPECT_EQ(eoe_result_text(0x0000), "success");
  EXPECT_EQ(eoe_result_text(0x0001), "unspecified error");
  EXPECT_EQ(eoe_result_text(0x0002), "unsupported frame type");
  EXPECT_EQ(eoe_result_text(0x0202), "DHCP not supported");
  EXPECT_EQ(eoe_result_text(0x0401), "no address filter support");
  EXPECT_EQ(eoe_result_text(0x0003), "unknown EoE result");
  EXPECT_EQ(to_string(EoeFrameType::fragment), "fragment");
  EXPECT_EQ(to_string(EoeFrameType::timestamp_response), "timestamp response");
  EXPECT_EQ(to_string(EoeFrameType::set_ip_request), "set IP parameter request");
  EXPECT_EQ(to_string(EoeFrameType::set_ip_response), "set IP parameter response");
  EXPECT_EQ(to_string(EoeFrameType::set_address_filter_request), "set address filter request");
  EXPECT_EQ(to_string(EoeFrameType::set_address_filter_response), "set address filter response");
  EXPECT_EQ(to_string(EoeFrameType::get_ip_request), "get IP parameter request");
  EXPECT_EQ(to_string(EoeFrameType::get_ip_response), "get IP parameter response");
  EXPECT_EQ(to_string(EoeFrameType::get_address_filter_request), "get address filter request");
  EXPECT_EQ(to_string(EoeFrameType::get_address_filter_response), "get address filter response");
  EXPECT_EQ(to_string(static_cast<EoeFrameType>(10)), "reserved");
}

// ============================== SoE ==============================

Vec soe(const SoeMessage& m) {
  auto r = encode_soe(m);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? *r : Vec{};
}

TEST(SoeHeader, PacksEveryField) {
  const SoeHeader h{.opcode = SoeOpcode::write_response,
                    .incomplete = true,
                    .error = true,
                    .drive_number = 5,
                    .elements = kSoeElementValue | kSoeElementName,
                    .idn = 0x8123};
  std::uint8_t buf[4];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_soe_header(h, w).ok());
  // control = opcode 4 | incomplete 0x08 | error 0x10 | drive 5 << 5 = 0xBC.
  EXPECT_EQ(Vec(buf, buf + 4), (Vec{0xBC, 0x42, 0x23, 0x81}));
  EXPECT_EQ(*decode_soe_header(Bytes(buf)), h);
}

TEST(Soe, KnownBytesAndRoundTrips) {
  SoeMessage read;
  read.header = {.opcode = SoeOpcode::read_request, .elements = kSoeElementValue, .idn = 1};
  EXPECT_EQ(soe(read), (Vec{0x01, 0x40, 0x01, 0x00}));

  SoeMessage failed;
  failed.header = {.opcode = SoeOpcode::read_response, .error = true, .elements = 0x40, .idn = 1};
  failed.error_code = 0x1001;
  EXPECT_EQ(soe(failed), (Vec{0x12, 0x40, 0x01, 0x00, 0x01, 0x10}));

  SoeMessage fragment;
  fragment.header = {.opcode = SoeOpcode::write_request,
                     .incomplete = true,
                     .drive_number = 7,
                     .elements = 0x40,
                     .idn = 3};
  fragment.data = Vec(100, 0x5A);

  SoeMessage notification;
  notification.header = {.opcode = SoeOpcode::notification, .idn = 0xFFFF};
  notification.data = {1, 2};

  SoeMessage info;
  info.header = {.opcode = SoeOpcode::slave_info, .error = true};
  info.error_code = 0;
  info.data = {0xEE};

  for (const auto& m : {read, failed, fragment, notification, info}) {
    auto back = decode_soe(soe(m));
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, m);
  }
}

TEST(Soe, Errors) {
  expect_error(decode_soe(Vec{0x01, 0x40, 0x01}), Errc::truncated,
               "SoE header: IDN at offset 2 needs 2 bytes, 1 remains");
  expect_error(decode_soe(Vec{0x12, 0x40, 0x01, 0x00, 0x01}), Errc::truncated,
               "SoE: error code at offset 4 needs 2 bytes, 1 remains");
  SoeMessage no_code;
  no_code.header.error = true;
  expect_error(encode_soe(no_code), Errc::invalid_argument,
               "SoE: an error code must be present exactly when the error flag is set");
  SoeMessage stray_code;
  stray_code.error_code = 1;
  expect_error(encode_soe(stray_code), Errc::invalid_argument,
               "SoE: an error code must be present exactly when the error flag is set");
  SoeMessage bad_drive;
  bad_drive.header.drive_number = 8;
  expect_error(encode_soe(bad_drive), Errc::invalid_argument,
               "SoE header: opcode 1 or drive number 8 exceeds 7");
  SoeMessage big;
  big.data = Vec(65532);
  expect_error(encode_soe(big), Errc::invalid_argument,
               "SoE: 65536 bytes exceed the mailbox length limit of 65535");
}

TEST(Soe, Texts) {
  EXPECT_EQ(format_idn(0x0001), "S-0-0001");
  EXPECT_EQ(format_idn(0x8123), "P-0-0291");
  EXPECT_EQ(format_idn(0x7FFF), "S-7-4095");
  EXPECT_EQ(format_idn(0xF000), "P-7-0000");
  EXPECT_EQ(to_string(SoeOpcode::read_request), "read request");
  EXPECT_EQ(to_string(SoeOpcode::read_response), "read response");
  EXPECT_EQ(to_string(SoeOpcode::write_request), "write request");
  EXPECT_EQ(to_string(SoeOpcode::write_response), "write response");
  EXPECT_EQ(to_string(SoeOpcode::notification), "notification");
  EXPECT_EQ(to_string(SoeOpcode::slave_info), "slave info");
  EXPECT_EQ(to_string(static_cast<SoeOpcode>(0)), "reserved");
  EXPECT_EQ(to_string(static_cast<SoeOpcode>(7)), "reserved");
}

}  // namespace
}  // namespace ecat::wire
