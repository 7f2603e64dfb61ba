// Mailbox buffers into every mailbox decoder and the summary. Whatever decodes must re-encode and
// decode to the same value.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/soe.hpp>
#include <ecat/wire/voe.hpp>

namespace {

using namespace ecat::wire;

void require(bool condition) {
  if (!condition) std::abort();
}

// Inputs this small always re-encode within the 65535-byte mailbox limit.
constexpr std::size_t kSureToFit = 32768;
std::size_t g_input_size = 0;

// decode(encode(x)) == x for anything the decoder accepted; the encoder must accept it as long as
// it fits a mailbox.
template <class Message, class Encode, class Decode>
void check_round_trip(const Message& message, Encode encode, Decode decode) {
  auto encoded = encode(message);
  if (!encoded) {
    require(g_input_size > kSureToFit && encoded.error().code() == ecat::Errc::invalid_argument);
    return;
  }
  auto decoded = decode(Bytes(*encoded));
  require(decoded.ok());
  require(*decoded == message);
}

void decode_body(Bytes data) {
  if (auto sdo = decode_sdo(data)) {
    (void)to_string(*sdo);
    (void)direction_of(*sdo);
    check_round_trip(*sdo, encode_sdo, [](Bytes b) { return decode_sdo(b); });
    if (const auto* upload = std::get_if<SdoInitiateUploadResponse>(&*sdo)) {
      (void)complete_access_u16_entries(upload->data);
      (void)complete_access_u32_entries(upload->data);
    }
  }
  if (auto info = decode_sdo_info(data)) {
    check_round_trip(*info, encode_sdo_info, [](Bytes b) { return decode_sdo_info(b); });
  }
  if (auto fragment = decode_sdo_info_fragment(data)) {
    (void)decode_sdo_info(fragment->header.opcode, fragment->data);
    SdoInfoReassembler reassembler;
    if (auto status = reassembler.add(data);
        status && *status == SdoInfoReassembler::Status::complete) {
      (void)reassembler.message();
    }
  }
  if (auto emergency = decode_emergency(data)) {
    (void)emergency_error_text(emergency->error_code);
    std::uint8_t buf[kEmergencySize];
    ByteWriter w(buf);
    require(encode_emergency(*emergency, w).ok());
    auto again = decode_emergency(Bytes(buf));
    require(again.ok() && *again == *emergency);
  }
  if (auto foe = decode_foe(data)) {
    check_round_trip(*foe, encode_foe, [](Bytes b) { return decode_foe(b); });
  }
  if (auto eoe = decode_eoe(data)) {
    check_round_trip(*eoe, encode_eoe, [](Bytes b) { return decode_eoe(b); });
  }
  if (auto soe = decode_soe(data)) {
    check_round_trip(*soe, encode_soe, [](Bytes b) { return decode_soe(b); });
  }
  if (auto voe = decode_voe(data)) {
    check_round_trip(*voe, encode_voe, [](Bytes b) { return decode_voe(b); });
  }
  if (auto error = decode_mailbox_error(data)) (void)mailbox_error_text(error->detail);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const Bytes input(data, size);
  g_input_size = size;
  (void)summarize_mailbox(input);
  if (auto mailbox = decode_mailbox(input)) {
    require(mailbox->data.size() == mailbox->header.length);
    // Every body decoder, whatever the type says: a wrong type must not crash them either.
    decode_body(mailbox->data);
    std::vector<std::uint8_t> out(size);
    auto written = encode_mailbox(mailbox->header, mailbox->data, ecat::wire::MutableBytes(out));
    require(written.ok());
    auto again = decode_mailbox(out);
    require(again.ok() && again->header == mailbox->header);
  } else {
    decode_body(input);
  }
  return 0;
}
