// One-line human summaries of mailbox traffic, for `ecat decode` and logs.
#pragma once

#include <string>

#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

// Summarises the bytes of a mailbox SyncManager buffer (mailbox header + body), for example
//   "mbx CoE cnt=3 SDO upload req 0x1018:01"
//   "mbx CoE cnt=4 SDO upload resp expedited 0x1018:01 = 02 00 00 00"
//   "mbx CoE cnt=5 SDO abort 0x6000:02 0x06020000 (object does not exist in the object dictionary)"
// Returns an empty string when the bytes are not a mailbox (length 0, or shorter than the
// mailbox header), and a summary ending in "(malformed: <reason>)" when a header is recognised
// but its body is not. Never fails, never reads out of bounds.
std::string summarize_mailbox(Bytes mailbox_buffer);

}  // namespace ecat::wire
