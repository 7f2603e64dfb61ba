// ENI files come from configurators and from whoever hands one over: parsing one and mapping it
// onto a master configuration must never crash, hang or read out of bounds, whatever it holds.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include <ecat/config/eni.hpp>
#include <ecat/master/config.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view xml(reinterpret_cast<const char*>(data), size);
  (void)ecat::config::looks_like_eni(xml);
  auto eni = ecat::config::parse_eni(xml, "fuzz.xml");
  if (!eni) return 0;
  (void)ecat::master::import_eni(*eni, "fuzz.xml");
  return 0;
}
