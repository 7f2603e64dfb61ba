#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::wire {
namespace {

using Vec = std::vector<std::uint8_t>;

Vec encoded(const SdoMessage& m) {
  auto r = encode_sdo(m);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? *r : Vec{};
}

void expect_decode_error(const Vec& coe, Errc code, const std::string& message) {
  auto r = decode_sdo(coe);
  ASSERT_FALSE(r.ok()) << "decoded as " << to_string(*r);
  EXPECT_EQ(r.error().code(), code);
  EXPECT_EQ(r.error().message(), message);
}

void expect_encode_error(const SdoMessage& m, const std::string& message) {
  auto r = encode_sdo(m);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_EQ(r.error().message(), message);
}

// --- CoE header ---

TEST(CoeHeader, EncodesNumberAndService) {
  std::uint8_t buf[2];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_coe_header({0x1FF, CoeService::rx_pdo}, w).ok());
  EXPECT_EQ(Vec(buf, buf + 2), (Vec{0xFF, 0x51}));
  auto back = decode_coe_header(Bytes(buf));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, (CoeHeader{0x1FF, CoeService::rx_pdo}));
  // Reserved bits 9..11 are ignored.
  EXPECT_EQ(*decode_coe_header(Vec{0x00, 0x2E}), (CoeHeader{0, CoeService::sdo_request}));
}

TEST(CoeHeader, Errors) {
  std::uint8_t buf[2];
  ByteWriter w(buf);
  auto big = encode_coe_header({0x200, CoeService::sdo_request}, w);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().message(), "CoE header: number 512 exceeds 511");
  ByteWriter w2(buf);
  auto service = encode_coe_header({0, static_cast<CoeService>(16)}, w2);
  ASSERT_FALSE(service.ok());
  EXPECT_EQ(service.error().message(), "CoE header: service 16 exceeds 15");
  std::uint8_t one[1];
  ByteWriter w3(one);
  EXPECT_EQ(encode_coe_header({}, w3).error().code(), Errc::out_of_range);
  auto r = decode_coe_header(Vec{0x00});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "CoE header: number/service at offset 0 needs 2 bytes, 1 remains");
}

TEST(CoeService, Names) {
  EXPECT_EQ(to_string(CoeService::emergency), "emergency");
  EXPECT_EQ(to_string(CoeService::sdo_request), "SDO request");
  EXPECT_EQ(to_string(CoeService::sdo_response), "SDO response");
  EXPECT_EQ(to_string(CoeService::tx_pdo), "TxPDO");
  EXPECT_EQ(to_string(CoeService::rx_pdo), "RxPDO");
  EXPECT_EQ(to_string(CoeService::tx_pdo_remote_request), "TxPDO remote request");
  EXPECT_EQ(to_string(CoeService::rx_pdo_remote_request), "RxPDO remote request");
  EXPECT_EQ(to_string(CoeService::sdo_information), "SDO information");
  EXPECT_EQ(to_string(static_cast<CoeService>(0)), "reserved");
  EXPECT_EQ(to_string(static_cast<CoeService>(9)), "reserved");
}

// --- exact bytes of known messages (ETG.1000.6 layouts) ---

TEST(Sdo, ExpeditedUploadRequestOf0x1018_01) {
  // Mailbox header (length 10, counter 0, type CoE), CoE header "SDO request", command 0x40.
  auto mbx = encode_mailbox(MailboxHeader{.type = MailboxType::coe},
                            encoded(SdoInitiateUploadRequest{0x1018, 0x01, false}));
  ASSERT_TRUE(mbx.ok());
  EXPECT_EQ(*mbx, (Vec{0x0a, 0x00, 0x00, 0x00, 0x00, 0x03, 0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0x00,
                       0x00, 0x00, 0x00}));
}

TEST(Sdo, KnownCommandBytes) {
  const std::pair<SdoMessage, Vec> cases[] = {
      // Expedited download of 1, 2, 3, 4 bytes: 0x2F, 0x2B, 0x27, 0x23.
      {SdoInitiateDownloadRequest{.index = 0x6060, .expedited = true, .data = {0x08}},
       {0x00, 0x20, 0x2F, 0x60, 0x60, 0x00, 0x08, 0x00, 0x00, 0x00}},
      {SdoInitiateDownloadRequest{.index = 0x6040, .expedited = true, .data = {0x0F, 0x00}},
       {0x00, 0x20, 0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0x00, 0x00}},
      {SdoInitiateDownloadRequest{
           .index = 0x2000, .subindex = 3, .expedited = true, .data = {1, 2, 3}},
       {0x00, 0x20, 0x27, 0x00, 0x20, 0x03, 0x01, 0x02, 0x03, 0x00}},
      {SdoInitiateDownloadRequest{.index = 0xF008, .expedited = true, .data = {1, 0, 0, 0}},
       {0x00, 0x20, 0x23, 0x08, 0xF0, 0x00, 0x01, 0x00, 0x00, 0x00}},
      // Normal download (0x21), with complete access (0x31).
      {SdoInitiateDownloadRequest{.index = 0x1008, .complete_size = 5, .data = {'h', 'e'}},
       {0x00, 0x20, 0x21, 0x08, 0x10, 0x00, 0x05, 0x00, 0x00, 0x00, 'h', 'e'}},
      {SdoInitiateDownloadRequest{.index = 0x1C12,
                                  .complete_access = true,
                                  .complete_size = 4,
                                  .data = {0x01, 0x00, 0x01, 0x16}},
       {0x00, 0x20, 0x31, 0x12, 0x1C, 0x00, 0x04, 0x00, 0x00, 0x00, 0x01, 0x00, 0x01, 0x16}},
      {SdoInitiateDownloadResponse{0x6060, 0},
       {0x00, 0x30, 0x60, 0x60, 0x60, 0x00, 0x00, 0x00, 0x00, 0x00}},
      // Upload request plain (0x40) and complete access (0x50).
      {SdoInitiateUploadRequest{0x1C12, 0, true},
       {0x00, 0x20, 0x50, 0x12, 0x1C, 0x00, 0x00, 0x00, 0x00, 0x00}},
      // Expedited upload response of 2 bytes: 0x4B (the CoE manual example 0x5FD8:01 = 0x0FA0).
      {SdoInitiateUploadResponse{
           .index = 0x5FD8, .subindex = 1, .expedited = true, .data = {0xA0, 0x0F}},
       {0x00, 0x30, 0x4B, 0xD8, 0x5F, 0x01, 0xA0, 0x0F, 0x00, 0x00}},
      // Complete-access upload of 0x1C12 holding PDO 0x1601: SI0 padded to 16 bits.
      {SdoInitiateUploadResponse{.index = 0x1C12,
                                 .complete_access = true,
                                 .complete_size = 4,
                                 .data = {0x01, 0x00, 0x01, 0x16}},
       {0x00, 0x30, 0x51, 0x12, 0x1C, 0x00, 0x04, 0x00, 0x00, 0x00, 0x01, 0x00, 0x01, 0x16}},
      // Upload segment requests 0x60 / 0x70, download segment responses 0x20 / 0x30.
      {SdoUploadSegmentRequest{false}, {0x00, 0x20, 0x60, 0, 0, 0, 0, 0, 0, 0}},
      {SdoUploadSegmentRequest{true}, {0x00, 0x20, 0x70, 0, 0, 0, 0, 0, 0, 0}},
      {SdoDownloadSegmentResponse{false}, {0x00, 0x30, 0x20, 0, 0, 0, 0, 0, 0, 0}},
      {SdoDownloadSegmentResponse{true}, {0x00, 0x30, 0x30, 0, 0, 0, 0, 0, 0, 0}},
      // Last upload segment with 3 bytes: 4 unused (n=4), toggle 1: 0x19.
      {SdoUploadSegmentResponse{.toggle = true, .last = true, .data = {'a', 'b', 'c'}},
       {0x00, 0x30, 0x19, 'a', 'b', 'c', 0, 0, 0, 0}},
      // Full 7-byte download segment, not last, toggle 0: 0x00.
      {SdoDownloadSegmentRequest{.data = {1, 2, 3, 4, 5, 6, 7}},
       {0x00, 0x20, 0x00, 1, 2, 3, 4, 5, 6, 7}},
      // Longer segment: no padding, n = 0.
      {SdoDownloadSegmentRequest{.toggle = true, .last = true, .data = {1, 2, 3, 4, 5, 6, 7, 8}},
       {0x00, 0x20, 0x11, 1, 2, 3, 4, 5, 6, 7, 8}},
      // Aborts travel as SDO requests (service 2) from either side, as real stacks send them.
      {SdoAbort{0x6000, 0x02, 0x06020000},
       {0x00, 0x20, 0x80, 0x00, 0x60, 0x02, 0x00, 0x00, 0x02, 0x06}},
      {SdoAbort{0x1234, 0x05, 0x05040000, SdoDirection::request},
       {0x00, 0x20, 0x80, 0x34, 0x12, 0x05, 0x00, 0x00, 0x04, 0x05}},
      // The non-standard service-3 form some stacks send keeps its form through a round trip.
      {SdoAbort{0x6000, 0x02, 0x06020000, SdoDirection::response},
       {0x00, 0x30, 0x80, 0x00, 0x60, 0x02, 0x00, 0x00, 0x02, 0x06}},
  };
  for (const auto& [message, bytes] : cases) {
    SCOPED_TRACE(to_string(message));
    EXPECT_EQ(encoded(message), bytes);
    auto back = decode_sdo(bytes);
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, message);
  }
}

TEST(Sdo, DecodesSlaveVariantsTheEncoderDoesNotProduce) {
  // A download response echoing the written data in its reserved bytes.
  auto echo = decode_sdo(Vec{0x00, 0x30, 0x60, 0x08, 0xF0, 0x00, 0x01, 0x00, 0x00, 0x00});
  ASSERT_TRUE(echo.ok());
  EXPECT_EQ(*echo, SdoMessage(SdoInitiateDownloadResponse{0xF008, 0}));
  // Expedited upload response without size indicator (0x42): all 4 bytes, size unspecified.
  auto unsized = decode_sdo(Vec{0x00, 0x30, 0x42, 0x00, 0x10, 0x00, 0x91, 0x01, 0x0F, 0x00});
  ASSERT_TRUE(unsized.ok());
  EXPECT_EQ(*unsized, SdoMessage(SdoInitiateUploadResponse{.index = 0x1000,
                                                           .expedited = true,
                                                           .size_indicated = false,
                                                           .data = {0x91, 0x01, 0x0F, 0x00}}));
  // A normal upload response whose data holds everything (a "normal" rather than segmented one).
  auto normal = decode_sdo(Vec{0x00, 0x30, 0x41, 0x08, 0x10, 0x00, 0x06, 0x00, 0x00, 0x00, 'E', 'L',
                               '3', '0', '0', '4'});
  ASSERT_TRUE(normal.ok());
  const auto& n = std::get<SdoInitiateUploadResponse>(*normal);
  EXPECT_FALSE(n.expedited);
  EXPECT_EQ(n.complete_size, 6u);
  EXPECT_EQ(n.data, (Vec{'E', 'L', '3', '0', '0', '4'}));
  // Reserved bits of an upload segment request are ignored.
  EXPECT_EQ(*decode_sdo(Vec{0x00, 0x20, 0x7F, 1, 2, 3, 4, 5, 6, 7}),
            SdoMessage(SdoUploadSegmentRequest{true}));
}

TEST(Sdo, SegmentsPadShortDataToSevenBytes) {
  for (std::size_t size = 0; size <= 12; ++size) {
    for (bool toggle : {false, true}) {
      for (bool last : {false, true}) {
        Vec data(size);
        for (std::size_t i = 0; i < size; ++i)
          data[i] = static_cast<std::uint8_t>(0xA0 + i);
        for (SdoMessage m : {SdoMessage(SdoDownloadSegmentRequest{toggle, last, data}),
                             SdoMessage(SdoUploadSegmentResponse{toggle, last, data})}) {
          const Vec bytes = encoded(m);
          ASSERT_EQ(bytes.size(), 3 + std::max<std::size_t>(size, 7));
          const unsigned unused = size < 7 ? static_cast<unsigned>(7 - size) : 0;
          EXPECT_EQ((bytes[2] >> 1) & 0x07, unused);
          EXPECT_EQ((bytes[2] & 0x10) != 0, toggle);
          EXPECT_EQ((bytes[2] & 0x01) != 0, last);
          auto back = decode_sdo(bytes);
          ASSERT_TRUE(back.ok());
          EXPECT_EQ(*back, m);
        }
      }
    }
  }
}

TEST(Sdo, RoundTripsEveryMessage) {
  const SdoMessage messages[] = {
      SdoInitiateDownloadRequest{
          .index = 0x1, .subindex = 2, .complete_access = true, .expedited = true, .data = {9}},
      SdoInitiateDownloadRequest{
          .index = 0x2, .expedited = true, .size_indicated = false, .data = {1, 2, 3, 4}},
      SdoInitiateDownloadRequest{.index = 0x3, .complete_size = 100, .data = {}},
      SdoInitiateDownloadRequest{
          .index = 0x3, .size_indicated = false, .complete_size = 0, .data = {5, 5}},
      SdoInitiateDownloadResponse{0xFFFF, 0xFF},
      SdoDownloadSegmentRequest{true, false, Vec(100, 0x11)},
      SdoDownloadSegmentResponse{false},
      SdoInitiateUploadRequest{0x6041, 0, false},
      SdoInitiateUploadResponse{.index = 0x6041, .expedited = true, .data = {0x37, 0x02}},
      SdoInitiateUploadResponse{
          .index = 0x1C13, .complete_access = true, .complete_size = 1000, .data = Vec(200, 0x22)},
      SdoUploadSegmentRequest{true},
      SdoUploadSegmentResponse{true, true, {}},
      SdoAbort{0x1000, 0, 0x08000022, SdoDirection::response},
      SdoAbort{0x1000, 0, 0x05030000, SdoDirection::request},
  };
  for (const auto& m : messages) {
    SCOPED_TRACE(to_string(m));
    const Vec bytes = encoded(m);
    // The CoE service says the direction.
    EXPECT_EQ(bytes[1] >> 4, direction_of(m) == SdoDirection::request ? 2 : 3);
    auto back = decode_sdo(bytes);
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, m);
  }
}

TEST(Sdo, DirectionsAndNames) {
  EXPECT_EQ(direction_of(SdoInitiateDownloadRequest{}), SdoDirection::request);
  EXPECT_EQ(direction_of(SdoDownloadSegmentRequest{}), SdoDirection::request);
  EXPECT_EQ(direction_of(SdoInitiateUploadRequest{}), SdoDirection::request);
  EXPECT_EQ(direction_of(SdoUploadSegmentRequest{}), SdoDirection::request);
  EXPECT_EQ(direction_of(SdoInitiateDownloadResponse{}), SdoDirection::response);
  EXPECT_EQ(direction_of(SdoDownloadSegmentResponse{}), SdoDirection::response);
  EXPECT_EQ(direction_of(SdoInitiateUploadResponse{}), SdoDirection::response);
  EXPECT_EQ(direction_of(SdoUploadSegmentResponse{}), SdoDirection::response);
  EXPECT_EQ(direction_of(SdoAbort{.service = SdoDirection::response}), SdoDirection::response);
  EXPECT_EQ(direction_of(SdoAbort{}), SdoDirection::request);  // the standard form
  EXPECT_EQ(to_string(SdoMessage(SdoInitiateDownloadRequest{})), "initiate download request");
  EXPECT_EQ(to_string(SdoMessage(SdoInitiateDownloadResponse{})), "initiate download response");
  EXPECT_EQ(to_string(SdoMessage(SdoDownloadSegmentRequest{})), "download segment request");
  EXPECT_EQ(to_string(SdoMessage(SdoDownloadSegmentResponse{})), "download segment response");
  EXPECT_EQ(to_string(SdoMessage(SdoInitiateUploadRequest{})), "initiate upload request");
  EXPECT_EQ(to_string(SdoMessage(SdoInitiateUploadResponse{})), "initiate upload response");
  EXPECT_EQ(to_string(SdoMessage(SdoUploadSegmentRequest{})), "upload segment request");
  EXPECT_EQ(to_string(SdoMessage(SdoUploadSegmentResponse{})), "upload segment response");
  EXPECT_EQ(to_string(SdoMessage(SdoAbort{})), "abort transfer");
}

TEST(Sdo, DecodeErrors) {
  expect_decode_error({0x00}, Errc::truncated,
                      "CoE header: number/service at offset 0 needs 2 bytes, 1 remains");
  expect_decode_error({0x00, 0x20}, Errc::truncated,
                      "SDO: command at offset 2 needs 1 byte, 0 remain");
  expect_decode_error({0x00, 0x10, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0}, Errc::malformed,
                      "SDO: CoE service 1 (emergency) at offset 0 is neither SDO request (2) nor "
                      "SDO response (3)");
  expect_decode_error({0x00, 0x80, 0x01, 0x00, 0x00, 0x00}, Errc::malformed,
                      "SDO: CoE service 8 (SDO information) at offset 0 is neither SDO request "
                      "(2) nor SDO response (3)");
  for (std::uint8_t cmd : {0xA0, 0xC0, 0xE0}) {
    expect_decode_error({0x00, 0x20, cmd, 0, 0, 0, 0, 0, 0, 0}, Errc::malformed,
                        "SDO request: client command specifier " + std::to_string(cmd >> 5) +
                            " (command 0x" +
                            (cmd == 0xA0   ? "a0"
                             : cmd == 0xC0 ? "c0"
                                           : "e0") +
                            " at offset 2) is not valid for EtherCAT");
  }
  expect_decode_error({0x00, 0x30, 0xE0, 0, 0, 0, 0, 0, 0, 0}, Errc::malformed,
                      "SDO response: server command specifier 7 (command 0xe0 at offset 2) is not "
                      "valid for EtherCAT");
  expect_decode_error({0x00, 0x20, 0x23, 0x00}, Errc::truncated,
                      "SDO initiate download request: index at offset 3 needs 2 bytes, 1 remains");
  expect_decode_error({0x00, 0x20, 0x23, 0x00, 0x10}, Errc::truncated,
                      "SDO initiate download request: subindex at offset 5 needs 1 byte, 0 remain");
  expect_decode_error({0x00, 0x20, 0x23, 0x00, 0x10, 0x00, 0x01, 0x02}, Errc::truncated,
                      "SDO initiate download request: expedited data at offset 6 needs 4 bytes, "
                      "2 remain");
  expect_decode_error({0x00, 0x20, 0x21, 0x00, 0x10, 0x00, 0x01}, Errc::truncated,
                      "SDO initiate download request: complete size at offset 6 needs 4 bytes, 1 "
                      "remains");
  expect_decode_error({0x00, 0x30, 0x41, 0x00, 0x10, 0x00}, Errc::truncated,
                      "SDO initiate upload response: complete size at offset 6 needs 4 bytes, 0 "
                      "remain");
  expect_decode_error({0x00, 0x20, 0x00, 0x01, 0x02, 0x03}, Errc::truncated,
                      "SDO download segment request: segment data at offset 3 needs 7 bytes, 3 "
                      "remain");
  expect_decode_error({0x00, 0x30, 0x01}, Errc::truncated,
                      "SDO upload segment response: segment data at offset 3 needs 7 bytes, 0 "
                      "remain");
  expect_decode_error({0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0x00, 0x00}, Errc::truncated,
                      "SDO initiate upload request: reserved bytes at offset 6 needs 4 bytes, 2 "
                      "remain");
  expect_decode_error({0x00, 0x30, 0x60, 0x18, 0x10}, Errc::truncated,
                      "SDO initiate download response: subindex at offset 5 needs 1 byte, 0 "
                      "remain");
  expect_decode_error({0x00, 0x30, 0x80, 0x00, 0x60, 0x02, 0x00, 0x00, 0x02}, Errc::truncated,
                      "SDO abort transfer: abort code at offset 6 needs 4 bytes, 3 remain");
  expect_decode_error({0x00, 0x20, 0x60, 0x00}, Errc::truncated,
                      "SDO upload segment request: reserved bytes at offset 3 needs 7 bytes, 1 "
                      "remains");
  expect_decode_error({0x00, 0x30, 0x20, 0, 0, 0, 0, 0, 0}, Errc::truncated,
                      "SDO download segment response: reserved bytes at offset 3 needs 7 bytes, 6 "
                      "remain");
}

TEST(Sdo, EncodeErrors) {
  expect_encode_error(SdoInitiateDownloadRequest{.expedited = true, .data = {}},
                      "SDO initiate download request: expedited data must be 1 to 4 bytes, is 0");
  expect_encode_error(SdoInitiateUploadResponse{.expedited = true, .data = {1, 2, 3, 4, 5}},
                      "SDO initiate upload response: expedited data must be 1 to 4 bytes, is 5");
  expect_encode_error(
      SdoInitiateDownloadRequest{.expedited = true, .size_indicated = false, .data = {1, 2, 3}},
      "SDO initiate download request: expedited data without size indicator must be 4 bytes, is "
      "3");
  expect_encode_error(
      SdoInitiateDownloadRequest{.expedited = true, .complete_size = 4, .data = {1, 2, 3, 4}},
      "SDO initiate download request: complete_size must be 0 for an expedited transfer, is 4");
  expect_encode_error(SdoInitiateDownloadRequest{.complete_size = 65530, .data = Vec(65526)},
                      "SDO initiate download request: 65536 bytes exceed the mailbox length limit "
                      "of 65535");
  expect_encode_error(SdoUploadSegmentResponse{.data = Vec(65533)},
                      "SDO upload segment response: 65536 bytes exceed the mailbox length limit of "
                      "65535");
  // The largest that fits.
  EXPECT_TRUE(encode_sdo(SdoUploadSegmentResponse{.data = Vec(65532)}).ok());
}

// --- complete access ---

TEST(CompleteAccess, SplitsThePaddedSubindexZero) {
  const Vec value{0x01, 0x00, 0x01, 0x16};
  auto split = split_complete_access(value);
  ASSERT_TRUE(split.ok());
  EXPECT_EQ(split->subindex0, 1);
  EXPECT_EQ(Vec(split->entries.begin(), split->entries.end()), (Vec{0x01, 0x16}));
  auto assigned = complete_access_u16_entries(value);
  ASSERT_TRUE(assigned.ok());
  EXPECT_EQ(*assigned, (std::vector<std::uint16_t>{0x1601}));
  EXPECT_EQ(join_complete_access(1, Vec{0x01, 0x16}), value);
}

TEST(CompleteAccess, MappingEntriesAndExtraBytes) {
  // 0x1A00 with two 32-bit mapping entries 0x6000:01 16 bits and 0x6000:02 16 bits, then bytes of
  // a third entry beyond subindex 0's count (ignored).
  const Vec value{0x02, 0x00, 0x10, 0x01, 0x00, 0x60, 0x10,
                  0x02, 0x00, 0x60, 0xAA, 0xBB, 0xCC, 0xDD};
  auto entries = complete_access_u32_entries(value);
  ASSERT_TRUE(entries.ok());
  EXPECT_EQ(*entries, (std::vector<std::uint32_t>{0x60000110, 0x60000210}));
  auto none = complete_access_u16_entries(Vec{0x00, 0x00});
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
}

TEST(CompleteAccess, Errors) {
  auto one_byte = split_complete_access(Vec{0x01});
  ASSERT_FALSE(one_byte.ok());
  EXPECT_EQ(one_byte.error().code(), Errc::truncated);
  EXPECT_EQ(one_byte.error().message(),
            "complete-access value: subindex 0 padding at offset 1 needs 1 byte, 0 remain");
  auto short_list = complete_access_u16_entries(Vec{0x03, 0x00, 0x00, 0x16, 0x01, 0x16});
  ASSERT_FALSE(short_list.ok());
  EXPECT_EQ(short_list.error().code(), Errc::truncated);
  EXPECT_EQ(short_list.error().message(),
            "complete-access value: subindex 0 counts 3 entries of 2 bytes (6 bytes from offset "
            "2), only 4 bytes follow");
  EXPECT_FALSE(complete_access_u32_entries(Vec{0x01, 0x00, 0x10, 0x01, 0x00}).ok());
  EXPECT_FALSE(complete_access_u32_entries(Bytes{}).ok());
}

// --- emergency ---

TEST(Emergency, DecodesAndEncodesExactly) {
  const Vec bytes{0x00, 0x10, 0x11, 0x86, 0x80, 0x01, 0x02, 0x03, 0x04, 0x05};
  auto e = decode_emergency(bytes);
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(e->error_code, 0x8611);
  EXPECT_EQ(e->error_register, 0x80);
  EXPECT_EQ(e->data, (std::array<std::uint8_t, 5>{1, 2, 3, 4, 5}));
  std::uint8_t buf[kEmergencySize];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_emergency(*e, w).ok());
  EXPECT_EQ(Vec(buf, buf + kEmergencySize), bytes);
  // Trailing bytes beyond the 10 are ignored.
  Vec longer = bytes;
  longer.push_back(0xFF);
  EXPECT_EQ(*decode_emergency(longer), *e);
}

TEST(Emergency, Errors) {
  auto short_one = decode_emergency(Vec{0x00, 0x10, 0x11, 0x86, 0x80, 0x01});
  ASSERT_FALSE(short_one.ok());
  EXPECT_EQ(short_one.error().code(), Errc::truncated);
  EXPECT_EQ(short_one.error().message(),
            "CoE emergency: manufacturer data at offset 5 needs 5 bytes, 1 remains");
  auto wrong = decode_emergency(Vec{0x00, 0x30, 0x11, 0x86, 0x80, 0, 0, 0, 0, 0});
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().code(), Errc::malformed);
  EXPECT_EQ(wrong.error().message(),
            "CoE emergency: CoE service 3 at offset 0 is not emergency (1)");
  std::uint8_t small[9];
  ByteWriter w(small);
  auto r = encode_emergency({}, w);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "CoE emergency: needs 10 bytes of buffer, 9 left");
}

TEST(Emergency, ErrorCodeTexts) {
  const std::pair<std::uint16_t, const char*> expected[] = {
      {0x0000, "no error"},
      {0x0001, "error reset or no error"},
      {0x1000, "generic error"},
      {0x1234, "generic error"},
      {0x2000, "current"},
      {0x2110, "current, device input side"},
      {0x2200, "current inside the device"},
      {0x2310, "current, device output side"},
      {0x3000, "voltage"},
      {0x3120, "mains voltage"},
      {0x3210, "voltage inside the device"},
      {0x3310, "output voltage"},
      {0x4000, "temperature"},
      {0x4110, "ambient temperature"},
      {0x4210, "device temperature"},
      {0x5000, "device hardware"},
      {0x5530, "device hardware"},
      {0x6000, "device software"},
      {0x6100, "internal software"},
      {0x6200, "user software"},
      {0x6320, "data set"},
      {0x7000, "additional modules"},
      {0x7305, "additional modules"},
      {0x8000, "monitoring"},
      {0x8100, "communication"},
      {0x8110, "CAN overrun (objects lost)"},
      {0x8120, "CAN in error passive mode"},
      {0x8130, "life guard error or heartbeat error"},
      {0x8140, "recovered from bus off"},
      {0x8150, "CAN-ID collision"},
      {0x8200, "protocol error"},
      {0x8210, "PDO not processed due to length error"},
      {0x8220, "PDO length exceeded"},
      {0x8230, "DAM MPDO not processed, destination object not available"},
      {0x8240, "unexpected SYNC data length"},
      {0x8250, "RPDO timeout"},
      {0x8611, "following error"},
      {0x8612, "reference limit"},
      {0x8700, "monitoring"},
      {0x9000, "external error"},
      {0xA000, "unknown error code class"},
      {0xE123, "unknown error code class"},
      {0xF000, "additional functions"},
      {0xF100, "additional functions"},
      {0xFF00, "device specific"},
      {0xFF42, "device specific"},
  };
  for (const auto& [code, text] : expected) {
    EXPECT_EQ(emergency_error_text(code), text) << std::hex << code;
  }
}

}  // namespace
}  // namespace ecat::wire

namespace ecat::wire {
namespace {

// A slave's refusal exactly as real slave stacks put it into SM1 (SOES' SDO abort, KickCAT's
// simulated slave, Beckhoff terminals): mailbox header (length 10, address 0, channel 0,
// priority 0, type 3 CoE, counter 2), CoE header with service 2 (SDO request), command 0x80,
// 0x6041:00, abort code 0x06020000 little endian. The IgH master recognises an abort only in this
// form (CoE service 2 and command specifier 4).
TEST(Sdo, AnAbortAsRealSlaveStacksSendItDecodesWithItsCode) {
  const std::vector<std::uint8_t> mailbox = {0x0A, 0x00, 0x00, 0x00, 0x00, 0x23, 0x00, 0x20,
                                             0x80, 0x41, 0x60, 0x00, 0x00, 0x00, 0x02, 0x06};
  auto header = decode_mailbox_header(mailbox);
  ASSERT_TRUE(header.ok()) << header.error().message();
  EXPECT_EQ(header->type, MailboxType::coe);
  EXPECT_EQ(header->length, 10);
  auto sdo = decode_sdo(Bytes(mailbox).subspan(kMailboxHeaderSize));
  ASSERT_TRUE(sdo.ok()) << sdo.error().message();
  const auto* abort = std::get_if<SdoAbort>(&*sdo);
  ASSERT_NE(abort, nullptr) << to_string(*sdo);
  EXPECT_EQ(abort->index, 0x6041);
  EXPECT_EQ(abort->subindex, 0);
  EXPECT_EQ(abort->code, 0x06020000u);
  EXPECT_EQ(abort->service, SdoDirection::request);
  // And ecat's encoder (the simulator's refusals) produces these very bytes.
  auto ours = encode_sdo(SdoAbort{0x6041, 0, 0x06020000});
  ASSERT_TRUE(ours.ok());
  EXPECT_EQ(*ours, std::vector<std::uint8_t>(mailbox.begin() + kMailboxHeaderSize, mailbox.end()));
}

}  // namespace
}  // namespace ecat::wire
