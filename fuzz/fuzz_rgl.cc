// libFuzzer: the RGL .bsdf tensor loader (brdf/rgl.h), through LoadBrdf as `brdf info` calls it.
#include "brdf/brdf.h"
#include "fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  const auto path = fuzz::WriteInput("brdf.bsdf", data, size);
  fuzz::Expect([&] { (void)LoadBrdf(path); });
  return 0;
}
