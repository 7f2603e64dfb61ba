// The built-in device drivers as a registry: what MasterConfig::drivers holds unless the
// application says otherwise (drivers.hpp lists them and their signals).
#pragma once

#include <ecat/master/driver.hpp>

namespace ecat::drivers {

// EL1809, EL2809, EL3202, EL4102 and the CiA 402 drive, in a registry an application may add its
// own drivers to (a later addition takes precedence over a built-in one).
master::DriverRegistry builtin_registry();

}  // namespace ecat::drivers
