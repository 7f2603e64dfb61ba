// Datagrams as the mailbox gateway receives them from the network (wire/mailbox_gateway.hpp):
// whatever decodes must re-encode to the same mailbox and decode to the same value.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include <ecat/wire/mailbox_gateway.hpp>

namespace {

void require(bool condition) {
  if (!condition) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace ecat::wire;
  auto message = decode_gateway_message(Bytes(data, size));
  if (!message) return 0;
  require(message->data.size() == message->header.length);
  require(message->mailbox.size() == kMailboxHeaderSize + message->header.length);
  require(message->mailbox.size() <= kMaxGatewayMailboxSize);
  auto encoded = encode_gateway_message(message->header, message->data);
  require(encoded.ok());
  require(encoded->size() == kMailboxGatewayHeaderSize + message->mailbox.size());
  auto again = decode_gateway_message(*encoded);
  require(again.ok() && again->header == message->header);
  // The data; not the raw mailbox bytes: the header's reserved bit is not kept.
  require(std::vector<std::uint8_t>(again->data.begin(), again->data.end()) ==
          std::vector<std::uint8_t>(message->data.begin(), message->data.end()));
  return 0;
}
