// How the bus treats one reliable transaction (transaction.hpp, Bus::transact): plain data, so
// that configurations carrying it do not carry the bus.
#pragma once

#include <chrono>

namespace ecat::bus {

// How the bus treats one reliable transaction.
struct TransactOptions {
  // Overall limit from submission to completion, queueing and retries included. Must be positive.
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // How many times the whole transaction is sent again after one of its frames got no reply.
  // A retry repeats every datagram of the transaction, so a non-idempotent datagram (a mailbox
  // write, ARMW/FRMW, APRW/FPRW/BRW, a write that starts an action) may take effect twice:
  // set retries = 0 for such transactions and handle Errc::timeout in the caller.
  unsigned retries = 2;
};

}  // namespace ecat::bus
