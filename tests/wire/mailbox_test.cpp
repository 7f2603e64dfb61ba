#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/soe.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::wire {
namespace {

using Vec = std::vector<std::uint8_t>;
using Vec16 = std::vector<std::uint16_t>;

Vec mailbox(MailboxType type, std::uint8_t counter, const Vec& data) {
  MailboxHeader h;
  h.type = type;
  h.counter = counter;
  auto out = encode_mailbox(h, data);
  EXPECT_TRUE(out.ok());
  return out.ok() ? *out : Vec{};
}

template <class T>
Vec value_of(Result<T> r) {
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? Vec(*r) : Vec{};
}

// --- header ---

TEST(MailboxHeader, EncodesTheSpecLayout) {
  MailboxHeader h{.length = 10,
                  .address = 0,
                  .channel = 0,
                  .priority = 0,
                  .type = MailboxType::coe,
                  .counter = 1};
  std::uint8_t buf[6];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_mailbox_header(h, w).ok());
  EXPECT_EQ(Vec(buf, buf + 6), (Vec{0x0a, 0x00, 0x00, 0x00, 0x00, 0x13}));
}

TEST(MailboxHeader, PacksChannelPriorityTypeAndCounterBits) {
  MailboxHeader h{.length = 0x1234,
                  .address = 0xBEEF,
                  .channel = 0x3F,
                  .priority = 3,
                  .type = MailboxType::voe,
                  .counter = 7};
  std::uint8_t buf[6];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_mailbox_header(h, w).ok());
  EXPECT_EQ(Vec(buf, buf + 6), (Vec{0x34, 0x12, 0xEF, 0xBE, 0xFF, 0x7F}));
  auto back = decode_mailbox_header(Bytes(buf));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, h);

  MailboxHeader g{.length = 1,
                  .address = 2,
                  .channel = 0x15,
                  .priority = 1,
                  .type = MailboxType::foe,
                  .counter = 5};
  ByteWriter w2(buf);
  ASSERT_TRUE(encode_mailbox_header(g, w2).ok());
  EXPECT_EQ(buf[4], 0x55);
  EXPECT_EQ(buf[5], 0x54);
  EXPECT_EQ(*decode_mailbox_header(Bytes(buf)), g);
}

TEST(MailboxHeader, DecodeIgnoresReservedBitAndKeepsReservedTypes) {
  const Vec bytes{0x0a, 0x00, 0x00, 0x00, 0x00, 0x93};
  auto h = decode_mailbox_header(bytes);
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->type, MailboxType::coe);
  EXPECT_EQ(h->counter, 1);
  auto reserved = decode_mailbox_header(Vec{0, 0, 0, 0, 0, 0x27});
  ASSERT_TRUE(reserved.ok());
  EXPECT_EQ(static_cast<int>(reserved->type), 7);
  EXPECT_EQ(to_string(reserved->type), "reserved");
}

TEST(MailboxHeader, EncodeRejectsFieldsThatDoNotFit) {
  std::uint8_t buf[6];
  auto check = [&](MailboxHeader h, const std::string& message) {
    ByteWriter w(buf);
    auto r = encode_mailbox_header(h, w);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code(), Errc::invalid_argument);
    EXPECT_EQ(r.error().message(), message);
  };
  check({.channel = 64}, "mailbox header: channel 64 exceeds 63");
  check({.priority = 4}, "mailbox header: priority 4 exceeds 3");
  check({.counter = 8}, "mailbox header: counter 8 exceeds 7");
  check({.type = static_cast<MailboxType>(16)}, "mailbox header: type 16 exceeds 15");

  std::uint8_t small[5];
  ByteWriter w(small);
  auto r = encode_mailbox_header({}, w);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::out_of_range);
  EXPECT_EQ(r.error().message(), "mailbox header: needs 6 bytes of buffer, 5 left");
}

TEST(MailboxHeader, DecodeNamesTheMissingField) {
  auto r = decode_mailbox_header(Vec{0x0a, 0x00, 0x00, 0x00, 0x00});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::truncated);
  EXPECT_EQ(r.error().message(), "mailbox header: type/counter at offset 5 needs 1 byte, 0 remain");
  auto empty = decode_mailbox_header(Bytes{});
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.error().message(), "mailbox header: length at offset 0 needs 2 bytes, 0 remain");
  auto one = decode_mailbox_header(Vec{0x0a, 0x00, 0x01});
  ASSERT_FALSE(one.ok());
  EXPECT_EQ(one.error().message(), "mailbox header: address at offset 2 needs 2 bytes, 1 remains");
}

TEST(MailboxCounter, CyclesOneToSevenAndNeverReturnsZero) {
  EXPECT_EQ(next_mailbox_counter(0), 1);
  for (std::uint8_t c = 1; c < 7; ++c)
    EXPECT_EQ(next_mailbox_counter(c), c + 1);
  EXPECT_EQ(next_mailbox_counter(7), 1);
  std::uint8_t c = 0;
  for (int i = 0; i < 50; ++i) {
    c = next_mailbox_counter(c);
    EXPECT_GE(c, 1);
    EXPECT_LE(c, 7);
  }
  for (int v = 0; v < 256; ++v)
    EXPECT_NE(next_mailbox_counter(static_cast<std::uint8_t>(v)), 0);
}

// --- whole mailboxes ---

TEST(Mailbox, DecodeTrimsToTheLengthFieldAndIgnoresPadding) {
  const Vec buffer{0x04, 0x00, 0x00, 0x00, 0x00, 0x23, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF, 0x00};
  auto m = decode_mailbox(buffer);
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->header.length, 4);
  EXPECT_EQ(m->header.counter, 2);
  EXPECT_EQ(Vec(m->data.begin(), m->data.end()), (Vec{0xAA, 0xBB, 0xCC, 0xDD}));
}

TEST(Mailbox, DecodeRejectsALengthBeyondTheBuffer) {
  const Vec buffer{0x0b, 0x00, 0x00, 0x00, 0x00, 0x13, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  auto m = decode_mailbox(buffer);
  ASSERT_FALSE(m.ok());
  EXPECT_EQ(m.error().code(), Errc::truncated);
  EXPECT_EQ(m.error().message(),
            "mailbox: length field says 11 bytes of data, only 10 follow the header");
  EXPECT_FALSE(decode_mailbox(Vec{0x00, 0x00}).ok());
}

TEST(Mailbox, EncodeFillsTheWholeSyncManagerBuffer) {
  Vec sm(16, 0xAA);
  MailboxHeader h{.address = 0x1001, .type = MailboxType::coe, .counter = 3};
  auto n = encode_mailbox(h, Vec{1, 2, 3}, MutableBytes(sm));
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(*n, 9u);
  EXPECT_EQ(sm, (Vec{0x03, 0x00, 0x01, 0x10, 0x00, 0x33, 1, 2, 3, 0, 0, 0, 0, 0, 0, 0}));

  Vec too_small(8);
  auto r = encode_mailbox(h, Vec{1, 2, 3}, MutableBytes(too_small));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "mailbox: needs 9 bytes of buffer, 8 left");

  Vec huge(0x10000);
  auto big = encode_mailbox(h, huge);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().code(), Errc::invalid_argument);
  EXPECT_EQ(big.error().message(), "mailbox: 65536 bytes of data exceed the 16-bit length field");

  auto bad = encode_mailbox(MailboxHeader{.counter = 9}, Vec{1});
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(), "mailbox header: counter 9 exceeds 7");
}

TEST(Mailbox, RoundTrips) {
  for (auto type : {MailboxType::error, MailboxType::aoe, MailboxType::eoe, MailboxType::coe,
                    MailboxType::foe, MailboxType::soe, MailboxType::voe}) {
    MailboxHeader h{.address = 7, .channel = 2, .priority = 1, .type = type, .counter = 6};
    const Vec data{9, 8, 7, 6, 5};
    auto encoded = encode_mailbox(h, data);
    ASSERT_TRUE(encoded.ok());
    auto decoded = decode_mailbox(*encoded);
    ASSERT_TRUE(decoded.ok());
    h.length = 5;
    EXPECT_EQ(decoded->header, h);
    EXPECT_EQ(Vec(decoded->data.begin(), decoded->data.end()), data);
  }
}

TEST(MailboxType, Names) {
  EXPECT_EQ(to_string(MailboxType::error), "error");
  EXPECT_EQ(to_string(MailboxType::aoe), "AoE");
  EXPECT_EQ(to_string(MailboxType::eoe), "EoE");
  EXPECT_EQ(to_string(MailboxType::coe), "CoE");
  EXPECT_EQ(to_string(MailboxType::foe), "FoE");
  EXPECT_EQ(to_string(MailboxType::soe), "SoE");
  EXPECT_EQ(to_string(MailboxType::voe), "VoE");
}

// --- mailbox error replies ---

TEST(MailboxError, DecodesAnInvalidHeaderReply) {
  const Vec buffer{0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x05, 0x00};
  auto m = decode_mailbox(buffer);
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->header.type, MailboxType::error);
  auto reply = decode_mailbox_error(m->data);
  ASSERT_TRUE(reply.ok());
  EXPECT_EQ(reply->detail, 0x0005);
  EXPECT_EQ(mailbox_error_text(reply->detail), "invalid header");
}

TEST(MailboxError, RoundTripsAndEncodesExactly) {
  std::uint8_t buf[4];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_mailbox_error({0x0008}, w).ok());
  EXPECT_EQ(Vec(buf, buf + 4), (Vec{0x01, 0x00, 0x08, 0x00}));
  EXPECT_EQ(*decode_mailbox_error(Bytes(buf)), MailboxErrorReply{0x0008});
  std::uint8_t small[3];
  ByteWriter ws(small);
  EXPECT_FALSE(encode_mailbox_error({1}, ws).ok());
}

TEST(MailboxError, DecodeErrors) {
  auto wrong = decode_mailbox_error(Vec{0x02, 0x00, 0x01, 0x00});
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().code(), Errc::malformed);
  EXPECT_EQ(wrong.error().message(),
            "mailbox error reply: service type at offset 0 is 0x0002, expected 0x0001");
  auto short_reply = decode_mailbox_error(Vec{0x01, 0x00, 0x01});
  ASSERT_FALSE(short_reply.ok());
  EXPECT_EQ(short_reply.error().message(),
            "mailbox error reply: detail at offset 2 needs 2 bytes, 1 remains");
}

TEST(MailboxError, EveryDetailCodeHasItsText) {
  const std::pair<std::uint16_t, const char*> expected[] = {
      {0x01, "syntax error"},          {0x02, "unsupported protocol"}, {0x03, "invalid channel"},
      {0x04, "service not supported"}, {0x05, "invalid header"},       {0x06, "size too short"},
      {0x07, "no more memory"},        {0x08, "invalid size"},         {0x09, "service in work"},
  };
  for (const auto& [code, text] : expected)
    EXPECT_EQ(mailbox_error_text(code), text);
  EXPECT_EQ(mailbox_error_text(0x0000), "unknown mailbox error 0x0000");
  EXPECT_EQ(mailbox_error_text(0x1234), "unknown mailbox error 0x1234");
}

// --- summaries ---

TEST(MailboxSummary, NotAMailbox) {
  EXPECT_EQ(summarize_mailbox(Bytes{}), "");
  EXPECT_EQ(summarize_mailbox(Vec{0x0a, 0x00, 0x00, 0x00, 0x00}), "");
  EXPECT_EQ(summarize_mailbox(Vec(128, 0)), "");  // an empty mailbox read back
}

TEST(MailboxSummary, SdoUploadRequestAndExpeditedResponse) {
  const Vec request{0x0a, 0x00, 0x00, 0x00, 0x00, 0x33, 0x00, 0x20,
                    0x40, 0x18, 0x10, 0x01, 0x00, 0x00, 0x00, 0x00};
  EXPECT_EQ(summarize_mailbox(request), "mbx CoE cnt=3 SDO upload req 0x1018:01");
  Vec padded = request;
  padded.resize(128, 0);
  EXPECT_EQ(summarize_mailbox(padded), "mbx CoE cnt=3 SDO upload req 0x1018:01");

  const Vec response{0x0a, 0x00, 0x00, 0x00, 0x00, 0x43, 0x00, 0x30,
                     0x43, 0x18, 0x10, 0x01, 0x02, 0x00, 0x00, 0x00};
  EXPECT_EQ(summarize_mailbox(response),
            "mbx CoE cnt=4 SDO upload resp expedited 0x1018:01 = 02 00 00 00");
}

TEST(MailboxSummary, EverySdoMessage) {
  auto sdo = [](SdoMessage m, std::uint8_t counter = 1) {
    return summarize_mailbox(mailbox(MailboxType::coe, counter, value_of(encode_sdo(m))));
  };
  EXPECT_EQ(sdo(SdoAbort{0x6000, 2, 0x06020000}, 5),
            "mbx CoE cnt=5 SDO abort 0x6000:02 0x06020000 (object does not exist in the object "
            "dictionary)");
  EXPECT_EQ(sdo(SdoAbort{0x1234, 0, 0x12345678, SdoDirection::request}),
            "mbx CoE cnt=1 SDO abort 0x1234:00 0x12345678 (unknown SDO abort code 0x12345678)");
  EXPECT_EQ(sdo(SdoInitiateDownloadRequest{
                .index = 0xF008, .subindex = 0, .expedited = true, .data = {1, 0, 0, 0}}),
            "mbx CoE cnt=1 SDO download req expedited 0xF008:00 = 01 00 00 00");
  EXPECT_EQ(sdo(SdoInitiateDownloadRequest{.index = 0x1C12,
                                           .subindex = 0,
                                           .complete_access = true,
                                           .complete_size = 4,
                                           .data = {1, 0, 1, 0x16}}),
            "mbx CoE cnt=1 SDO download req normal 0x1C12:00 complete-access size=4 = 01 00 01 16");
  EXPECT_EQ(sdo(SdoInitiateDownloadResponse{0xF008, 0}),
            "mbx CoE cnt=1 SDO download resp 0xF008:00");
  EXPECT_EQ(sdo(SdoDownloadSegmentRequest{.toggle = true, .last = true, .data = {0xAB}}),
            "mbx CoE cnt=1 SDO download segment req toggle=1 last = ab");
  EXPECT_EQ(sdo(SdoDownloadSegmentResponse{true}),
            "mbx CoE cnt=1 SDO download segment resp toggle=1");
  EXPECT_EQ(sdo(SdoInitiateUploadRequest{0x1C13, 0, true}),
            "mbx CoE cnt=1 SDO upload req 0x1C13:00 complete-access");
  EXPECT_EQ(sdo(SdoInitiateUploadResponse{
                .index = 0x1008, .subindex = 0, .complete_size = 30, .data = Vec(20, 0x41)}),
            "mbx CoE cnt=1 SDO upload resp normal 0x1008:00 size=30 = 41 41 41 41 41 41 41 41 41 "
            "41 41 41 41 41 41 41 ... (20 bytes)");
  EXPECT_EQ(sdo(SdoUploadSegmentRequest{false}), "mbx CoE cnt=1 SDO upload segment req toggle=0");
  EXPECT_EQ(sdo(SdoUploadSegmentResponse{
                .toggle = false, .last = false, .data = {1, 2, 3, 4, 5, 6, 7, 8}}),
            "mbx CoE cnt=1 SDO upload segment resp toggle=0 = 01 02 03 04 05 06 07 08");
}

TEST(MailboxSummary, EmergencyAndOtherCoeServices) {
  std::uint8_t buf[kEmergencySize];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_emergency({0x8611, 0x80, {}}, w).ok());
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::coe, 1, Vec(buf, buf + 10))),
            "mbx CoE cnt=1 emergency 0x8611 (following error) reg=0x80");
  ByteWriter w2(buf);
  ASSERT_TRUE(encode_emergency({0x2310, 0x03, {1, 0, 0, 0, 2}}, w2).ok());
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::coe, 2, Vec(buf, buf + 10))),
            "mbx CoE cnt=2 emergency 0x2310 (current, device output side) reg=0x03 data=01 00 00 "
            "00 02");
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::coe, 1, Vec{0x03, 0x40, 0x11, 0x22})),
            "mbx CoE cnt=1 TxPDO number=3 = 11 22");
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::coe, 1, Vec{0x00, 0xF0, 0x11})),
            "mbx CoE cnt=1 service 15 3 bytes");
}

TEST(MailboxSummary, SdoInformation) {
  auto info = [](SdoInfoMessage m) {
    return summarize_mailbox(mailbox(MailboxType::coe, 2, value_of(encode_sdo_info(m))));
  };
  EXPECT_EQ(info(OdListRequest{OdListType::all}),
            "mbx CoE cnt=2 SDO info get OD list req type=all");
  EXPECT_EQ(info(OdListResponse{OdListType::all, {0x1000, 0x1018, 0x1C12}}),
            "mbx CoE cnt=2 SDO info get OD list resp type=all 3 objects: 0x1000 0x1018 0x1C12");
  EXPECT_EQ(info(OdListResponse{OdListType::number_of_objects, {12, 3, 4, 0, 0}}),
            "mbx CoE cnt=2 SDO info get OD list resp type=number of objects 5 counts: 12 3 4 0 0");
  EXPECT_EQ(info(ObjectDescriptionRequest{0x1018}),
            "mbx CoE cnt=2 SDO info get object description req 0x1018");
  EXPECT_EQ(info(ObjectDescriptionResponse{0x1018, 0x0023, 4, ObjectCode::record, "Identity"}),
            "mbx CoE cnt=2 SDO info get object description resp 0x1018 'Identity' RECORD "
            "type=0x0023 max subindex=4");
  EXPECT_EQ(info(EntryDescriptionRequest{0x1018, 1, 0x07}),
            "mbx CoE cnt=2 SDO info get entry description req 0x1018:01 value info=0x07");
  EXPECT_EQ(info(EntryDescriptionResponse{.index = 0x1018,
                                          .subindex = 1,
                                          .value_info = 0x07,
                                          .data_type = 7,
                                          .bit_length = 32,
                                          .object_access = 0x0007,
                                          .description = "Vendor ID"}),
            "mbx CoE cnt=2 SDO info get entry description resp 0x1018:01 'Vendor ID' type=0x0007 "
            "bits=32 access=0x0007");
  EXPECT_EQ(info(SdoInfoError{0x06020000}),
            "mbx CoE cnt=2 SDO info error 0x06020000 (object does not exist in the object "
            "dictionary)");
  auto fragments =
      encode_sdo_info_fragments(OdListResponse{OdListType::all, Vec16(40, 0x2000)}, 30);
  ASSERT_TRUE(fragments.ok());
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::coe, 2, fragments->front())),
            "mbx CoE cnt=2 SDO info get OD list resp fragment (3 left) 24 bytes");
}

TEST(MailboxSummary, OtherProtocols) {
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::foe, 1,
                                      value_of(encode_foe(FoeReadRequest{0, "firmware.bin"})))),
            "mbx FoE cnt=1 read req 'firmware.bin'");
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::foe, 2,
                                      value_of(encode_foe(FoeError{0x8001, "no such file"})))),
            "mbx FoE cnt=2 error 0x00008001 (file not found) 'no such file'");
  EoeSetIpRequest set_ip;
  set_ip.parameters.ip = 0xC0A80102;
  set_ip.parameters.subnet_mask = 0xFFFFFF00;
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::eoe, 3, value_of(encode_eoe(set_ip)))),
            "mbx EoE cnt=3 set IP req ip=192.168.1.2 mask=255.255.255.0");
  EoeFragment fragment;
  fragment.header = {.last_fragment = true, .offset_blocks = 2, .frame_number = 4};
  fragment.data = Vec(60, 0xFF);
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::eoe, 4, value_of(encode_eoe(fragment)))),
            "mbx EoE cnt=4 fragment frame=4 part=0 size=64 last 60 bytes");
  SoeMessage soe;
  soe.header = {.opcode = SoeOpcode::read_request, .elements = kSoeElementValue, .idn = 1};
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::soe, 5, value_of(encode_soe(soe)))),
            "mbx SoE cnt=5 read request drive=0 S-0-0001 elements=0x40");
  EXPECT_EQ(summarize_mailbox(mailbox(MailboxType::aoe, 6, Vec{1, 2, 3})), "mbx AoE cnt=6 3 bytes");
  EXPECT_EQ(summarize_mailbox(mailbox(static_cast<MailboxType>(9), 1, Vec{1})),
            "mbx type=9 cnt=1 1 bytes");
}

TEST(MailboxSummary, MailboxErrorReply) {
  const Vec buffer{0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x05, 0x00};
  EXPECT_EQ(summarize_mailbox(buffer), "mbx error: invalid header");
  const Vec bad{0x02, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00};
  EXPECT_EQ(summarize_mailbox(bad),
            "mbx error (malformed: mailbox error reply: detail at offset 2 needs 2 bytes, 0 "
            "remain)");
}

TEST(MailboxSummary, MalformedBodies) {
  // Length field beyond the buffer.
  EXPECT_EQ(summarize_mailbox(Vec{0x20, 0x00, 0x00, 0x00, 0x00, 0x13, 0x00, 0x20}),
            "mbx CoE cnt=1 (malformed: mailbox: length field says 32 bytes of data, only 2 follow "
            "the header)");
  // SDO upload response cut inside its expedited data.
  EXPECT_EQ(summarize_mailbox(
                Vec{0x06, 0x00, 0x00, 0x00, 0x00, 0x13, 0x00, 0x30, 0x43, 0x18, 0x10, 0x01}),
            "mbx CoE cnt=1 (malformed: SDO initiate upload response: expedited data at offset 6 "
            "needs 4 bytes, 0 remain)");
  EXPECT_EQ(summarize_mailbox(Vec{0x01, 0x00, 0x00, 0x00, 0x00, 0x13, 0x00}),
            "mbx CoE cnt=1 (malformed: CoE header: number/service at offset 0 needs 2 bytes, 1 "
            "remains)");
  EXPECT_EQ(summarize_mailbox(Vec{0x01, 0x00, 0x00, 0x00, 0x00, 0x14, 0x07}),
            "mbx FoE cnt=1 (malformed: FoE: reserved at offset 1 needs 1 byte, 0 remain)");
}

TEST(MailboxSummary, NeverReadsOutOfBoundsOnAnyPrefix) {
  // Every prefix of a real-looking mailbox: summaries exist or are empty, and ASan watches reads.
  const Vec full = mailbox(MailboxType::coe, 1,
                           value_of(encode_sdo(SdoInitiateUploadResponse{
                               .index = 0x1008, .complete_size = 6, .data = {1, 2, 3, 4, 5, 6}})));
  for (std::size_t n = 0; n <= full.size(); ++n) {
    // An exact-size heap block, so ASan sees any read past the end.
    const Vec copy(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(n));
    const std::string s = summarize_mailbox(copy);
    if (n < kMailboxHeaderSize) {
      EXPECT_EQ(s, "");
    } else {
      EXPECT_EQ(s.rfind("mbx CoE cnt=1", 0), 0u) << s;
    }
  }
}

// --- committed fuzz seeds: generated from the encoders, and must keep decoding ---

std::vector<std::pair<std::string, Vec>> generated_seeds() {
  std::vector<std::pair<std::string, Vec>> seeds;
  auto coe = [&](const char* name, std::uint8_t counter, Vec data) {
    seeds.emplace_back(name, mailbox(MailboxType::coe, counter, std::move(data)));
  };
  coe("sdo_upload_req", 1, value_of(encode_sdo(SdoInitiateUploadRequest{0x1018, 1, false})));
  coe("sdo_upload_resp_expedited", 1,
      value_of(encode_sdo(SdoInitiateUploadResponse{
          .index = 0x1018, .subindex = 1, .expedited = true, .data = {2, 0, 0, 0}})));
  coe("sdo_upload_resp_normal", 2,
      value_of(encode_sdo(SdoInitiateUploadResponse{
          .index = 0x1008, .complete_size = 14, .data = {'E', 'L', '3', '0', '0', '4'}})));
  coe("sdo_upload_segment_resp", 3,
      value_of(encode_sdo(SdoUploadSegmentResponse{
          .toggle = false, .last = true, .data = {'-', '0', '0', '0', '0', '.', '1', '9'}})));
  coe("sdo_ca_upload_resp", 4,
      value_of(encode_sdo(SdoInitiateUploadResponse{.index = 0x1C12,
                                                    .complete_access = true,
                                                    .complete_size = 4,
                                                    .data = {1, 0, 0x01, 0x16}})));
  coe("sdo_download_req_expedited", 5,
      value_of(encode_sdo(
          SdoInitiateDownloadRequest{.index = 0xF008, .expedited = true, .data = {1, 0, 0, 0}})));
  coe("sdo_download_segment_req", 6,
      value_of(encode_sdo(SdoDownloadSegmentRequest{.toggle = true, .last = true, .data = {7}})));
  coe("sdo_abort", 7, value_of(encode_sdo(SdoAbort{0x6000, 2, 0x06020000})));
  std::uint8_t emcy[kEmergencySize];
  ByteWriter w(emcy);
  EXPECT_TRUE(encode_emergency({0x8611, 0x80, {0, 0, 0, 0, 0}}, w).ok());
  coe("emergency", 1, Vec(emcy, emcy + kEmergencySize));
  coe("sdo_info_od_list_resp", 2,
      value_of(encode_sdo_info(OdListResponse{OdListType::all, {0x1000, 0x1018}})));
  coe("sdo_info_entry_desc_resp", 3,
      value_of(encode_sdo_info(EntryDescriptionResponse{.index = 0x6000,
                                                        .subindex = 1,
                                                        .value_info = 0x78,
                                                        .data_type = 6,
                                                        .bit_length = 16,
                                                        .object_access = 0x87,
                                                        .unit_type = 0x00010000,
                                                        .default_value = {0, 0},
                                                        .minimum_value = {0, 0},
                                                        .maximum_value = {0xFF, 0x7F},
                                                        .description = "Value"})));
  seeds.emplace_back(
      "foe_write_req",
      mailbox(MailboxType::foe, 1, value_of(encode_foe(FoeWriteRequest{0x12345678, "app.efw"}))));
  seeds.emplace_back("foe_data",
                     mailbox(MailboxType::foe, 2, value_of(encode_foe(FoeData{1, Vec(24, 0x5A)}))));
  EoeSetIpRequest set_ip;
  set_ip.parameters.mac = std::array<std::uint8_t, 6>{2, 0, 0, 0, 0, 1};
  set_ip.parameters.ip = 0xC0A80102;
  set_ip.parameters.dns_name = "drive";
  seeds.emplace_back("eoe_set_ip_req", mailbox(MailboxType::eoe, 3, value_of(encode_eoe(set_ip))));
  EoeFragment fragment;
  fragment.header = {.last_fragment = true, .time_appended = true, .offset_blocks = 2};
  fragment.data = Vec(42, 0xEE);
  fragment.timestamp = 0x01020304;
  seeds.emplace_back("eoe_fragment", mailbox(MailboxType::eoe, 4, value_of(encode_eoe(fragment))));
  SoeMessage soe;
  soe.header = {.opcode = SoeOpcode::read_response, .error = true, .elements = 0x40, .idn = 1};
  soe.error_code = 0x1001;
  seeds.emplace_back("soe_read_resp_error",
                     mailbox(MailboxType::soe, 5, value_of(encode_soe(soe))));
  seeds.emplace_back("mailbox_error",
                     Vec{0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x05, 0x00});
  return seeds;
}

TEST(MailboxSeeds, CommittedSeedsMatchTheEncoders) {
  const std::filesystem::path dir = std::filesystem::path(ECAT_SOURCE_DIR) / "fuzz/seeds/mailbox";
  const bool write = std::getenv("ECAT_WRITE_MAILBOX_SEEDS") != nullptr;
  if (write) std::filesystem::create_directories(dir);
  for (const auto& [name, bytes] : generated_seeds()) {
    const auto path = dir / (name + ".bin");
    if (write) {
      std::ofstream(path, std::ios::binary)
          .write(reinterpret_cast<const char*>(bytes.data()),
                 static_cast<std::streamsize>(bytes.size()));
    }
    std::ifstream in(path, std::ios::binary);
    ASSERT_TRUE(in.good()) << path << " missing; regenerate with ECAT_WRITE_MAILBOX_SEEDS=1";
    const Vec committed{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    EXPECT_EQ(committed, bytes) << path;
    const std::string summary = summarize_mailbox(committed);
    EXPECT_FALSE(summary.empty()) << name;
    EXPECT_EQ(summary.find("malformed"), std::string::npos) << name << ": " << summary;
  }
}

}  // namespace
}  // namespace ecat::wire
