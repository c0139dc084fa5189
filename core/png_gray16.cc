#include "core/png_gray16.h"

#include <fcntl.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <libdeflate.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <mutex>
#include <new>
#include <utility>
#include <vector>

#include "core/large_block_cache.h"

namespace mesoscan {
namespace {

// The buffers of a decode: the file (its IDAT payloads gathered at its start) and the inflated
// rows, ~10 MB at full resolution. Mapped alone (LargeBlockAllocate: unmapped when freed, or kept
// for the next large allocation where the process enables the large block cache,
// core/large_block_cache.h; malloc keeps freed buffers in its per-thread arenas, +8 MB of the
// CLI's peak RSS), and pooled while decodes overlap: fresh pages for every frame cost 4 ms a frame
// (26.0 against 21.9 ms; with MAP_POPULATE 24.9), while buffers kept per thread for good stayed
// resident through the reconstruction's peak (+39 MB). The pool is emptied whenever no decode is
// running, so once a session's frames are read it holds nothing. Under AddressSanitizer (the
// fuzzers, CI's unit tests) each decode gets exact-size buffers from new[], whose bounds it checks.
#if defined(__SANITIZE_ADDRESS__)
#define MESOSCAN_PNG_EXACT_BUFFERS 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define MESOSCAN_PNG_EXACT_BUFFERS 1
#endif
#endif
class Buffer {
 public:
  Buffer() = default;
  ~Buffer() { Free(); }
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;
  // At least n bytes (contents undefined), or nullptr if out of memory.
  uint8_t* Reserve(size_t n) {
    n = n ? n : 1;
#ifdef MESOSCAN_PNG_EXACT_BUFFERS
    const bool enough = n == capacity_;
#else
    const bool enough = n <= capacity_;
#endif
    if (enough) return data_;
    Free();
#ifdef MESOSCAN_PNG_EXACT_BUFFERS
    data_ = new (std::nothrow) uint8_t[n];
#else
    data_ = static_cast<uint8_t*>(LargeBlockAllocate(n));
#endif
    capacity_ = data_ ? n : 0;
    return data_;
  }

 private:
  void Free() {
#ifdef MESOSCAN_PNG_EXACT_BUFFERS
    delete[] data_;
#else
    LargeBlockFree(data_, capacity_);
#endif
    data_ = nullptr;
    capacity_ = 0;
  }
  uint8_t* data_ = nullptr;
  size_t capacity_ = 0;
};

struct Scratch {
  Buffer file, raw;
};

// A decode's scratch, from the pool; back to it at the end unless no other decode runs.
class ScratchLease {
 public:
  ScratchLease() {
    std::lock_guard<std::mutex> lock(mutex_);
    ++active_;
    if (!free_.empty()) {
      scratch_ = std::move(free_.back());
      free_.pop_back();
    }
    if (!scratch_) scratch_ = std::make_unique<Scratch>();
  }
  ~ScratchLease() {
    std::vector<std::unique_ptr<Scratch>> unmap;  // freed outside the lock
    std::lock_guard<std::mutex> lock(mutex_);
    --active_;
#ifndef MESOSCAN_PNG_EXACT_BUFFERS
    if (active_ > 0) {
      free_.push_back(std::move(scratch_));
      return;
    }
#endif
    unmap.swap(free_);
    unmap.push_back(std::move(scratch_));
  }
  ScratchLease(const ScratchLease&) = delete;
  ScratchLease& operator=(const ScratchLease&) = delete;
  Scratch& operator*() { return *scratch_; }

 private:
  std::unique_ptr<Scratch> scratch_;
  static inline std::mutex mutex_;
  static inline int active_ = 0;
  static inline std::vector<std::unique_ptr<Scratch>> free_;
};

struct Decompressor {
  libdeflate_decompressor* d = libdeflate_alloc_decompressor();
  ~Decompressor() {
    if (d) libdeflate_free_decompressor(d);
  }
};

uint32_t Be32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | p[3];
}

const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

bool IsLetter(uint8_t c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }

// Ancillary chunks that OpenImageIO or libpng may let change the samples or add a channel: left
// to them. Every other ancillary chunk only describes the image (oFFs, pHYs, tEXt, tIME, ...).
bool ChangesSamples(const uint8_t* type) {
  static const char* kTypes[] = {"tRNS", "sBIT", "gAMA", "cHRM", "sRGB", "iCCP", "bKGD", "sPLT"};
  for (const char* t : kTypes)
    if (std::memcmp(type, t, 4) == 0) return true;
  return false;
}

// The Paeth predictor without branches (a branch on noisy samples is mispredicted about half
// the time): a, b or c, whichever is nearest to a + b - c, ties in that order.
inline int Paeth(int a, int b, int c) {
  const int pa = std::abs(b - c), pb = std::abs(a - c), pc = std::abs(a + b - 2 * c);
  const int take_b = -static_cast<int>(pb < pa);
  const int pred = (a & ~take_b) | (b & take_b);
  const int best = (pa & ~take_b) | (pb & take_b);
  const int take_c = -static_cast<int>(pc < best);
  return (pred & ~take_c) | (c & take_c);
}

// Undoes one row's filter in place: x (n bytes) becomes the reconstructed row, given the
// previous reconstructed row `up` (zeros for the first row) and bpp bytes per pixel. The byte
// lanes of a pixel are independent chains (bpp 2: the high and low bytes of a sample).
template <int kBpp>
bool Unfilter(uint8_t filter, uint8_t* x, const uint8_t* up, size_t n) {
  switch (filter) {
    case 0:
      return true;
    case 1:  // Sub
      for (size_t i = kBpp; i < n; ++i) x[i] = static_cast<uint8_t>(x[i] + x[i - kBpp]);
      return true;
    case 2: {  // Up
      size_t i = 0;
#if defined(__SSE2__)
      for (; i + 16 <= n; i += 16) {
        const __m128i v = _mm_add_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(x + i)),
                                       _mm_loadu_si128(reinterpret_cast<const __m128i*>(up + i)));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(x + i), v);
      }
#endif
      for (; i < n; ++i) x[i] = static_cast<uint8_t>(x[i] + up[i]);
      return true;
    }
    case 3:  // Average
      for (size_t i = 0; i < kBpp && i < n; ++i) x[i] = static_cast<uint8_t>(x[i] + (up[i] >> 1));
      for (size_t i = kBpp; i < n; ++i)
        x[i] = static_cast<uint8_t>(x[i] + ((x[i - kBpp] + up[i]) >> 1));
      return true;
    case 4:  // Paeth
      for (size_t i = 0; i < kBpp && i < n; ++i) x[i] = static_cast<uint8_t>(x[i] + up[i]);
#if defined(__SSE2__)
      if constexpr (kBpp == 2) {
        // A pixel's two bytes as two 16-bit lanes of one register: half the instructions of
        // the scalar pair of chains (21.3 against 23.5-24.3 ms a frame, two decoding threads).
        const __m128i zero = _mm_setzero_si128(), low_byte = _mm_set1_epi16(0xff);
        auto load2 = [&](const uint8_t* p) {
          uint16_t v;
          std::memcpy(&v, p, 2);
          return _mm_unpacklo_epi8(_mm_cvtsi32_si128(v), zero);
        };
        auto abs16 = [&](__m128i v) { return _mm_max_epi16(v, _mm_sub_epi16(zero, v)); };
        __m128i a = load2(x);
        for (size_t i = 2; i + 1 < n; i += 2) {
          uint32_t cb_bytes;  // c0 c1 b0 b1: the pixels above-left and above
          std::memcpy(&cb_bytes, up + i - 2, 4);
          const __m128i c = _mm_unpacklo_epi8(_mm_cvtsi32_si128(static_cast<int>(cb_bytes)), zero);
          const __m128i b = _mm_srli_si128(c, 4);
          const __m128i bc = _mm_sub_epi16(b, c), pa = abs16(bc);
          const __m128i ac = _mm_sub_epi16(a, c);
          const __m128i pb = abs16(ac), pc = abs16(_mm_add_epi16(ac, bc));
          const __m128i take_b = _mm_cmplt_epi16(pb, pa);
          __m128i pred = _mm_xor_si128(a, _mm_and_si128(_mm_xor_si128(a, b), take_b));
          const __m128i take_c = _mm_cmplt_epi16(pc, _mm_min_epi16(pa, pb));
          pred = _mm_xor_si128(pred, _mm_and_si128(_mm_xor_si128(pred, c), take_c));
          a = _mm_and_si128(_mm_add_epi16(load2(x + i), pred), low_byte);
          const int v = _mm_cvtsi128_si32(_mm_packus_epi16(a, a));
          x[i] = static_cast<uint8_t>(v);
          x[i + 1] = static_cast<uint8_t>(v >> 8);
        }
        return true;
      }
#endif
      if constexpr (kBpp == 2) {  // the left pixel's two bytes carried in registers
        int a0 = n > 0 ? x[0] : 0, a1 = n > 1 ? x[1] : 0;
        for (size_t i = 2; i + 1 < n; i += 2) {
          a0 = static_cast<uint8_t>(x[i] + Paeth(a0, up[i], up[i - 2]));
          a1 = static_cast<uint8_t>(x[i + 1] + Paeth(a1, up[i + 1], up[i - 1]));
          x[i] = static_cast<uint8_t>(a0);
          x[i + 1] = static_cast<uint8_t>(a1);
        }
      } else {
        int a = n > 0 ? x[0] : 0;
        for (size_t i = kBpp; i < n; ++i) {
          a = static_cast<uint8_t>(x[i] + Paeth(a, up[i], up[i - kBpp]));
          x[i] = static_cast<uint8_t>(a);
        }
      }
      return true;
    default:
      return false;
  }
}

// Big-endian 16-bit samples to native ones; 8-bit samples v to v * 257 (OpenImageIO's UINT8 ->
// UINT16 conversion). The SSE2 loops (every x86-64) assume a little-endian host, as x86 is; GCC
// does not vectorise these loops by itself.
void Convert16(const uint8_t* row, int width, uint16_t* out) {
  int x = 0;
#if defined(__SSE2__)
  for (; x + 8 <= width; x += 8) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + 2 * x));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x),
                     _mm_or_si128(_mm_slli_epi16(v, 8), _mm_srli_epi16(v, 8)));
  }
#endif
  for (; x < width; ++x) out[x] = static_cast<uint16_t>((row[2 * x] << 8) | row[2 * x + 1]);
}
void Convert8(const uint8_t* row, int width, uint16_t* out) {
  int x = 0;
#if defined(__SSE2__)
  for (; x + 16 <= width; x += 16) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + x));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm_unpacklo_epi8(v, v));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x + 8), _mm_unpackhi_epi8(v, v));
  }
#endif
  for (; x < width; ++x) out[x] = static_cast<uint16_t>(row[x] * 257);
}

PngGrayStatus Fail(PngGrayStatus s, std::string* why, const char* reason) {
  if (why) *why = reason;
  return s;
}

// Decodes the file held in scratch.file (size bytes) in place: it is overwritten (the IDAT
// payloads are gathered at its start).
PngGrayStatus DecodeInPlace(Scratch& scratch, size_t size, int width, int height, uint16_t* out,
                            std::string* why) {
  uint8_t* const file = scratch.file.Reserve(size);
  using S = PngGrayStatus;
  if (width <= 0 || height <= 0) return Fail(S::kUnsupported, why, "no expected size");
  if (size < 8 || std::memcmp(file, kSignature, 8) != 0)
    return Fail(S::kUnsupported, why, "not a PNG signature");
  // IHDR first, 13 bytes.
  if (size < 8 + 12 + 13) return Fail(S::kDamaged, why, "file ends inside IHDR");
  if (Be32(file + 8) != 13 || std::memcmp(file + 12, "IHDR", 4) != 0)
    return Fail(S::kDamaged, why, "first chunk is not a 13-byte IHDR");
  const uint8_t* ihdr = file + 16;
  if (libdeflate_crc32(0, file + 12, 17) != Be32(file + 29))
    return Fail(S::kDamaged, why, "IHDR CRC mismatch");
  const uint32_t w = Be32(ihdr), h = Be32(ihdr + 4);
  const int depth = ihdr[8], colour = ihdr[9];
  if (w != static_cast<uint32_t>(width) || h != static_cast<uint32_t>(height))
    return Fail(S::kUnsupported, why, "size other than expected");
  if ((depth != 8 && depth != 16) || colour != 0)
    return Fail(S::kUnsupported, why, "not grey 8 or 16 bits");
  if (ihdr[10] != 0 || ihdr[11] != 0 || ihdr[12] != 0)
    return Fail(S::kUnsupported, why, "interlaced or unknown compression/filter method");

  // The chunks: each one's CRC checked, the IDAT payloads moved to the front of the buffer
  // (never past where they are read from), the rest skipped.
  size_t pos = 33, idat_end = 0;
  enum { kBefore, kIn, kAfter } idat = kBefore;
  bool iend = false;
  while (!iend) {
    if (size - pos < 12) return Fail(S::kDamaged, why, "file cut short (no IEND)");
    const uint32_t len = Be32(file + pos);
    const uint8_t* type = file + pos + 4;
    if (len > 0x7fffffffu || len > size - pos - 12)
      return Fail(S::kDamaged, why, "chunk length past the end of the file");
    if (!IsLetter(type[0]) || !IsLetter(type[1]) || !IsLetter(type[2]) || !IsLetter(type[3]))
      return Fail(S::kDamaged, why, "chunk type is not four letters");
    if (libdeflate_crc32(0, type, len + 4) != Be32(type + 4 + len))
      return Fail(S::kDamaged, why, "chunk CRC mismatch");
    const bool is_idat = std::memcmp(type, "IDAT", 4) == 0;
    if (is_idat) {
      if (idat == kAfter) return Fail(S::kUnsupported, why, "IDAT chunks not consecutive");
      idat = kIn;
      std::memmove(file + idat_end, type + 4, len);
      idat_end += len;
    } else {
      if (idat == kIn) idat = kAfter;
      if (std::memcmp(type, "IEND", 4) == 0) {
        iend = true;
      } else if (!(type[0] & 0x20)) {  // critical: IHDR again, PLTE, or unknown
        return Fail(S::kUnsupported, why, "a critical chunk other than IDAT and IEND");
      } else if (ChangesSamples(type)) {
        return Fail(S::kUnsupported, why, "an ancillary chunk that may change the samples");
      }
    }
    pos += 12 + static_cast<size_t>(len);
  }
  if (idat == kBefore) return Fail(S::kDamaged, why, "no IDAT chunk");

  // Inflate the whole stream at once (Adler-32 checked by libdeflate; it must fill the rows
  // exactly and end where the IDAT data ends).
  const int bpp = depth / 8;
  const size_t rowbytes = static_cast<size_t>(width) * bpp;
  const size_t stride = rowbytes + 1;
  const size_t raw_size = stride * static_cast<size_t>(height);
  thread_local Decompressor decompressor;  // its tables, some KB per thread
  if (!decompressor.d) return Fail(S::kUnsupported, why, "no libdeflate decompressor");
  uint8_t* raw = scratch.raw.Reserve(raw_size);
  if (!raw) return Fail(S::kUnsupported, why, "out of memory");
  size_t in_used = 0, out_used = 0;
  const libdeflate_result r = libdeflate_zlib_decompress_ex(decompressor.d, file, idat_end, raw,
                                                            raw_size, &in_used, &out_used);
  if (r != LIBDEFLATE_SUCCESS)
    return Fail(S::kDamaged, why,
                r == LIBDEFLATE_INSUFFICIENT_SPACE ? "more image data than the rows hold"
                                                   : "bad zlib stream or Adler-32");
  if (out_used != raw_size) return Fail(S::kDamaged, why, "less image data than the rows need");
  if (in_used != idat_end) return Fail(S::kDamaged, why, "data after the zlib stream");

  const std::vector<uint8_t> zeros(rowbytes, 0);
  const uint8_t* up = zeros.data();
  auto convert = [&](int y, const uint8_t* row) {
    uint16_t* dst = out + static_cast<size_t>(y) * width;
    if (bpp == 2)
      Convert16(row, width, dst);
    else
      Convert8(row, width, dst);
  };
  for (int y = 0; y < height; ++y) {
    uint8_t* row = raw + static_cast<size_t>(y) * stride;
    const bool ok = bpp == 2 ? Unfilter<2>(row[0], row + 1, up, rowbytes)
                             : Unfilter<1>(row[0], row + 1, up, rowbytes);
    if (!ok) return Fail(S::kDamaged, why, "unknown row filter");
    convert(y, row + 1);
    up = row + 1;
  }
  return S::kDecoded;
}

}  // namespace

bool ParsePngHeader(const uint8_t* p, PngHeader* header) {
  if (std::memcmp(p, kSignature, 8) != 0 || Be32(p + 8) != 13 ||
      std::memcmp(p + 12, "IHDR", 4) != 0 || libdeflate_crc32(0, p + 12, 17) != Be32(p + 29))
    return false;
  header->width = Be32(p + 16);
  header->height = Be32(p + 20);
  header->bit_depth = p[24];
  header->colour_type = p[25];
  return true;
}

PngGrayStatus DecodePngGray(const uint8_t* file, size_t size, int width, int height, uint16_t* out,
                            std::string* why) {
  ScratchLease scratch;
  uint8_t* copy = (*scratch).file.Reserve(size);
  if (!copy) return Fail(PngGrayStatus::kUnsupported, why, "out of memory");
  if (size) std::memcpy(copy, file, size);
  return DecodeInPlace(*scratch, size, width, height, out, why);
}

bool ReadPngGray16(const std::filesystem::path& path, int width, int height, uint16_t* out) {
  if (width <= 0 || height <= 0) return false;
  return ReadPngGray16(
      path, [&](int w, int h, int) { return w == width && h == height ? out : nullptr; });
}

bool ReadPngGray16(const std::filesystem::path& path,
                   const std::function<uint16_t*(int width, int height, int bit_depth)>& alloc) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  struct stat st {};
  uint8_t head[25];
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size < 33 ||
      ::pread(fd, head, sizeof head, 0) != static_cast<ssize_t>(sizeof head)) {
    ::close(fd);
    return false;
  }
  // The size from IHDR (checked again, with its CRC, by the decode).
  const uint32_t w = Be32(head + 16), h = Be32(head + 20);
  // A regular file no larger than twice its 16-bit samples plus 1 MB (as OpenImageInput checks).
  const double limit = 4.0 * w * static_cast<double>(h) + (1 << 20);
  if (std::memcmp(head + 12, "IHDR", 4) != 0 || w == 0 || h == 0 || w > (1u << 24) ||
      h > (1u << 24) || static_cast<double>(st.st_size) > limit) {
    ::close(fd);
    return false;
  }
  const size_t size = static_cast<size_t>(st.st_size);
  ScratchLease scratch;
  uint8_t* buf = (*scratch).file.Reserve(size);
  if (!buf) {
    ::close(fd);
    return false;
  }
  size_t got = 0;
  while (got < size) {
    const ssize_t n = ::read(fd, buf + got, size - got);
    if (n <= 0) break;
    got += static_cast<size_t>(n);
  }
  ::close(fd);
  if (got != size) return false;
  const int width = static_cast<int>(w), height = static_cast<int>(h);
  uint16_t* out = alloc(width, height, head[24]);
  if (!out) return false;
  return DecodeInPlace(*scratch, size, width, height, out, nullptr) == PngGrayStatus::kDecoded;
}

}  // namespace mesoscan
