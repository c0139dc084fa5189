#include "core/image_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>

#include "core/error.h"
#include "core/fs.h"
#include "core/png_gray16.h"
#include "core/scan_folder.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempDir("core_test", name); }

TEST(ImageIo, Png16RoundTripIsExact) {
  const fs::path dir = TempDir("png16");
  ImageU16 im(7, 5, 1);
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 7; ++x) im(x, y) = static_cast<uint16_t>(x * 9000 + y * 17);
  WritePng16(dir / "a.png", im);
  ImageInfo info;
  ImageF back = ReadImage(dir / "a.png", &info);
  EXPECT_EQ(info.bits_per_sample, 16);
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 7; ++x) EXPECT_EQ(std::lround(back(x, y) * 65535.0f), im(x, y));
  // Nothing but the final file is left behind.
  int files = 0;
  for (auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
}

// The frames' fast path (core/png_gray16.h) gives OpenImageIO's samples to the bit on a grey
// 16-bit PNG, and declines (false, for OIIO to decode or refuse) a colour PNG, another size and a
// truncated file.
TEST(ImageIo, PngGray16FastPathMatchesOiioAndDeclinesTheRest) {
  const fs::path dir = TempDir("png_gray16");
  const int w = 301, h = 37;  // odd sizes, rows not a multiple of anything
  ImageU16 im(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      im(x, y) = static_cast<uint16_t>((x * 2654435761u + y * 40503u) >> 7);
  WritePng16(dir / "g.png", im);
  std::vector<uint16_t> fast(static_cast<size_t>(w) * h, 0);
  ASSERT_TRUE(ReadPngGray16(dir / "g.png", w, h, fast.data()));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      ASSERT_EQ(fast[static_cast<size_t>(y) * w + x], im(x, y)) << x << "," << y;
  EXPECT_FALSE(ReadPngGray16(dir / "g.png", w + 1, h, fast.data()));
  EXPECT_FALSE(ReadPngGray16(dir / "missing.png", w, h, fast.data()));
  ImageU16 rgb(w, h, 3, 1000);
  WritePng16(dir / "rgb.png", rgb);
  EXPECT_FALSE(ReadPngGray16(dir / "rgb.png", w, h, fast.data()));
  const auto size = fs::file_size(dir / "g.png");
  fs::copy_file(dir / "g.png", dir / "cut.png");
  fs::resize_file(dir / "cut.png", size / 2);
  EXPECT_FALSE(ReadPngGray16(dir / "cut.png", w, h, fast.data()));
}

// Reading as another type than the file's goes through ReadPixels' strips of scan lines (at most
// 256 at a time): an 8-bit PNG taller than one strip, whose height is no multiple of it, reads
// back exactly, each value v as v / 255.
TEST(ImageIo, ConvertedReadsCoverEveryStrip) {
  const fs::path dir = TempDir("strips");
  ImageU8 im(3, 601, 3);  // RGB: a 2- or 4-channel PNG has alpha, which OpenImageIO premultiplies
  for (size_t i = 0; i < im.data().size(); ++i) im.data()[i] = static_cast<uint8_t>((i * 37) % 251);
  WritePng8(dir / "tall.png", im);
  const ImageF f = ReadImage(dir / "tall.png");
  ASSERT_EQ(f.height(), 601);
  ASSERT_EQ(f.channels(), 3);
  for (size_t i = 0; i < im.data().size(); ++i)
    ASSERT_FLOAT_EQ(f.data()[i], im.data()[i] / 255.0f) << i;
}

TEST(ImageIo, ExrNamedChannelsAndAttributes) {
  const fs::path dir = TempDir("exr");
  HeightField hf;
  hf.z = ImageF(4, 3, 1, 0.001f);
  hf.z(1, 1) = std::numeric_limits<float>::quiet_NaN();
  hf.x0 = -0.01;
  hf.y0 = 0.02;
  hf.pixel_size = 55e-6;
  WriteHeightExr(dir / "height.exr", hf);
  HeightField back = ReadHeightExr(dir / "height.exr");
  EXPECT_NEAR(back.pixel_size, 55e-6, 1e-12);
  EXPECT_NEAR(back.x0, -0.01, 1e-9);
  EXPECT_TRUE(std::isnan(back.z(1, 1)));
  EXPECT_FLOAT_EQ(back.z(0, 0), 0.001f);
  EXPECT_EQ(back.confidence(1, 1), 0.0f);
}

TEST(ImageIo, MissingFileNamesIt) {
  try {
    ReadImage("/nonexistent/frame.png");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), "/nonexistent/frame.png: file not found");
    EXPECT_EQ(e.exit_code(), 3);
  }
}

// EXR headers whose sizes cannot be true are refused from the header, with a message that says so
// (OpenEXR's C++ reader would first allocate what they claim: a 651-byte file with a 1.9 GB string
// attribute, found by fuzz_frame, took seconds and gigabytes).
void ExpectRefused(const fs::path& path, const std::string& why) {
  try {
    ReadImage(path);
    FAIL() << path;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind(path.string() + ": cannot read image (", 0), 0u) << what;
    EXPECT_NE(what.find(why), std::string::npos) << what;
    EXPECT_EQ(e.exit_code(), 3);
  }
}

TEST(ImageIo, ExrHeaderSizesThatCannotBeTrue) {
  const fs::path dir = TempDir("exr_sizes");
  // A small EXR with a string attribute (the first patch below makes it claim 1.9 GB).
  WriteExr(dir / "height.exr", ImageF(4, 3, 1, 0.001f), {"Z"}, {{"mesoscan:pixel_size", 55e-6}},
           {{"mesoscan:note", "a string attribute"}}, "none");
  EXPECT_EQ(ReadImage(dir / "height.exr").width(), 4);  // the untouched file reads
  const std::string bytes = ReadTextFile(dir / "height.exr");
  auto patched = [&](const std::string& key, size_t offset, int32_t value,
                     const std::string& name) {
    std::string b = bytes;
    const size_t at = b.find(key);
    EXPECT_NE(at, std::string::npos) << key;
    if (at != std::string::npos) std::memcpy(&b[at + key.size() + offset], &value, 4);
    WriteTextFile(dir / name, b);
    return dir / name;
  };
  // A string attribute claiming 1.9 GB (its size is the int32 after the type name).
  ExpectRefused(patched(std::string("string") + '\0', 0, 1884225645, "long_string.exr"),
                "not a valid EXR header");
  // Twenty million scan lines (the data window's fourth int32, after the attribute's size): the
  // chunk offset table alone would be megabytes in a file of a few hundred bytes.
  ExpectRefused(
      patched(std::string("dataWindow") + '\0' + "box2i" + '\0', 4 + 12, 20000000, "tall.exr"),
      "offset table");
  // An attribute of a type no reader knows, claiming 1.7 GB, first in the header: OpenEXR's core
  // skips it with an error message and succeeds; its C++ reader would allocate the 1.7 GB.
  {
    int32_t size = 1768685568;
    std::string b = bytes.substr(0, 8) + std::string("custom\0blob\0", 12) +
                    std::string(reinterpret_cast<const char*>(&size), 4) + bytes.substr(8);
    WriteTextFile(dir / "opaque.exr", b);
    ExpectRefused(dir / "opaque.exr", "Invalid size 1768685568");
  }
}

}  // namespace
}  // namespace mesoscan
