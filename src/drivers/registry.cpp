#include <ecat/drivers/builtin.hpp>
#include <ecat/drivers/drivers.hpp>

namespace ecat::drivers {

master::DriverRegistry builtin_registry() {
  master::DriverRegistry registry;
  for (auto& d : builtin_drivers())
    registry.add(std::move(d));
  return registry;
}

}  // namespace ecat::drivers
