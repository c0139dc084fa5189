// libFuzzer: the MERL .binary loader (brdf/merl.h). A full table is 35 MB, beyond the
// fuzzer's input sizes: this exercises the header, size and dimension checks.
#include "brdf/merl.h"
#include "fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  const auto path = fuzz::WriteInput("brdf.binary", data, size);
  fuzz::Expect([&] { (void)MerlBrdf::Load(path); });
  return 0;
}
