// libFuzzer: the rig-file parser (sim/virtual_rig.h LoadRigFile, as `capture --rig` and
// `simulate --rig` read it).
#include "fuzz/fuzz_util.h"
#include "sim/virtual_rig.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  const auto path = fuzz::WriteInput("rig.json", data, size);
  fuzz::Expect([&] { (void)LoadRigFile(path); });
  return 0;
}
