// Rebuilding a simulated segment from a wire capture of a real one.
//
// A capture (pcap/pcapng of EtherCAT frames between a master and real slaves) says a lot about the
// slaves it shows: how many there are (the address increments of broadcast and auto-increment
// datagrams), their station addresses (APWR 0x0010), their ESC information and register values
// (reads), their SII EEPROM (the words the master read through 0x0502..0x050F), their CoE objects
// (SDO uploads and downloads through the mailbox SyncManagers) and which register areas they do
// not implement (accesses with working counter 0). build_capture_profile() collects all of it
// per slave; build_capture_segment() turns the profile into a Segment of emulated ESCs that
// answers the same requests the same way (see capture_verify.hpp for the proof), and
// write_capture_profile() stores it as SII images, a ring file and a JSON summary.
//
// Unknown values are filled from what is known and marked as inferred: SII words the master never
// read are 0xFF, except the ESC configuration area (words 0..7), which is rebuilt from register
// reads and from behaviour (device emulation: AL status follows AL control; DC units: the system
// time answers) and gets a valid checksum, because a real ESC only loads a checksummed area.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <ecat/capture/capture_file.hpp>
#include <ecat/result.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/segment.hpp>

namespace ecat::sim {

// ---- The capture as exchanges -------------------------------------------------------------------

// One EtherCAT frame of a capture.
struct CaptureFrame {
  std::uint64_t number = 0;       // packet number in the file (1-based)
  std::int64_t timestamp_ns = 0;  // capture time, since the Unix epoch
  bool from_master = true;
  std::vector<std::uint8_t> frame;  // EtherCAT frame header + datagrams (padding removed)
};

// A request of the master and the reply the segment sent back to it (if the capture has one).
struct CaptureExchange {
  std::size_t request = 0;           // index into CaptureTrace::frames
  std::optional<std::size_t> reply;  // index into CaptureTrace::frames
  // No reply, and no reply at all follows in the capture: the capture ended (or the master gave
  // up on a dead segment) before the answer could be recorded.
  bool after_last_reply = false;
};

struct CaptureTrace {
  std::string source;                      // file name, for messages
  std::vector<CaptureFrame> frames;        // every well-formed EtherCAT frame, in file order
  std::vector<CaptureExchange> exchanges;  // one per master request, in file order
  std::size_t replies = 0;                 // frames recognised as replies
  std::size_t orphan_replies = 0;          // replies that match no request of the capture
  std::size_t malformed_frames = 0;        // EtherCAT payloads that do not decode (skipped)
  std::size_t other_packets = 0;           // packets without EtherCAT (other traffic)
};

// Which way a frame travels. Real ESCs set bit 1 of the first source-MAC byte of every frame they
// pass on (0x10 -> 0x12, 01:01:.. -> 03:01:..), so with Ethernet addresses the frame says it
// itself; EtherCAT over UDP with distinct ports says it by the port (requests go to 0x88A4);
// Linux cooked captures mark the capturing host's own frames as outgoing. Frames none of these
// decide are paired by content: a frame whose datagrams match an open request is its reply.
enum class FrameDirection : std::uint8_t { master, slave, unknown };

// The direction a captured packet shows by itself (see FrameDirection).
FrameDirection frame_direction(const capture::EtherCatPacket& packet) noexcept;

// Reads every EtherCAT frame of a pcap/pcapng file and pairs requests with replies. Errors: the
// file cannot be read or is damaged (io_error, malformed, truncated, unsupported link type).
Result<CaptureTrace> load_capture_trace(const std::string& path);
// The same for a capture already opened (e.g. CaptureFile::from_bytes); `source` names it.
Result<CaptureTrace> load_capture_trace(capture::CaptureFile& file, std::string source);

// Pairs frames that are already in memory (directions as known; `unknown` is decided by content:
// a frame matching an open request is its reply unless it is a byte-identical copy, a retry).
// A reply belongs to the oldest open request with the same datagrams (command, index, length,
// station or logical address, register offset); a request that is repeated with the same
// datagrams before it was answered counts as unanswered (a master's retry after a lost frame).
CaptureTrace pair_capture_frames(std::vector<CaptureFrame> frames,
                                 std::vector<FrameDirection> directions, std::string source);

// ---- The profile
// ----------------------------------------------------------------------------------

// Where a value in the profile came from.
enum class Evidence : std::uint8_t {
  observed,  // read from the capture
  inferred,  // derived from other observations (see the note)
  assumed,   // nothing in the capture says: a typical value
};
std::string_view to_string(Evidence evidence) noexcept;

struct ProfileNote {
  std::string field;  // "esc.type", "sii.word[0]", "dc_system_time", ...
  Evidence evidence = Evidence::assumed;
  std::string reason;
};

// A CoE object entry seen in the capture.
struct CapturedObject {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool complete_access = false;
  // The value when the capture started: the first upload, or the first download when the
  // master wrote the object before reading it (its earlier value is unknown).
  std::vector<std::uint8_t> value;
  bool uploaded = false;                    // the slave answered an upload
  bool downloaded = false;                  // the slave accepted a download
  std::optional<std::uint32_t> abort_code;  // the slave refused the access with this code
};

struct CaptureSlaveProfile {
  std::size_t position = 0;
  std::string name;  // "slave0_EK1100" (position and the SII device name)
  // The station address the master assigned (APWR/FPWR 0x0010), or the one the slave already had
  // when the capture started (then `station_preset`).
  std::optional<std::uint16_t> station;
  bool station_preset = false;
  // The AL status the slave showed before the master changed its state, when the capture starts
  // with slaves already out of INIT.
  std::optional<std::uint16_t> initial_al_status;

  EscHardware hardware;
  // The SII image: 2 bytes per word; words the master never read are 0xFFFF (the ESC
  // configuration area is rebuilt, see the header comment).
  std::vector<std::uint8_t> sii;
  std::vector<bool> sii_word_read;  // per word: the capture shows it
  bool device_emulation = false;    // AL status follows AL control (no firmware)
  bool dc_system_time = false;      // the DC system time unit answers (0x0910..)
  bool has_mailbox = false;         // the SII declares a standard mailbox
  std::map<std::pair<std::uint16_t, std::uint8_t>, CapturedObject> objects;
  // The first value the capture shows for each register byte the master had not written yet
  // (0x0000..0x0FFF): the power-up (or capture-start) contents.
  std::map<std::uint16_t, std::uint8_t> initial_registers;
  std::vector<ProfileNote> notes;
};

struct CaptureProfile {
  std::string source;
  std::vector<CaptureSlaveProfile> slaves;
  std::vector<ProfileNote> notes;  // segment-wide (slave count, topology)
};

// Rebuilds the slaves a capture shows. Fails (out_of_range) when the capture claims more than
// kMaxProfileSlaves slaves.
constexpr std::size_t kMaxProfileSlaves = 1024;
Result<CaptureProfile> build_capture_profile(const CaptureTrace& trace);

// The emulated ESC of one profiled slave: its exact ESC hardware, its SII image, firmware that
// answers the captured CoE objects (devices with a mailbox) or none (device emulation), and the
// station address / AL state it had when the capture started.
Result<std::unique_ptr<Esc>> make_capture_device(const CaptureSlaveProfile& slave);

// All slaves in a line, in position order (port 0 of each to port 1 of the previous one).
Result<std::unique_ptr<Segment>> build_capture_segment(const CaptureProfile& profile);

// Writes <dir>/<name>.bin (SII image) per slave, <dir>/ring.yaml (docs/RING-FILE.md format,
// profile "eeprom"; not for a capture without slaves, as a ring needs one) and
// <dir>/profile.json (everything in the profile, with evidence notes).
// Creates `dir` when missing. Returns the paths written.
Result<std::vector<std::string>> write_capture_profile(const CaptureProfile& profile,
                                                       const std::string& dir);

// The JSON summary (as written to profile.json).
std::string capture_profile_json(const CaptureProfile& profile);

}  // namespace ecat::sim
