// libFuzzer: the scan-folder reader (core/scan_folder.h ReadScanFolder): the input replaces
// the height.exr of an otherwise valid scan folder written once at start-up, or, if it starts
// with '{', its report.json.
#include "core/fs.h"
#include "core/scan_folder.h"
#include "fuzz/fuzz_util.h"

namespace {

mesoscan::Scan SmallScan() {
  using namespace mesoscan;
  Scan s;
  s.points.xyz = ImageF(4, 3, 3, 0.0f);
  s.points.confidence = ImageF(4, 3, 1, 1.0f);
  s.points.projector_u = ImageF(4, 3, 1, 0.5f);  // same size as xyz (WriteScanFolder checks it)
  s.height.z = ImageF(4, 3, 1, 0.0f);
  s.height.confidence = ImageF(4, 3, 1, 1.0f);
  s.height.pixel_size = 1e-5;
  s.normals = ImageF(4, 3, 3, 0.0f);
  return s;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mesoscan;
  namespace fs = std::filesystem;
  static const fs::path pristine = [] {
    const auto d = fuzz::WorkDir() / "scan_pristine";
    WriteScanFolder(d, SmallScan());
    WriteTextFile(d / "report.json", "{}");
    return d;
  }();
  const fs::path dir = fuzz::WorkDir() / "scan";
  fs::remove_all(dir);
  fs::copy(pristine, dir);
  const bool json = size > 0 && data[0] == '{';
  fuzz::WriteInput(json ? "scan/report.json" : "scan/height.exr", data, size);
  fuzz::Expect([&] { (void)ReadScanFolder(dir); });
  return 0;
}
