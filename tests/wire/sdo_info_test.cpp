#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/sdo_info.hpp>

namespace ecat::wire {
namespace {

using Vec = std::vector<std::uint8_t>;
using Status = SdoInfoReassembler::Status;

Vec encoded(const SdoInfoMessage& m) {
  auto r = encode_sdo_info(m);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message());
  return r.ok() ? *r : Vec{};
}

EntryDescriptionResponse full_entry() {
  return EntryDescriptionResponse{
      .index = 0x6000,
      .subindex = 0x11,
      .value_info = 0x7F,
      .data_type = 0x0003,
      .bit_length = 16,
      .object_access = kAccessReadPreop | kAccessReadSafeop | kAccessReadOp | kAccessTxPdoMappable,
      .unit_type = 0x00FD0000,
      .default_value = {0x00, 0x00},
      .minimum_value = {0x00, 0x80},
      .maximum_value = {0xFF, 0x7F},
      .description = "Value"};
}

std::vector<std::uint16_t> index_range(std::size_t count) {
  std::vector<std::uint16_t> indices(count);
  for (std::size_t i = 0; i < count; ++i)
    indices[i] = static_cast<std::uint16_t>(0x1000 + i);
  return indices;
}

// --- exact bytes ---

TEST(SdoInfo, KnownRequestBytes) {
  EXPECT_EQ(encoded(OdListRequest{OdListType::all}),
            (Vec{0x00, 0x80, 0x01, 0x00, 0x00, 0x00, 0x01, 0x00}));
  EXPECT_EQ(encoded(ObjectDescriptionRequest{0x1018}),
            (Vec{0x00, 0x80, 0x03, 0x00, 0x00, 0x00, 0x18, 0x10}));
  EXPECT_EQ(encoded(EntryDescriptionRequest{0x1018, 0x01, 0x07}),
            (Vec{0x00, 0x80, 0x05, 0x00, 0x00, 0x00, 0x18, 0x10, 0x01, 0x07}));
  EXPECT_EQ(encoded(SdoInfoError{0x06020000}),
            (Vec{0x00, 0x80, 0x07, 0x00, 0x00, 0x00, 0x00, 0x00, 0x02, 0x06}));
}

TEST(SdoInfo, KnownResponseBytes) {
  EXPECT_EQ(encoded(ObjectDescriptionResponse{0x1018, 0x0023, 4, ObjectCode::record, "Identity"}),
            (Vec{0x00, 0x80, 0x04, 0x00, 0x00, 0x00, 0x18, 0x10, 0x23, 0x00,
                 0x04, 0x09, 'I',  'd',  'e',  'n',  't',  'i',  't',  'y'}));
  EXPECT_EQ(encoded(OdListResponse{OdListType::number_of_objects, {12, 3, 4, 0, 0}}),
            (Vec{0x00, 0x80, 0x02, 0x00, 0x00, 0x00, 0x00, 0x00, 12, 0, 3, 0, 4, 0, 0, 0, 0, 0}));
  EXPECT_EQ(encoded(full_entry()),
            (Vec{0x00, 0x80, 0x06, 0x00, 0x00, 0x00,  // CoE + SDO info headers
                 0x00, 0x60, 0x11, 0x7F,              // index, subindex, value info
                 0x03, 0x00, 0x10, 0x00, 0x87, 0x00,  // data type, bit length, access
                 0x00, 0x00, 0xFD, 0x00,              // unit type
                 0x00, 0x00, 0x00, 0x80, 0xFF, 0x7F,  // default, minimum, maximum
                 'V',  'a',  'l',  'u',  'e'}));
}

TEST(SdoInfo, RoundTripsEveryMessage) {
  const SdoInfoMessage messages[] = {
      OdListRequest{OdListType::tx_pdo_mappable},
      OdListResponse{OdListType::settings, index_range(7)},
      OdListResponse{OdListType::backup, {}},
      ObjectDescriptionRequest{0xF000},
      ObjectDescriptionResponse{0x1600, 0x0021, 8, ObjectCode::array, "RxPDO map"},
      ObjectDescriptionResponse{0x7000, 0x0005, 0, ObjectCode::var, ""},
      EntryDescriptionRequest{0x6000, 0x11, 0x78},
      full_entry(),
      EntryDescriptionResponse{.index = 0x1008,
                               .data_type = 9,
                               .bit_length = 48,
                               .object_access = 0x0007,
                               .description = "Device name"},
      EntryDescriptionResponse{.index = 1,
                               .value_info = kValueInfoMaximumValue,
                               .bit_length = 1,
                               .maximum_value = {0x01}},
      SdoInfoError{0x06010000},
  };
  for (const auto& m : messages) {
    SCOPED_TRACE(to_string(opcode_of(m)));
    const Vec bytes = encoded(m);
    EXPECT_EQ(bytes[2], static_cast<std::uint8_t>(opcode_of(m)));
    auto back = decode_sdo_info(bytes);
    ASSERT_TRUE(back.ok()) << back.error().message();
    EXPECT_EQ(*back, m);
  }
}

TEST(SdoInfo, TextsStopAtNul) {
  const Vec bytes{0x00, 0x80, 0x04, 0x00, 0x00, 0x00, 0x18, 0x10, 0x23,
                  0x00, 0x04, 0x09, 'A',  'b',  'c',  0x00, 'x',  'y'};
  auto m = decode_sdo_info(bytes);
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(std::get<ObjectDescriptionResponse>(*m).name, "Abc");
}

// --- fragments ---

TEST(SdoInfoFragments, SplitsAtEvenSizesAndCountsDown) {
  const OdListResponse list{OdListType::all, index_range(100)};  // 202 bytes of service data
  auto fragments = encode_sdo_info_fragments(list, 41);          // 35 bytes of room, cut to 34
  ASSERT_TRUE(fragments.ok());
  ASSERT_EQ(fragments->size(), 6u);
  for (std::size_t i = 0; i < fragments->size(); ++i) {
    const Vec& f = (*fragments)[i];
    auto header = decode_sdo_info_fragment(f);
    ASSERT_TRUE(header.ok());
    EXPECT_EQ(header->header.opcode, SdoInfoOpcode::get_od_list_response);
    EXPECT_EQ(header->header.incomplete, i < 5);
    EXPECT_EQ(header->header.fragments_left, 5 - i);
    EXPECT_EQ(header->data.size(), i < 5 ? 34u : 32u);
  }
  EXPECT_EQ(Vec((*fragments)[0].begin(), (*fragments)[0].begin() + 10),
            (Vec{0x00, 0x80, 0x82, 0x00, 0x05, 0x00, 0x01, 0x00, 0x00, 0x10}));

  SdoInfoReassembler reassembler;
  for (std::size_t i = 0; i < fragments->size(); ++i) {
    auto status = reassembler.add((*fragments)[i]);
    ASSERT_TRUE(status.ok()) << status.error().message();
    EXPECT_EQ(*status, i + 1 < fragments->size() ? Status::need_more : Status::complete);
  }
  EXPECT_EQ(reassembler.opcode(), SdoInfoOpcode::get_od_list_response);
  EXPECT_EQ(reassembler.data().size(), 202u);
  auto message = reassembler.message();
  ASSERT_TRUE(message.ok());
  EXPECT_EQ(*message, SdoInfoMessage(list));

  // A whole fragment is not decoded alone.
  auto alone = decode_sdo_info((*fragments)[0]);
  ASSERT_FALSE(alone.ok());
  EXPECT_EQ(alone.error().code(), Errc::unsupported);
  EXPECT_EQ(alone.error().message(),
            "SDO information: get OD list response is a fragment (5 more to come); reassemble it "
            "first");
}

TEST(SdoInfoFragments, SingleFragmentAndLimits) {
  auto one = encode_sdo_info_fragments(SdoInfoError{1}, 1000);
  ASSERT_TRUE(one.ok());
  ASSERT_EQ(one->size(), 1u);
  EXPECT_EQ((*one)[0], encoded(SdoInfoError{1}));
  SdoInfoReassembler reassembler;
  EXPECT_EQ(*reassembler.add((*one)[0]), Status::complete);
  EXPECT_EQ(*reassembler.message(), SdoInfoMessage(SdoInfoError{1}));

  auto tiny = encode_sdo_info_fragments(SdoInfoError{1}, 7);
  ASSERT_FALSE(tiny.ok());
  EXPECT_EQ(tiny.error().code(), Errc::invalid_argument);
  EXPECT_EQ(tiny.error().message(),
            "SDO information: 7 bytes of mailbox data cannot hold a fragment (need at least 8)");

  auto huge = encode_sdo_info(OdListResponse{OdListType::all, index_range(40000)});
  ASSERT_FALSE(huge.ok());
  EXPECT_EQ(huge.error().message(),
            "SDO information: message exceeds one mailbox (65535 bytes); send it in fragments");
}

TEST(SdoInfoReassembler, RejectsBrokenSequencesAndStartsOver) {
  auto fragments =
      encode_sdo_info_fragments(OdListResponse{OdListType::all, index_range(30)}, 16);  // 10/frag
  ASSERT_TRUE(fragments.ok());
  ASSERT_EQ(fragments->size(), 7u);
  const auto& f = *fragments;

  SdoInfoReassembler r;
  EXPECT_FALSE(r.message().ok());
  EXPECT_EQ(r.message().error().code(), Errc::wrong_state);
  EXPECT_EQ(r.message().error().message(),
            "SDO information reassembly: the message is not complete");

  // A skipped fragment.
  ASSERT_EQ(*r.add(f[0]), Status::need_more);
  auto skipped = r.add(f[2]);
  ASSERT_FALSE(skipped.ok());
  EXPECT_EQ(skipped.error().code(), Errc::malformed);
  EXPECT_EQ(skipped.error().message(),
            "SDO information reassembly: fragment says 4 fragments left, expected 5");

  // After the error the next fragment starts a new message.
  ASSERT_EQ(*r.add(f[0]), Status::need_more);
  ASSERT_EQ(*r.add(f[1]), Status::need_more);
  // Another opcode in the middle.
  Vec other = encoded(EntryDescriptionResponse{.index = 1, .bit_length = 8});
  other[5] = 0x04;  // fragments left 4, as the sequence expects next
  auto wrong_opcode = r.add(other);
  ASSERT_FALSE(wrong_opcode.ok());
  EXPECT_EQ(wrong_opcode.error().message(),
            "SDO information reassembly: fragment has opcode 6 (get entry description response), "
            "expected 2 (get OD list response)");

  // Incomplete but nothing left.
  Vec inconsistent = encoded(SdoInfoError{1});
  inconsistent[2] |= 0x80;
  auto bad = r.add(inconsistent);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(),
            "SDO information reassembly: fragment is marked incomplete but 0 fragments are left");

  // Not SDO information at all.
  auto not_info = r.add(Vec{0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  ASSERT_FALSE(not_info.ok());
  EXPECT_EQ(not_info.error().code(), Errc::malformed);

  // A full sequence, then a new message reuses the reassembler.
  for (std::size_t i = 0; i < f.size(); ++i)
    ASSERT_TRUE(r.add(f[i]).ok());
  EXPECT_EQ(std::get<OdListResponse>(*r.message()).indices, index_range(30));
  ASSERT_EQ(*r.add(encoded(SdoInfoError{7})), Status::complete);
  EXPECT_EQ(*r.message(), SdoInfoMessage(SdoInfoError{7}));
  r.reset();
  EXPECT_FALSE(r.message().ok());
}

// --- errors ---

TEST(SdoInfo, DecodeErrors) {
  auto check = [](Result<SdoInfoMessage> r, Errc code, const std::string& message) {
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code(), code);
    EXPECT_EQ(r.error().message(), message);
  };
  check(decode_sdo_info(Vec{0x00, 0x80, 0x01}), Errc::truncated,
        "SDO information: reserved at offset 3 needs 1 byte, 0 remain");
  check(decode_sdo_info(Vec{0x00, 0x80, 0x01, 0x00, 0x00}), Errc::truncated,
        "SDO information: fragments left at offset 4 needs 2 bytes, 1 remains");
  check(decode_sdo_info(Vec{0x00, 0x20, 0x01, 0x00, 0x00, 0x00, 0x01, 0x00}), Errc::malformed,
        "SDO information: CoE service 2 at offset 0 is not SDO information (8)");
  check(decode_sdo_info(Vec{0x00, 0x80, 0x08, 0x00, 0x00, 0x00}), Errc::malformed,
        "SDO information: opcode 8 is not an SDO information opcode (1..7)");
  check(decode_sdo_info(Vec{0x00, 0x80, 0x00, 0x00, 0x00, 0x00}), Errc::malformed,
        "SDO information: opcode 0 is not an SDO information opcode (1..7)");
  check(decode_sdo_info(SdoInfoOpcode::get_od_list_request, Bytes{}), Errc::truncated,
        "SDO info get OD list request: list type at offset 0 needs 2 bytes, 0 remain");
  check(decode_sdo_info(SdoInfoOpcode::get_od_list_response, Vec{0x01, 0x00, 0x00, 0x10, 0x18}),
        Errc::malformed,
        "SDO info get OD list response: index list from offset 2 has odd length 3");
  check(decode_sdo_info(SdoInfoOpcode::get_object_description_request, Vec{0x18}), Errc::truncated,
        "SDO info get object description request: index at offset 0 needs 2 bytes, 1 remains");
  check(decode_sdo_info(SdoInfoOpcode::get_object_description_response,
                        Vec{0x18, 0x10, 0x23, 0x00, 0x04}),
        Errc::truncated,
        "SDO info object description response: object code at offset 5 needs 1 byte, 0 remain");
  check(decode_sdo_info(SdoInfoOpcode::get_entry_description_request, Vec{0x18, 0x10, 0x01}),
        Errc::truncated,
        "SDO info get entry description request: value info at offset 3 needs 1 byte, 0 remain");
  check(
      decode_sdo_info(SdoInfoOpcode::get_entry_description_response,
                      Vec{0x00, 0x60, 0x01, 0x10, 0x07, 0x00, 0x20, 0x00, 0x07, 0x00, 0x01, 0x02}),
      Errc::truncated,
      "SDO info entry description response: default value at offset 10 needs 4 bytes, 2 remain");
  check(decode_sdo_info(SdoInfoOpcode::get_entry_description_response,
                        Vec{0x00, 0x60, 0x01, 0x08, 0x07, 0x00, 0x20, 0x00, 0x07, 0x00, 0x01}),
        Errc::truncated,
        "SDO info entry description response: unit type at offset 10 needs 4 bytes, 1 remains");
  check(decode_sdo_info(SdoInfoOpcode::get_entry_description_response,
                        Vec{0x00, 0x60, 0x01, 0x00, 0x07, 0x00, 0x20, 0x00, 0x07}),
        Errc::truncated,
        "SDO info entry description response: object access at offset 8 needs 2 bytes, 1 remains");
  check(decode_sdo_info(SdoInfoOpcode::error_request, Vec{0x00, 0x00, 0x02}), Errc::truncated,
        "SDO info error: abort code at offset 0 needs 4 bytes, 3 remain");
}

TEST(SdoInfo, EncodeErrors) {
  auto check = [](const SdoInfoMessage& m, const std::string& message) {
    auto r = encode_sdo_info(m);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code(), Errc::invalid_argument);
    EXPECT_EQ(r.error().message(), message);
  };
  check(
      EntryDescriptionResponse{
          .value_info = kValueInfoDefaultValue, .bit_length = 32, .default_value = {1, 2}},
      "SDO info entry description response: default value is 2 bytes, value info 0x10 and bit "
      "length 32 need 4");
  check(EntryDescriptionResponse{.bit_length = 8, .minimum_value = {1}},
        "SDO info entry description response: minimum value is 1 bytes, value info 0x00 and bit "
        "length 8 need 0");
  check(
      EntryDescriptionResponse{
          .value_info = kValueInfoMaximumValue, .bit_length = 9, .maximum_value = {1}},
      "SDO info entry description response: maximum value is 1 bytes, value info 0x40 and bit "
      "length 9 need 2");
  check(EntryDescriptionResponse{.unit_type = 5},
        "SDO info entry description response: unit_type is set but value info lacks the unit "
        "flag");
  check(EntryDescriptionResponse{.description = std::string("a\0b", 3)},
        "SDO info entry description response: description holds a NUL character");
  check(ObjectDescriptionResponse{.name = std::string("\0", 1)},
        "SDO info object description response: name holds a NUL character");
}

TEST(SdoInfo, Names) {
  EXPECT_EQ(to_string(SdoInfoOpcode::get_od_list_request), "get OD list request");
  EXPECT_EQ(to_string(SdoInfoOpcode::get_od_list_response), "get OD list response");
  EXPECT_EQ(to_string(SdoInfoOpcode::get_object_description_request),
            "get object description request");
  EXPECT_EQ(to_string(SdoInfoOpcode::get_object_description_response),
            "get object description response");
  EXPECT_EQ(to_string(SdoInfoOpcode::get_entry_description_request),
            "get entry description request");
  EXPECT_EQ(to_string(SdoInfoOpcode::get_entry_description_response),
            "get entry description response");
  EXPECT_EQ(to_string(SdoInfoOpcode::error_request), "SDO info error");
  EXPECT_EQ(to_string(static_cast<SdoInfoOpcode>(0)), "reserved");
  EXPECT_EQ(to_string(OdListType::number_of_objects), "number of objects");
  EXPECT_EQ(to_string(OdListType::all), "all");
  EXPECT_EQ(to_string(OdListType::rx_pdo_mappable), "RxPDO mappable");
  EXPECT_EQ(to_string(OdListType::tx_pdo_mappable), "TxPDO mappable");
  EXPECT_EQ(to_string(OdListType::backup), "backup");
  EXPECT_EQ(to_string(OdListType::settings), "settings");
  EXPECT_EQ(to_string(static_cast<OdListType>(6)), "reserved");
  EXPECT_EQ(to_string(ObjectCode::null), "NULL");
  EXPECT_EQ(to_string(ObjectCode::domain), "DOMAIN");
  EXPECT_EQ(to_string(ObjectCode::deftype), "DEFTYPE");
  EXPECT_EQ(to_string(ObjectCode::defstruct), "DEFSTRUCT");
  EXPECT_EQ(to_string(ObjectCode::var), "VAR");
  EXPECT_EQ(to_string(ObjectCode::array), "ARRAY");
  EXPECT_EQ(to_string(ObjectCode::record), "RECORD");
  EXPECT_EQ(to_string(static_cast<ObjectCode>(1)), "reserved");
}

}  // namespace
}  // namespace ecat::wire
