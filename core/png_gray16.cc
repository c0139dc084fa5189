#include "core/png_gray16.h"

#include <png.h>

#include <csetjmp>
#include <cstdio>

namespace mesoscan {
namespace {

// libpng reports errors by longjmp to the setjmp in Decode, silently, as it drops warnings: the
// caller falls back to OpenImageIO, which names the problem if there is one.
[[noreturn]] void OnError(png_structp png, png_const_charp) { png_longjmp(png, 1); }
void OnWarning(png_structp, png_const_charp) {}

// Plain C objects only between setjmp and any longjmp (no destructors are skipped).
bool Decode(std::FILE* file, int width, int height, uint16_t* out) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, OnError, OnWarning);
  if (!png) return false;
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return false;
  }
  // Volatile: read after a longjmp.
  volatile bool ok = false;
  if (setjmp(png_jmpbuf(png)) == 0) {
    png_init_io(png, file);
    // Checksums off: the chunk CRCs and the zlib stream's Adler-32 (inflate still checks its
    // own structure).
    png_set_crc_action(png, PNG_CRC_QUIET_USE, PNG_CRC_QUIET_USE);
#ifdef PNG_IGNORE_ADLER32
    png_set_option(png, PNG_IGNORE_ADLER32, PNG_OPTION_ON);
#endif
    png_read_info(png, info);
    png_uint_32 w = 0, h = 0;
    int depth = 0, colour = 0, interlace = 0;
    png_get_IHDR(png, info, &w, &h, &depth, &colour, &interlace, nullptr, nullptr);
    if (static_cast<int64_t>(w) == width && static_cast<int64_t>(h) == height && depth == 16 &&
        colour == PNG_COLOR_TYPE_GRAY && interlace == PNG_INTERLACE_NONE &&
        !png_get_valid(png, info, PNG_INFO_tRNS)) {
      const uint16_t probe = 1;
      if (*reinterpret_cast<const uint8_t*>(&probe) == 1) png_set_swap(png);  // little-endian
      png_read_update_info(png, info);
      if (png_get_rowbytes(png, info) == static_cast<size_t>(width) * 2) {
        for (int y = 0; y < height; ++y)
          png_read_row(png, reinterpret_cast<png_bytep>(out + static_cast<size_t>(y) * width),
                       nullptr);
        ok = true;
      }
    }
  }
  png_destroy_read_struct(&png, &info, nullptr);
  return ok;
}

}  // namespace

bool ReadPngGray16(const std::filesystem::path& path, int width, int height, uint16_t* out) {
  if (width <= 0 || height <= 0) return false;
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (!file) return false;
  const bool ok = Decode(file, width, height, out);
  std::fclose(file);
  return ok;
}

}  // namespace mesoscan
