#include "session/raw_frame.h"

#include <tiffio.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "core/error.h"
#include "core/fs.h"
#include "core/oiio_module.h"

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

bool IsRawIfd(TIFF* tif) {
  uint32_t subfile = 0;
  uint16_t photometric = 0;
  TIFFGetFieldDefaulted(tif, TIFFTAG_SUBFILETYPE, &subfile);
  if (!TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &photometric)) return false;
  return subfile == 0 && photometric == kPhotometricCfa;
}

RawLevels LevelsOfIfd(TIFF* tif) {
  RawLevels levels;
  uint16_t* repeat = nullptr;  // BlackLevelRepeatDim: rows, columns
  int rows = 1, cols = 1;
  if (TIFFGetField(tif, TIFFTAG_BLACKLEVELREPEATDIM, &repeat) && repeat) {
    rows = std::max<int>(1, repeat[0]);
    cols = std::max<int>(1, repeat[1]);
  }
  uint16_t n = 0;
  float* black = nullptr;
  if (TIFFGetField(tif, TIFFTAG_BLACKLEVEL, &n, &black) && black && n > 0) {
    // Black level of cell position (x, y): the repeat pattern's entry (y % rows, x % cols); a
    // single value applies everywhere.
    for (int y = 0; y < 2; ++y)
      for (int x = 0; x < 2; ++x) {
        const int i = (y % rows) * cols + (x % cols);
        levels.black[y * 2 + x] = black[i < n ? i : 0];
      }
    levels.from_file = true;
  }
  uint32_t* white = nullptr;
  if (TIFFGetField(tif, TIFFTAG_WHITELEVEL, &n, &white) && white && n > 0) {
    levels.white = white[0];
    levels.from_file = true;
  } else {
    uint16_t bits = 16;
    TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
    levels.white = std::ldexp(1.0, bits) - 1.0;
  }
  return levels;
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

RawLevels ReadRawLevels(const std::filesystem::path& path) {
  TIFFSetErrorHandler(SilentTiffHandler);
  TIFFSetWarningHandler(SilentTiffHandler);
  std::unique_ptr<TIFF, TiffCloser> tif(TIFFOpen(path.c_str(), "r"));
  if (!tif) return {};  // not TIFF-based (e.g. .cr3, .raf): levels unknown here
  uint8_t* dng_version = nullptr;
  if (!TIFFGetField(tif.get(), TIFFTAG_DNGVERSION, &dng_version)) return {};
  if (IsRawIfd(tif.get())) return LevelsOfIfd(tif.get());
  // The raw image of a DNG with a preview in IFD 0 lives in a SubIFD.
  uint16_t count = 0;
  uint64_t* offsets = nullptr;
  if (!TIFFGetField(tif.get(), TIFFTAG_SUBIFD, &count, &offsets) || !offsets) return {};
  const std::vector<uint64_t> subifds(offsets, offsets + count);
  for (uint64_t off : subifds) {
    if (!TIFFSetSubDirectory(tif.get(), off)) continue;
    if (IsRawIfd(tif.get())) return LevelsOfIfd(tif.get());
  }
  return {};
}

ImageU16 ReadRawMosaic(const std::filesystem::path& path, const std::string& label) {
  const std::string who = label.empty() ? path.string() : label;
  // The raw plugin explicitly: a DNG is also a valid TIFF, and OIIO's TIFF reader would claim it.
  std::string err;
  bool no_reader = false;
  auto in = Oiio().Open(path.string(), "raw", {ImageAttribute::String("raw:Demosaic", "none")},
                        &err, &no_reader);
  if (no_reader)
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(who),
        "cannot read camera raw (OpenImageIO has no raw plugin: " << OneLine(err) << ")");
  if (!in)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who), "cannot read camera raw (" << OneLine(err) << ")");
  const ImageHeader& spec = in->header();
  if (spec.channels != 1)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who),
                          "cannot read camera raw (LibRaw returned "
                              << spec.channels
                              << " channels, expected the 1-channel sensor mosaic)");
  ImageU16 mosaic(spec.width, spec.height);
  if (!in->ReadWhole(PixelType::kUInt16, mosaic.data().data()))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(who),
                          "cannot read camera raw (" << OneLine(in->error()) << ")");
  return mosaic;
}

ImageU16 ReadRawGrey(const std::filesystem::path& path, const std::string& label) {
  const ImageU16 mosaic = ReadRawMosaic(path, label);
  const RawLevels levels = ReadRawLevels(path);
  const double black =
      (levels.black[0] + levels.black[1] + levels.black[2] + levels.black[3]) / 4.0;
  const double max_black = *std::max_element(levels.black.begin(), levels.black.end());
  if (!(levels.white > max_black))
    MESOSCAN_BAD_INPUT((label.empty() ? path.string() : label)
                       << ": camera raw white level " << levels.white
                       << " is not above the black level " << max_black);
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

std::string LibRawVersion() {
  // OIIO lists it as "raw:libraw 0.20.2-Release".
  const std::string list = Oiio().GlobalAttribute("library_list");
  // "name:version;name:version ..."; the raw plugin's entry is "raw:LibRaw 0.20.2".
  for (size_t start = 0; start < list.size();) {
    size_t end = list.find(';', start);
    if (end == std::string::npos) end = list.size();
    const std::string entry = list.substr(start, end - start);
    if (entry.rfind("raw:", 0) == 0) {
      const std::string v = entry.substr(4);
      const size_t space = v.find(' ');
      return space == std::string::npos ? v : v.substr(space + 1);
    }
    start = end + 1;
  }
  return "";
}

}  // namespace mesoscan
