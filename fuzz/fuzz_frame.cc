// libFuzzer: the frame readers (core/image_input.h OpenImageInput through ReadImage), as PNG,
// EXR or TIFF by the first byte (the extension picks the reader, as for a session's frames).
#include "core/image_io.h"
#include "fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  if (size < 1) return 0;
  static const char* kExt[] = {".png", ".exr", ".tif"};
  const std::string name = std::string("frame") + kExt[data[0] % 3];
  const auto path = fuzz::WriteInput(name, data + 1, size - 1);
  fuzz::Expect([&] { (void)ReadImage(path); });
  fuzz::Expect([&] { (void)ReadImageInfo(path); });
  return 0;
}
