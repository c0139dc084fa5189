#include "core/scan_folder.h"

#include <tbb/parallel_invoke.h>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/output_dir.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {
// The scan folder's EXRs are written uncompressed (WriteExrPlanes): ZIP saves ~20 % on this noisy
// float data but costs ~2.5 s of CPU per full-resolution scan, more than the reconstruction
// itself (the end-to-end goal). Readers take any EXR compression; `mesoscan export`
// compresses its files.

std::map<std::string, double> GridAttributes(const HeightField& hf) {
  return {{kAttrX0, hf.x0}, {kAttrY0, hf.y0}, {kAttrPixelSize, hf.pixel_size}};
}

void ReadGridAttributes(const fs::path& path, const std::map<std::string, double>& attrs,
                        HeightField* hf) {
  for (const char* key : {kAttrX0, kAttrY0, kAttrPixelSize}) {
    if (!attrs.count(key))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "missing header attribute '" << key << "'");
  }
  hf->x0 = attrs.at(kAttrX0);
  hf->y0 = attrs.at(kAttrY0);
  hf->pixel_size = attrs.at(kAttrPixelSize);
  if (!(hf->pixel_size > 0) || !std::isfinite(hf->pixel_size))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "header attribute '"
                                                     << kAttrPixelSize
                                                     << "': expected a positive number");
}

ImageF Plane(const ImageF& all, int c0, int n) {
  ImageF out(all.width(), all.height(), n);
  for (int k = 0; k < n; ++k)
    std::copy(all.channel(c0 + k), all.channel(c0 + k) + all.pixels(), out.channel(k));
  return out;
}
}  // namespace

void WritePointsExr(const fs::path& path, const ScanPoints& p) {
  // Straight from the planes (no stacked or interleaved copy: 75 MB at full resolution).
  std::vector<ExrPlane> planes = {{"X", &p.xyz, 0},
                                  {"Y", &p.xyz, 1},
                                  {"Z", &p.xyz, 2},
                                  {"confidence", &p.confidence},
                                  {"projector_u", &p.projector_u}};
  if (!p.source.empty()) planes.push_back({"source", &p.source});
  WriteExrPlanes(path, planes);
}

ScanPoints ReadPointsExr(const fs::path& path) {
  try {  // `source` is optional (scan-outputs.md)
    ImageF all = ReadExrChannels(path, {"X", "Y", "Z", "confidence", "projector_u", "source"});
    return {Plane(all, 0, 3), Plane(all, 3, 1), Plane(all, 4, 1), Plane(all, 5, 1)};
  } catch (const Error&) {
  }
  ImageF all = ReadExrChannels(path, {"X", "Y", "Z", "confidence", "projector_u"});
  return {Plane(all, 0, 3), Plane(all, 3, 1), Plane(all, 4, 1), ImageF()};
}

void WriteHeightExr(const fs::path& path, const HeightField& hf) {
  ImageF own_conf;
  if (hf.confidence.empty()) {
    own_conf = ImageF(hf.width(), hf.height(), 1, 0.0f);
    for (size_t i = 0; i < own_conf.pixels(); ++i)
      own_conf.data()[i] = std::isfinite(hf.z.data()[i]) ? 1.0f : 0.0f;
  }
  const ImageF& conf = hf.confidence.empty() ? own_conf : hf.confidence;
  WriteExrPlanes(path, {{"Z", &hf.z}, {"confidence", &conf}}, GridAttributes(hf));
}

HeightField ReadHeightExr(const fs::path& path) {
  std::map<std::string, double> attrs;
  ImageF all = ReadExrChannels(path, {"Z", "confidence"}, &attrs);
  HeightField hf;
  hf.z = Plane(all, 0, 1);
  hf.confidence = Plane(all, 1, 1);
  ReadGridAttributes(path, attrs, &hf);
  return hf;
}

void WriteNormalExr(const fs::path& path, const HeightField& grid, const ImageF& n) {
  MESOSCAN_CHECK_EQ(n.channels(), 3);
  WriteExrPlanes(path, {{"X", &n, 0}, {"Y", &n, 1}, {"Z", &n, 2}}, GridAttributes(grid));
}

void WriteScanFolder(const fs::path& dir, const Scan& scan) {
  WriteFolderAtomically(dir, [&](const fs::path& tmp) {
    // The three EXRs in parallel (each is compressed on one thread); then the report.
    tbb::parallel_invoke([&] { WritePointsExr(tmp / "points.exr", scan.points); },
                         [&] { WriteHeightExr(tmp / "height.exr", scan.height); },
                         [&] {
                           WriteNormalExr(
                               tmp / "normal.exr", scan.height,
                               scan.normals.empty() ? scan.height.Normals() : scan.normals);
                         });
    WriteJsonFile(tmp / "report.json", scan.report);
  });
}

Scan ReadScanFolder(const fs::path& dir) {
  RestoreInterruptedReplacement(dir);
  if (!fs::is_directory(dir))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(dir), "not a scan folder (no such directory)");
  Scan s;
  s.points = ReadPointsExr(dir / "points.exr");
  s.height = ReadHeightExr(dir / "height.exr");
  s.normals = ReadExrChannels(dir / "normal.exr", {"X", "Y", "Z"});
  if (fs::exists(dir / "report.json")) s.report = ReadJsonFile(dir / "report.json");
  return s;
}

}  // namespace mesoscan
