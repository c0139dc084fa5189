// libFuzzer: the session parser (session/session.h ReadSession) on arbitrary session.json bytes.
#include "fuzz/fuzz_util.h"
#include "session/session.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  const auto path = fuzz::WriteInput("session/session.json", data, size);
  fuzz::Expect([&] { (void)ReadSession(path.parent_path(), /*check_frames=*/false); });
  return 0;
}
