// The frames' PNG fast path (core/png_gray16.h) against OpenImageIO's decode of the same files:
// PNGs encoded here with each row filter (and a mix), 8 and 16 bits, odd sizes, IDATs split into
// many chunks with ancillary chunks around them; then damaged files (a wrong CRC, a wrong
// Adler-32, a truncated file, an unknown filter) and files outside the fast path.
#include "core/png_gray16.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <libdeflate.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/image_io.h"
#include "core/library_leaks.h"  // OpenImageIO's error strings
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempDir("png_gray16_test", name); }

void PutBe32(std::vector<uint8_t>& v, uint32_t x) {
  for (int s = 24; s >= 0; s -= 8) v.push_back(static_cast<uint8_t>(x >> s));
}

void PutChunk(std::vector<uint8_t>& png, const char* type, const std::vector<uint8_t>& data) {
  PutBe32(png, static_cast<uint32_t>(data.size()));
  const size_t start = png.size();
  png.insert(png.end(), type, type + 4);
  png.insert(png.end(), data.begin(), data.end());
  PutBe32(png, libdeflate_crc32(0, png.data() + start, png.size() - start));
}

int PaethRef(int a, int b, int c) {
  const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
  if (pa <= pb && pa <= pc) return a;
  return pb <= pc ? b : c;
}

struct PngOptions {
  int depth = 16;
  int filter = 0;          // 0-4 for every row; 5: row y uses filter y % 5
  size_t idat_chunk = 0;   // split the zlib stream into IDATs of this many bytes (0: one)
  bool ancillary = false;  // tEXt before and after the IDATs, oFFs before
  uint8_t interlace = 0;   // written into IHDR only
  uint8_t colour = 0;
};

// A grey PNG of `samples` (row-major, values < 2^depth), each row filtered as asked.
std::vector<uint8_t> EncodePng(int w, int h, const std::vector<uint16_t>& samples,
                               const PngOptions& o) {
  const int bpp = o.depth / 8;
  const size_t rowbytes = static_cast<size_t>(w) * bpp;
  std::vector<uint8_t> raw, prev(rowbytes, 0), cur(rowbytes);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const uint16_t v = samples[static_cast<size_t>(y) * w + x];
      if (bpp == 2) {
        cur[2 * x] = static_cast<uint8_t>(v >> 8);
        cur[2 * x + 1] = static_cast<uint8_t>(v);
      } else {
        cur[x] = static_cast<uint8_t>(v);
      }
    }
    const int f = o.filter == 5 ? y % 5 : o.filter;
    raw.push_back(static_cast<uint8_t>(f));
    for (size_t i = 0; i < rowbytes; ++i) {
      const int a = i >= static_cast<size_t>(bpp) ? cur[i - bpp] : 0, b = prev[i];
      const int c = i >= static_cast<size_t>(bpp) ? prev[i - bpp] : 0;
      const int pred = f == 0   ? 0
                       : f == 1 ? a
                       : f == 2 ? b
                       : f == 3 ? (a + b) / 2
                                : PaethRef(a, b, c);
      raw.push_back(static_cast<uint8_t>(cur[i] - pred));
    }
    prev = cur;
  }
  libdeflate_compressor* comp = libdeflate_alloc_compressor(6);
  std::vector<uint8_t> z(libdeflate_zlib_compress_bound(comp, raw.size()));
  z.resize(libdeflate_zlib_compress(comp, raw.data(), raw.size(), z.data(), z.size()));
  libdeflate_free_compressor(comp);

  std::vector<uint8_t> png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  std::vector<uint8_t> ihdr;
  PutBe32(ihdr, static_cast<uint32_t>(w));
  PutBe32(ihdr, static_cast<uint32_t>(h));
  ihdr.insert(ihdr.end(), {static_cast<uint8_t>(o.depth), o.colour, 0, 0, o.interlace});
  PutChunk(png, "IHDR", ihdr);
  const std::vector<uint8_t> text = {'C', 'o', 'm', 'm', 'e', 'n', 't', 0, 'h', 'i'};
  if (o.ancillary) {
    PutChunk(png, "tEXt", text);
    PutChunk(png, "oFFs", std::vector<uint8_t>(9, 0));
  }
  const size_t step = o.idat_chunk ? o.idat_chunk : z.size();
  for (size_t i = 0; i < z.size(); i += step)
    PutChunk(png, "IDAT",
             std::vector<uint8_t>(z.begin() + i, z.begin() + std::min(z.size(), i + step)));
  if (o.ancillary) PutChunk(png, "tEXt", text);
  PutChunk(png, "IEND", {});
  return png;
}

std::vector<uint16_t> Samples(int w, int h, int depth, uint32_t seed) {
  std::vector<uint16_t> s(static_cast<size_t>(w) * h);
  uint32_t r = seed;
  for (size_t i = 0; i < s.size(); ++i) {
    r = r * 1664525u + 1013904223u;
    // A smooth ramp plus noise (as frames are), sometimes the extremes.
    const uint32_t v = static_cast<uint32_t>(i % w) * 97 + (r >> 20);
    s[i] = static_cast<uint16_t>((r >> 8) % 17 == 0 ? ((r >> 4) & 1 ? 0xffff : 0) : v);
    if (depth == 8) s[i] &= 0xff;
  }
  return s;
}

fs::path Write(const fs::path& dir, const std::string& name, const std::vector<uint8_t>& bytes) {
  const fs::path p = dir / name;
  std::ofstream(p, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  return p;
}

// OpenImageIO's samples as 16 bits (what the frames' loader asks it for); false if it refuses.
bool OiioDecode(const fs::path& path, std::vector<uint16_t>* out) {
  auto in = OIIO::ImageInput::open(path.string());
  if (!in) {
    (void)OIIO::geterror();
    return false;
  }
  const OIIO::ImageSpec& spec = in->spec();
  out->assign(static_cast<size_t>(spec.width) * spec.height * spec.nchannels, 0);
  const bool ok = in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT16, out->data());
  (void)in->geterror();
  return ok;
}

TEST(PngGray16, EveryFilterAndDepthMatchesOpenImageIo) {
  const fs::path dir = TempDir("filters");
  const int sizes[][2] = {{1, 1}, {2, 3}, {7, 5}, {301, 37}};
  for (int depth : {8, 16})
    for (int filter = 0; filter <= 5; ++filter)
      for (const auto& wh : sizes) {
        const int w = wh[0], h = wh[1];
        PngOptions o;
        o.depth = depth;
        o.filter = filter;
        o.idat_chunk = (filter % 2) ? 7 : 0;  // many tiny IDATs half the time
        o.ancillary = filter >= 3;
        const auto samples = Samples(w, h, depth, static_cast<uint32_t>(w * 131 + filter));
        char buf[64];
        std::snprintf(buf, sizeof buf, "d%d_f%d_%dx%d.png", depth, filter, w, h);
        const std::string name = buf;
        const fs::path p = Write(dir, name, EncodePng(w, h, samples, o));
        std::vector<uint16_t> ref, fast(samples.size(), 1);
        ASSERT_TRUE(OiioDecode(p, &ref)) << name;
        ASSERT_EQ(ref.size(), samples.size()) << name;
        ASSERT_TRUE(ReadPngGray16(p, w, h, fast.data())) << name;
        for (size_t i = 0; i < samples.size(); ++i) {
          ASSERT_EQ(fast[i], ref[i]) << name << " sample " << i;
          // And what was encoded (8 bits read as v * 257).
          ASSERT_EQ(fast[i], depth == 8 ? samples[i] * 257 : samples[i]) << name << " " << i;
        }
      }
}

// What the project's own writers produce (OpenImageIO, its default filters and compression).
TEST(PngGray16, OpenImageIoWrittenFramesMatch) {
  const fs::path dir = TempDir("oiio");
  const int w = 523, h = 41;
  ImageU16 im16(w, h, 1);
  ImageU8 im8(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      im16(x, y) = static_cast<uint16_t>((x * 2654435761u + y * 40503u) >> 7);
      im8(x, y) = static_cast<uint8_t>((x * 7 + y * y) ^ (x >> 3));
    }
  WritePng16(dir / "g16.png", im16);
  WritePng8(dir / "g8.png", im8, 9);
  for (const char* name : {"g16.png", "g8.png"}) {
    std::vector<uint16_t> ref, fast(static_cast<size_t>(w) * h);
    ASSERT_TRUE(OiioDecode(dir / name, &ref));
    ASSERT_TRUE(ReadPngGray16(dir / name, w, h, fast.data())) << name;
    EXPECT_EQ(fast, ref) << name;
  }
}

// Damage: the fast path says kDamaged and ReadPngGray16 false, so the loader falls back to
// OpenImageIO, which refuses the file with one line naming it (or, for damage libpng does not
// check, decodes it: see the Adler-32 case).
TEST(PngGray16, DamagedFilesAreDeclinedAndOpenImageIoRefusesThem) {
  const fs::path dir = TempDir("damaged");
  const int w = 64, h = 9;
  const auto samples = Samples(w, h, 16, 5);
  PngOptions o;
  o.filter = 5;
  o.idat_chunk = 100;
  const std::vector<uint8_t> good = EncodePng(w, h, samples, o);
  std::vector<uint16_t> out(static_cast<size_t>(w) * h);
  ASSERT_EQ(DecodePngGray(good.data(), good.size(), w, h, out.data()), PngGrayStatus::kDecoded);

  auto expect_damaged = [&](const std::string& name, const std::vector<uint8_t>& bytes,
                            bool oiio_refuses) {
    std::string why;
    EXPECT_EQ(DecodePngGray(bytes.data(), bytes.size(), w, h, out.data(), &why),
              PngGrayStatus::kDamaged)
        << name;
    EXPECT_FALSE(why.empty()) << name;
    const fs::path p = Write(dir, name, bytes);
    EXPECT_FALSE(ReadPngGray16(p, w, h, out.data())) << name;
    if (oiio_refuses) {
      MESOSCAN_IGNORE_LIBRARY_LEAKS();
      try {
        (void)ReadImage(p);
        ADD_FAILURE() << name << ": OpenImageIO decoded it";
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::kBadInput) << name;
        const std::string msg = e.what();
        EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
        EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      }
    }
  };
  // The first IDAT starts after the signature (8) and IHDR (25): its length, type, data, CRC.
  const size_t idat = 33;
  ASSERT_EQ(std::string(good.begin() + idat + 4, good.begin() + idat + 8), "IDAT");
  {
    auto bad = good;
    bad[idat + 8 + 100] ^= 0x01;  // the first IDAT's CRC
    expect_damaged("crc.png", bad, true);
  }
  {
    auto bad = good;
    bad[idat + 8 + 50] ^= 0x10;  // a byte of compressed data: the CRC notices
    expect_damaged("data.png", bad, true);
  }
  {
    // A wrong Adler-32 with every CRC right: decode the stream, change one sample's byte,
    // re-encode the file with the original stream's checksum.
    PngOptions one = o;
    one.idat_chunk = 0;
    auto bad = EncodePng(w, h, samples, one);
    const uint32_t len =
        (uint32_t{bad[idat]} << 24) | (bad[idat + 1] << 16) | (bad[idat + 2] << 8) | bad[idat + 3];
    uint8_t* adler = bad.data() + idat + 8 + len - 4;
    adler[3] ^= 0x01;
    const uint32_t crc = libdeflate_crc32(0, bad.data() + idat + 4, len + 4);
    uint8_t* c = bad.data() + idat + 8 + len;
    c[0] = static_cast<uint8_t>(crc >> 24), c[1] = static_cast<uint8_t>(crc >> 16);
    c[2] = static_cast<uint8_t>(crc >> 8), c[3] = static_cast<uint8_t>(crc);
    expect_damaged("adler.png", bad, true);
  }
  for (size_t cut : {good.size() - 12, good.size() / 2, size_t{40}, size_t{20}}) {
    auto bad = good;
    bad.resize(cut);
    // Cut inside IEND (after every IDAT) libpng has all rows and OpenImageIO decodes it.
    expect_damaged("cut" + std::to_string(cut) + ".png", bad, cut < good.size() - 12);
  }
  {
    // Row filter 5 does not exist.
    std::vector<uint8_t> raw((static_cast<size_t>(w) * 2 + 1) * h, 0);
    raw[0] = 5;
    libdeflate_compressor* comp = libdeflate_alloc_compressor(1);
    std::vector<uint8_t> z(libdeflate_zlib_compress_bound(comp, raw.size()));
    z.resize(libdeflate_zlib_compress(comp, raw.data(), raw.size(), z.data(), z.size()));
    libdeflate_free_compressor(comp);
    std::vector<uint8_t> bad(good.begin(), good.begin() + idat);
    PutChunk(bad, "IDAT", z);
    PutChunk(bad, "IEND", {});
    expect_damaged("filter5.png", bad, true);
  }
}

TEST(PngGray16, OtherPngsAreLeftToOpenImageIo) {
  const int w = 10, h = 4;
  const auto samples = Samples(w, h, 16, 9);
  std::vector<uint16_t> out(static_cast<size_t>(w) * h * 3);
  auto status = [&](const std::vector<uint8_t>& png, int ww = 10) {
    return DecodePngGray(png.data(), png.size(), ww, h, out.data());
  };
  PngOptions o;
  EXPECT_EQ(status(EncodePng(w, h, samples, o)), PngGrayStatus::kDecoded);
  EXPECT_EQ(status(EncodePng(w, h, samples, o), 11), PngGrayStatus::kUnsupported);  // size
  PngOptions interlaced = o;
  interlaced.interlace = 1;
  EXPECT_EQ(status(EncodePng(w, h, samples, interlaced)), PngGrayStatus::kUnsupported);
  PngOptions rgb = o;
  rgb.colour = 2;
  EXPECT_EQ(status(EncodePng(w, h, samples, rgb)), PngGrayStatus::kUnsupported);
  // A tRNS chunk (OpenImageIO adds an alpha channel) and an unknown critical chunk.
  for (const char* type : {"tRNS", "ABCD"}) {
    auto png = EncodePng(w, h, samples, o);
    std::vector<uint8_t> tail(png.begin() + 33, png.end());
    png.resize(33);
    PutChunk(png, type, {0, 1});
    png.insert(png.end(), tail.begin(), tail.end());
    EXPECT_EQ(status(png), PngGrayStatus::kUnsupported) << type;
  }
  const std::vector<uint8_t> jpeg = {0xff, 0xd8, 0xff, 0xe0, 0, 0x10, 'J', 'F', 'I', 'F'};
  EXPECT_EQ(status(jpeg), PngGrayStatus::kUnsupported);
}

}  // namespace
}  // namespace mesoscan
