// Vendor specific mailbox messages (VoE, mailbox type 15), the master's side: raw messages a
// vendor defines, sent and received over a slave's Mailbox from tasks on the control thread.
//
// VoE has no request/reply rule of its own: voe_send writes one message, voe_receive waits for
// the next VoE message the slave sends. A VoE message that arrives while nobody waits (during an
// SDO transfer, a poll) stays in the mailbox's unsolicited queue until voe_receive takes it;
// other protocols' queued messages are left there.
#pragma once

#include <chrono>
#include <cstdint>
#include <vector>

#include <ecat/exec/task.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/voe.hpp>

namespace ecat::master {

// One message; the data must fit one mailbox (VoE does not fragment): Errc::invalid_argument
// beyond Mailbox::max_request_data() - 6.
exec::Task<Result<void>> voe_send(Mailbox& mailbox, std::uint32_t vendor_id,
                                  std::uint16_t vendor_type, std::vector<std::uint8_t> data,
                                  std::chrono::nanoseconds timeout = std::chrono::seconds(1));

// The oldest VoE message queued, else the next one the slave sends within `timeout`
// (Errc::timeout). A VoE message too short for its header fails with Errc::malformed.
exec::Task<Result<wire::VoeMessage>> voe_receive(
    Mailbox& mailbox, std::chrono::nanoseconds timeout = std::chrono::seconds(1));

}  // namespace ecat::master
