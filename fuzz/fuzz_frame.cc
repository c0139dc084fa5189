// libFuzzer: the frame readers (core/image_input.h OpenImageInput through ReadImage), as PNG,
// EXR or TIFF by the first byte (the extension picks the reader, as for a session's frames).
// A PNG whose header OpenImageIO accepts also goes through the frames' fast path
// (core/png_gray16.h) as the frame loader calls it: whatever the fast path decodes, OpenImageIO
// must decode to the same samples (a difference, or a file only the fast path takes, is a
// finding).
#include <cmath>
#include <vector>

#include "core/image_io.h"
#include "core/png_gray16.h"
#include "fuzz/fuzz_util.h"

namespace {

// `info`: the header OpenImageIO read (a file it refuses at the header never reaches the fast
// path in the loader either).
void CheckPngFastPath(const std::filesystem::path& path, const mesoscan::ImageInfo& info) {
  using namespace mesoscan;
  if (info.channels != 1 || static_cast<double>(info.width) * info.height > (1 << 22)) return;
  std::vector<uint16_t> fast(static_cast<size_t>(info.width) * info.height);
  if (!ReadPngGray16(path, info.width, info.height, fast.data())) return;
  ImageF ref;
  try {
    ref = ReadImage(path);
  } catch (const Error& e) {
    std::fprintf(stderr, "fuzz finding: the PNG fast path decoded a file OpenImageIO refuses: %s\n",
                 e.what());
    std::abort();
  }
  const double scale = info.bits_per_sample == 8 ? 255.0 : 65535.0;
  const long mul = info.bits_per_sample == 8 ? 257 : 1;
  for (size_t i = 0; i < fast.size(); ++i)
    if (std::lround(ref.data()[i] * scale) * mul != fast[i]) {
      std::fprintf(stderr,
                   "fuzz finding: the PNG fast path gives %d at sample %zu, OpenImageIO %g\n",
                   fast[i], i, ref.data()[i] * scale);
      std::abort();
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  if (size < 1) return 0;
  static const char* kExt[] = {".png", ".exr", ".tif"};
  const std::string name = std::string("frame") + kExt[data[0] % 3];
  const auto path = fuzz::WriteInput(name, data + 1, size - 1);
  fuzz::Expect([&] { (void)ReadImage(path); });
  ImageInfo info;
  bool have_info = false;
  fuzz::Expect([&] {
    info = ReadImageInfo(path);
    have_info = true;
  });
  if (data[0] % 3 == 0 && have_info) CheckPngFastPath(path, info);
  return 0;
}
