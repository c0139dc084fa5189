#include "session/raw_frame.h"

#include <libraw/libraw.h>
#include <tiffio.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <set>

#include "core/error.h"
#include "core/fs.h"

namespace mesoscan {
namespace {

constexpr uint16_t kPhotometricCfa = 32803;

std::string OneLine(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

// libtiff reports through global handlers; silence them (errors are reported by return codes).
void SilentTiffHandler(const char*, const char*, va_list) {}

struct TiffCloser {
  void operator()(TIFF* t) const {
    if (t) TIFFClose(t);
  }
};

// A LibRaw handle with the file opened and unpacked; throws Error(kBadInput) naming `who`.
std::unique_ptr<LibRaw> OpenRaw(const std::filesystem::path& path, const std::string& who) {
  auto raw = std::make_unique<LibRaw>();
  int rc = raw->open_file(path.c_str());
  if (rc == LIBRAW_SUCCESS) rc = raw->unpack();
  if (rc != LIBRAW_SUCCESS)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who), "cannot read camera raw (LibRaw: "
                                                    << OneLine(libraw_strerror(rc)) << ")");
  if (!raw->imgdata.rawdata.raw_image)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who),
                          "cannot read camera raw (not a one-channel sensor mosaic: LibRaw found "
                              << raw->imgdata.idata.colors << " colours per pixel)");
  if (raw->imgdata.sizes.width < 2 || raw->imgdata.sizes.height < 2)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who), "cannot read camera raw (empty visible area)");
  return raw;
}

// Black level of the visible pixel (x, y), in sensor codes, as LibRaw documents it: the common
// black, the per-colour black and the repeating black pattern (cblack[4] rows x cblack[5] columns
// from cblack[6]).
double BlackAt(LibRaw& raw, int x, int y) {
  const libraw_colordata_t& c = raw.imgdata.color;
  double b = c.black + c.cblack[raw.COLOR(y, x) & 3];
  const unsigned rows = c.cblack[4], cols = c.cblack[5];
  if (rows > 0 && cols > 0 && rows * cols <= 4096)
    b += c.cblack[6 + (static_cast<unsigned>(y) % rows) * cols + static_cast<unsigned>(x) % cols];
  return b;
}

RawLevels LevelsOf(LibRaw& raw) {
  RawLevels levels;
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 2; ++x) levels.black[y * 2 + x] = BlackAt(raw, x, y);
  levels.white = raw.imgdata.color.maximum;
  levels.from_file = true;
  return levels;
}

ImageU16 MosaicOf(LibRaw& raw) {
  const libraw_image_sizes_t& sz = raw.imgdata.sizes;
  ImageU16 mosaic(sz.width, sz.height);
  const size_t pitch = sz.raw_pitch / sizeof(uint16_t);
  for (int y = 0; y < sz.height; ++y) {
    const uint16_t* src =
        raw.imgdata.rawdata.raw_image + (y + sz.top_margin) * pitch + sz.left_margin;
    std::copy(src, src + sz.width, mosaic.row(y));
  }
  return mosaic;
}

void CheckLevels(const RawLevels& levels, const std::string& who) {
  const double max_black = *std::max_element(levels.black.begin(), levels.black.end());
  if (!(levels.white > max_black))
    MESOSCAN_BAD_INPUT(who << ": camera raw white level " << levels.white
                           << " is not above the black level " << max_black);
}

}  // namespace

bool IsCameraRawPath(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  static const std::set<std::string> kRaw = {".nef", ".nrw", ".cr2", ".cr3", ".crw", ".dng",
                                             ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw"};
  return kRaw.count(ext) > 0;
}

RawLevels ReadRawLevels(const std::filesystem::path& path, const std::string& label) {
  const std::string who = label.empty() ? path.string() : label;
  auto raw = OpenRaw(path, who);
  return LevelsOf(*raw);
}

ImageU16 ReadRawMosaic(const std::filesystem::path& path, const std::string& label) {
  const std::string who = label.empty() ? path.string() : label;
  auto raw = OpenRaw(path, who);
  return MosaicOf(*raw);
}

ImageU16 ReadRawGrey(const std::filesystem::path& path, const std::string& label) {
  const std::string who = label.empty() ? path.string() : label;
  auto raw = OpenRaw(path, who);
  const ImageU16 mosaic = MosaicOf(*raw);
  const RawLevels levels = LevelsOf(*raw);
  raw.reset();
  CheckLevels(levels, who);
  const double black =
      (levels.black[0] + levels.black[1] + levels.black[2] + levels.black[3]) / 4.0;
  const double scale = 65535.0 / (levels.white - black);
  const int w = mosaic.width() / 2, h = mosaic.height() / 2;
  ImageU16 grey(w, h);
  // Sum of the four sensor codes minus the four black levels, times scale / 4.
  const double black_sum = 4.0 * black, gain = scale / 4.0;
  for (int y = 0; y < h; ++y) {
    const uint16_t* r0 = mosaic.row(2 * y);
    const uint16_t* r1 = mosaic.row(2 * y + 1);
    uint16_t* out = grey.row(y);
    for (int x = 0; x < w; ++x) {
      const double sum = double(r0[2 * x]) + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1];
      const double v = std::round((sum - black_sum) * gain);
      out[x] = static_cast<uint16_t>(std::clamp(v, 0.0, 65535.0));
    }
  }
  return grey;
}

ImageF ReadRawColour(const std::filesystem::path& path, const std::string& label) {
  const std::string who = label.empty() ? path.string() : label;
  auto raw = OpenRaw(path, who);
  if (raw->imgdata.idata.colors != 3)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who), "cannot demosaic camera raw ("
                                                    << raw->imgdata.idata.colors
                                                    << " colour filters, expected R, G, B)");
  const ImageU16 mosaic = MosaicOf(*raw);
  const RawLevels levels = LevelsOf(*raw);
  CheckLevels(levels, who);
  // Colour (0 R, 1 G, 2 B; LibRaw's 3 is the second green) and black of each cell position.
  std::array<int, 4> colour{};
  std::array<int, 3> count{};
  for (int i = 0; i < 4; ++i) {
    const int c = raw->COLOR(i / 2, i % 2) & 3;
    colour[i] = c == 3 ? 1 : c;
    ++count[colour[i]];
  }
  raw.reset();
  if (count[0] == 0 || count[1] == 0 || count[2] == 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who),
                          "cannot demosaic camera raw (its 2x2 cell lacks one of R, G, B)");
  const double black =
      (levels.black[0] + levels.black[1] + levels.black[2] + levels.black[3]) / 4.0;
  const double scale = 1.0 / (levels.white - black);
  const int w = mosaic.width() / 2, h = mosaic.height() / 2;
  ImageF rgb(w, h, 3, 0.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      std::array<double, 3> sum{};
      for (int i = 0; i < 4; ++i)
        sum[colour[i]] += mosaic(2 * x + i % 2, 2 * y + i / 2) - levels.black[i];
      for (int c = 0; c < 3; ++c)
        rgb(x, y, c) = static_cast<float>(std::max(0.0, sum[c] / count[c] * scale));
    }
  return rgb;
}

void WriteCfaDng(const std::filesystem::path& path, const ImageU16& mosaic, const RawLevels& levels,
                 std::array<uint8_t, 4> cfa) {
  MESOSCAN_CHECK(mosaic.channels() == 1 && mosaic.width() % 2 == 0 && mosaic.height() % 2 == 0);
  // libtiff writes the file itself (it checks its writes); the file is also checked to hold at
  // least the mosaic's bytes before it is renamed into place.
  const uintmax_t min_bytes = static_cast<uintmax_t>(mosaic.width()) * mosaic.height() * 2;
  WriteAtomicallyVerified(
      path,
      [&](const std::filesystem::path& tmp) {
        TIFFSetErrorHandler(SilentTiffHandler);
        TIFFSetWarningHandler(SilentTiffHandler);
        std::unique_ptr<TIFF, TiffCloser> tif(TIFFOpen(tmp.c_str(), "w"));
        if (!tif) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot create DNG");
        TIFF* t = tif.get();
        const uint32_t w = mosaic.width(), h = mosaic.height();
        TIFFSetField(t, TIFFTAG_SUBFILETYPE, 0);
        TIFFSetField(t, TIFFTAG_IMAGEWIDTH, w);
        TIFFSetField(t, TIFFTAG_IMAGELENGTH, h);
        TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, 16);
        TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, 1);
        TIFFSetField(t, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
        TIFFSetField(t, TIFFTAG_PHOTOMETRIC, kPhotometricCfa);
        TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        TIFFSetField(t, TIFFTAG_ORIENTATION, ORIENTATION_TOPLEFT);
        TIFFSetField(t, TIFFTAG_ROWSPERSTRIP, h);
        TIFFSetField(t, TIFFTAG_MAKE, "mesoscan");
        TIFFSetField(t, TIFFTAG_MODEL, "simulated camera");
        TIFFSetField(t, TIFFTAG_SOFTWARE, "mesoscan");
        const uint16_t repeat[2] = {2, 2};
        TIFFSetField(t, TIFFTAG_CFAREPEATPATTERNDIM, repeat);
        TIFFSetField(t, TIFFTAG_CFAPATTERN, 4, cfa.data());
        const uint8_t dng_version[4] = {1, 4, 0, 0};
        const uint8_t dng_backward[4] = {1, 1, 0, 0};
        TIFFSetField(t, TIFFTAG_DNGVERSION, dng_version);
        TIFFSetField(t, TIFFTAG_DNGBACKWARDVERSION, dng_backward);
        TIFFSetField(t, TIFFTAG_UNIQUECAMERAMODEL, "mesoscan simulated camera");
        TIFFSetField(t, TIFFTAG_BLACKLEVELREPEATDIM, repeat);
        // BlackLevel is ordered row by row over the repeat pattern: (0,0) (1,0) (0,1) (1,1).
        float black[4];
        for (int i = 0; i < 4; ++i) black[i] = static_cast<float>(levels.black[i]);
        TIFFSetField(t, TIFFTAG_BLACKLEVEL, 4, black);
        const uint32_t white = static_cast<uint32_t>(levels.white);
        TIFFSetField(t, TIFFTAG_WHITELEVEL, 1, &white);
        const float color_matrix[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // XYZ -> camera, neutral
        TIFFSetField(t, TIFFTAG_COLORMATRIX1, 9, color_matrix);
        const float as_shot_neutral[3] = {1, 1, 1};
        TIFFSetField(t, TIFFTAG_ASSHOTNEUTRAL, 3, as_shot_neutral);
        for (uint32_t y = 0; y < h; ++y)
          if (TIFFWriteScanline(t, const_cast<uint16_t*>(mosaic.row(static_cast<int>(y))), y, 0) <
              0)
            MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write DNG row " << y);
        if (!TIFFWriteDirectory(t))
          MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write DNG");
      },
      min_bytes, nullptr);
}

std::string LibRawVersion() { return libraw_version(); }

}  // namespace mesoscan
