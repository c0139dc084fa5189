// core/png_write.h: PNGs written in parallel deflate pieces decode (by libpng, through
// OpenImageIO) to exactly the image's samples: sizes of one row, one piece, many pieces with a
// short last one, 1 to 4 channels, levels 0, 1 and 9, noisy and constant content.
#include "core/png_write.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "core/image_io.h"
#include "core/library_leaks.h"  // OpenImageIO's error strings
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// The file's samples as libpng decodes them, planar; empty if it cannot be read.
ImageU8 DecodeWithLibpng(const fs::path& path) {
  // Alpha as stored (OIIO otherwise premultiplies it on reading).
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  auto in = OIIO::ImageInput::open(path.string(), &config);
  if (!in) return {};
  const OIIO::ImageSpec& s = in->spec();
  std::vector<uint8_t> inter(static_cast<size_t>(s.width) * s.height * s.nchannels);
  if (!in->read_image(0, 0, 0, s.nchannels, OIIO::TypeDesc::UINT8, inter.data())) return {};
  ImageU8 out(s.width, s.height, s.nchannels);
  for (int c = 0; c < s.nchannels; ++c)
    for (size_t i = 0; i < out.pixels(); ++i) out.channel(c)[i] = inter[i * s.nchannels + c];
  return out;
}

TEST(PngWrite, DecodesToTheSameSamples) {
  const fs::path dir = TestTempDir("png_write_test", "same_samples");
  std::mt19937 rng(7);
  struct Case {
    int w, h, nc, level;
    bool noise;
  };
  // 1001 x 3 x 3 bytes: ~87 rows a piece, so 300 rows make 4 pieces, the last one short.
  for (const Case& k :
       {Case{1, 1, 1, 1, true}, Case{17, 1, 3, 1, true}, Case{1001, 300, 3, 1, true},
        Case{1001, 300, 3, 9, true}, Case{640, 700, 4, 0, true}, Case{333, 999, 2, 1, true},
        Case{2000, 500, 1, 6, false}}) {
    ImageU8 im(k.w, k.h, k.nc);
    for (auto& v : im.data()) v = k.noise ? static_cast<uint8_t>(rng() & 0x3f) : 200;
    const fs::path path = dir / "map.png";
    WritePng8Unfiltered(path, im, k.level);
    const ImageU8 back = DecodeWithLibpng(path);
    ASSERT_EQ(back.width(), k.w);
    ASSERT_EQ(back.height(), k.h);
    ASSERT_EQ(back.channels(), k.nc);
    EXPECT_EQ(back.data(), im.data()) << k.w << "x" << k.h << "x" << k.nc << " level " << k.level;
  }
}

TEST(PngWrite, WritePng8UnfilteredRowsTakeThisPath) {
  // WritePng8(..., filter_rows = false) writes through WritePng8Unfiltered: same samples.
  const fs::path path = TestTempDir("png_write_test", "write_png8") / "map.png";
  ImageU8 im(513, 257, 3);
  std::mt19937 rng(3);
  for (auto& v : im.data()) v = static_cast<uint8_t>(rng());
  WritePng8(path, im, 1, /*filter_rows=*/false);
  EXPECT_EQ(DecodeWithLibpng(path).data(), im.data());
}

}  // namespace
}  // namespace mesoscan
