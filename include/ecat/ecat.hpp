// The one header a user includes.
#pragma once

#include <ecat/result.hpp>
#include <ecat/version.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>
