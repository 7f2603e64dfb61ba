// The registry of built-in drivers lives with the drivers, so the master layer does not name them.
#include <ecat/drivers/drivers.hpp>

namespace ecat::master {

DriverRegistry DriverRegistry::with_builtins() {
  DriverRegistry registry;
  for (auto& d : drivers::builtin_drivers())
    registry.add(std::move(d));
  return registry;
}

}  // namespace ecat::master
