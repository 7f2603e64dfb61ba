// Fuzzes the frame codec: whatever decodes must re-encode (FrameBuilder) to a chain that decodes to
// the same datagrams, and whatever does not decode must yield a describable error.
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include <ecat/wire/frame.hpp>

namespace ecat::wire {
namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_frame: %s\n", what);
  std::abort();
}

bool same_datagram(const DatagramView& a, const DatagramView& b) {
  return a.header == b.header && a.wkc == b.wkc && a.data.size() == b.data.size() &&
         (a.data.empty() || std::memcmp(a.data.data(), b.data.data(), a.data.size()) == 0);
}

void check_error(const DecodeError& error) {
  // Formatting must cope with whatever numbers the decoder put there.
  if (error.describe().empty()) fail("empty error description");
  (void)error.to_error();
}

void check_frame(Bytes input) {
  auto decoded = decode_frame(input);
  if (!decoded) {
    check_error(decoded.error);
    return;
  }
  const FrameView& frame = *decoded.frame;
  if (frame.datagram_count() == 0) fail("decoded frame without datagrams");
  if (frame.body().size() > frame.header_length()) fail("chain longer than the header length");

  std::array<std::uint8_t, kFrameHeaderSize + 0x7FF> buffer{};
  FrameBuilder builder(buffer);
  std::size_t count = 0;
  for (auto datagram : frame) {
    ++count;
    if (datagram.data.size() != datagram.header.length) fail("data size differs from length");
    if (!builder.add(datagram.header, datagram.data, datagram.wkc)) fail("re-encoding refused");
  }
  if (count != frame.datagram_count()) fail("iteration count differs from datagram_count()");

  auto reencoded = decode_frame(builder.finish());
  if (!reencoded) fail("re-encoded frame does not decode");
  if (reencoded.frame->datagram_count() != count) fail("re-encoded datagram count differs");
  if (reencoded.frame->body().size() != frame.body().size()) fail("re-encoded size differs");
  auto it = reencoded.frame->begin();
  for (auto datagram : frame) {
    if (!same_datagram(datagram, *it)) fail("re-encoded datagram differs");
    ++it;
  }
  if (it != reencoded.frame->end()) fail("re-encoded iteration does not end");
}

void run(Bytes input) {
  check_frame(input);

  auto ethernet = decode_ethernet(input);
  if (!ethernet) {
    check_error(ethernet.error);
    return;
  }
  check_frame(ethernet.frame->payload);

  // The Ethernet layer round-trips too (padding aside).
  std::array<std::uint8_t, 4096> out{};
  auto encoded = encode_ethernet(ethernet.frame->header, ethernet.frame->payload, out);
  if (encoded.empty() && input.size() <= out.size())
    fail("encode_ethernet refused a frame that fits");
  if (!encoded.empty()) {
    auto again = decode_ethernet(encoded);
    if (!again) fail("re-encoded Ethernet frame does not decode");
    if (again.frame->header.source != ethernet.frame->header.source ||
        again.frame->header.destination != ethernet.frame->header.destination ||
        again.frame->header.vlan_tci != ethernet.frame->header.vlan_tci ||
        again.frame->payload.size() < ethernet.frame->payload.size() ||
        (!ethernet.frame->payload.empty() &&
         std::memcmp(again.frame->payload.data(), ethernet.frame->payload.data(),
                     ethernet.frame->payload.size()) != 0)) {
      fail("re-encoded Ethernet frame differs");
    }
  }
}

}  // namespace
}  // namespace ecat::wire

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  ecat::wire::run(ecat::wire::Bytes(data, size));
  return 0;
}
