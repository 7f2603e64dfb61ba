// The one header a user includes.
#pragma once

#include <ecat/bus/bus.hpp>
#include <ecat/bus/realtime.hpp>
#include <ecat/bus/transaction.hpp>
#include <ecat/link/link.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/result.hpp>
#include <ecat/version.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sdo_abort.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/sii.hpp>
#include <ecat/wire/soe.hpp>
