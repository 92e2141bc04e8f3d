// libFuzzer target: any bytes as a patch sidecar. Parsing either throws rolamos::Error or gives a
// sidecar that serialises and parses back to the same JSON.
#include <cstdint>
#include <cstdlib>
#include <string>

#include "rolamos/error.hpp"
#include "rolamos/store.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  rolamos::PatchSidecar sidecar;
  try {
    sidecar = rolamos::ParseSidecar(text, "fuzz.json");
  } catch (const rolamos::Error&) {
    return 0;
  }
  const nlohmann::json j = rolamos::SidecarToJson(sidecar);
  const rolamos::PatchSidecar again = rolamos::ParseSidecar(j.dump(), "roundtrip.json");
  if (rolamos::SidecarToJson(again) != j) std::abort();
  return 0;
}
