// libFuzzer target for the rig JSON loader (clang, -fsanitize=fuzzer,address,undefined): any
// text must load into a rig or throw RigError with a message; a loaded rig must survive what
// stitchcalib does with one (rough homographies or canvas layout, adapting to the streams'
// sizes, saving) without crashing, hanging or throwing anything but RigError.
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    stitch::Rig rig = stitch::rig_from_json_string(text);
    std::vector<std::array<int, 2>> sizes;
    for (const auto& c : rig.cameras) sizes.push_back({c.width / 2 + 1, c.height / 2 + 1});
    stitch::rig_adapt_to_sizes(rig, sizes);
    if (rig.calibrated()) stitch::rig_layout_canvas(rig);
    else stitch::rig_compute_rough_homographies(rig);
    const std::string saved = stitch::rig_to_json_string(rig);
    stitch::rig_from_json_string(saved);  // what we write we read back
  } catch (const stitch::RigError& e) {
    if (std::string(e.what()).empty()) __builtin_trap();  // every refusal says why
  }
  return 0;
}
