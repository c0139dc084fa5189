// libFuzzer: the frames' PNG fast path (core/png_gray16.h) on bytes in memory, without
// OpenImageIO or files (thousands of inputs a second, where fuzz_frame, which also checks the
// fast path against OpenImageIO, runs a few). The expected size is the one the IHDR declares
// (bounded to 4 M samples), or a wrong one: whatever the bytes, the decoder returns a status,
// reads and writes only inside its buffers (AddressSanitizer), and a decoded file was whole.
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "core/png_gray16.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  int w = 7, h = 3;
  if (size >= 24) {
    auto be32 = [&](size_t o) {
      return (uint32_t{data[o]} << 24) | (uint32_t{data[o + 1]} << 16) |
             (uint32_t{data[o + 2]} << 8) | data[o + 3];
    };
    const uint32_t fw = be32(16), fh = be32(20);
    if (fw > 0 && fh > 0 && fw <= (1u << 22) && fh <= (1u << 22) &&
        static_cast<uint64_t>(fw) * fh <= (1u << 22)) {
      w = static_cast<int>(fw);
      h = static_cast<int>(fh);
    }
  }
  std::vector<uint16_t> out(static_cast<size_t>(w) * h);
  std::string why;
  const PngGrayStatus s = DecodePngGray(data, size, w, h, out.data(), &why);
  if (s != PngGrayStatus::kDecoded && why.empty()) {
    std::fprintf(stderr, "fuzz finding: the PNG fast path declined without a reason\n");
    std::abort();
  }
  // A decoded file ends with a whole IEND chunk somewhere: at least signature + IHDR + IEND.
  if (s == PngGrayStatus::kDecoded && size < 8 + 25 + 12) {
    std::fprintf(stderr, "fuzz finding: the PNG fast path decoded %zu bytes\n", size);
    std::abort();
  }
  return 0;
}
