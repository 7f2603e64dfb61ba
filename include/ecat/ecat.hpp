// The one header an application includes: the master, its slaves and domains, their
// configurations and summaries, signal values and handles, Result/Error, the event stream, the
// log, opening a link by name and starting a master from a ring file (open_master). The
// simulator has its own header (<ecat/sim/backend.hpp>: the built-in simulated ring); the bus,
// the cycler, the coroutine runtime and the protocol codecs are the library's own business,
// reachable by their headers for tools and tests.
#pragma once

#include <ecat/app/open_master.hpp>
#include <ecat/link/link.hpp>
#include <ecat/link/open.hpp>
#include <ecat/log.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/events.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/master/signal_handle.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/result.hpp>
#include <ecat/version.hpp>
