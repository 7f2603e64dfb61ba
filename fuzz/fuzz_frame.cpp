// Fuzzes the frame codec: whatever decodes must re-encode (FrameBuilder) to a chain that decodes to
// the same datagrams, and whatever does not decode must yield a describable error. Also the
// redundancy helpers (wire/redundancy.hpp) on the input and on thirds of it: a frame answers
// itself, merging it with itself decodes and doubles its working counters, and frames that do not
// answer the request are refused, never read past.
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include <ecat/wire/frame.hpp>
#include <ecat/wire/redundancy.hpp>

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

void check_redundancy(Bytes input) {
  std::array<std::uint8_t, 4096> out{};
  const bool decodes = static_cast<bool>(decode_frame(input));
  if (same_shape(input, input) != decodes) fail("a frame does not answer itself");
  if (decodes && input.size() <= out.size()) {
    auto merged = merge_bounces(input, input, input, out);
    if (!merged) fail("merging a frame with itself failed");
    auto again = decode_frame(*merged);
    if (!again || again.frame->datagram_count() != decode_frame(input).frame->datagram_count())
      fail("a merged frame does not decode to the request's datagrams");
    auto it = decode_frame(input).frame->begin();
    for (auto d : *again.frame) {
      const unsigned want = std::min(0xFFFFu, 2u * (*it).wkc);
      if (d.wkc != want) fail("merged working counter is not the sum");
      ++it;
    }
    const bool unprocessed = !any_processed(input);
    if (is_passthrough_copy(input, input) != unprocessed) fail("passthrough copy misjudged");
  }
  const std::size_t third = input.size() / 3;
  const Bytes a = input.subspan(0, third);
  const Bytes b = input.subspan(third, third);
  const Bytes c = input.subspan(2 * third);
  auto merged = merge_bounces(a, b, c, out);
  if (merged) {
    if (!same_shape(a, b) || !same_shape(a, c))
      fail("merged frames that do not answer the request");
    if (merged->size() != a.size()) fail("merged frame of another size");
  }
  (void)is_passthrough_copy(a, b);
  (void)classify_arrival(RedundantPort::primary, MacAddress{}, MacAddress{}, kBroadcastMac);
}

void run(Bytes input) {
  check_frame(input);
  check_redundancy(input);

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
