// A user of the installed package: encodes and decodes one frame through the public API.
#include <array>
#include <cstdio>

#include <ecat/ecat.hpp>

int main() {
  std::array<std::uint8_t, 64> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  ecat::wire::DatagramHeader header;
  header.command = ecat::wire::Command::brd;
  header.length = 2;
  if (!builder.add(header)) return 1;
  auto frame = ecat::wire::decode_frame(builder.finish());
  if (!frame || frame.frame->datagram_count() != 1) return 1;
  std::printf("ecat %s: decoded %zu datagram\n", ecat::kVersion, frame.frame->datagram_count());
  return 0;
}
