#pragma once
// OpenImageIO behind a module loaded on first use (core/module.h: libmesoscan_oiio.so, built
// from core/oiio_module.cc). Everything mesoscan does through OIIO goes through this interface,
// which names no OIIO type: the executable and the core library do not link OpenImageIO, so a
// process that never calls Oiio() (e.g. `mesoscan reconstruct` on PNG frames) never loads its
// 262-library tree. The wrappers with checks and one-line errors are in core/image_io.h and
// core/image_input.h; use those.

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace mesoscan {

// A pixel type as OIIO's TypeDesc base types (kOther: any other, e.g. half or uint32).
enum class PixelType { kUInt8, kUInt16, kHalf, kFloat, kOther };

// A header attribute for writing (or a reader's configuration): a number, a string, or a
// rational (numerator / denominator).
struct ImageAttribute {
  enum class Kind { kInt, kFloat, kString, kRational } kind = Kind::kFloat;
  std::string name;
  double number = 0;
  std::string text;
  int rational[2] = {0, 1};

  static ImageAttribute Int(std::string name, int v) {
    return {Kind::kInt, std::move(name), double(v), {}, {0, 1}};
  }
  static ImageAttribute Float(std::string name, double v) {
    return {Kind::kFloat, std::move(name), v, {}, {0, 1}};
  }
  static ImageAttribute String(std::string name, std::string v) {
    return {Kind::kString, std::move(name), 0, std::move(v), {0, 1}};
  }
  static ImageAttribute Rational(std::string name, int num, int den) {
    return {Kind::kRational, std::move(name), 0, {}, {num, den}};
  }
};

// What a reader knows after open().
struct ImageHeader {
  int width = 0, height = 0, channels = 0;
  PixelType format = PixelType::kOther;  // the file's (first channel's) type
  int format_bytes = 0;                  // bytes per sample of `format`
  bool is_float = false;
  int bits_per_sample_hint = 0;  // "oiio:BitsPerSample" (e.g. 12 in 16), 0 if absent
  std::vector<std::string> channel_names;
  std::map<std::string, double> numeric_attributes;  // int, float and double attributes
  std::string format_name;                           // OIIO's, e.g. "png", "openexr"
};

// An open image.
class ImageReader {
 public:
  virtual ~ImageReader() = default;
  virtual const ImageHeader& header() const = 0;
  // Every pixel of the first subimage as `type`, interleaved (width x height x channels
  // values). OIIO's read_image converts types through a buffer of 256 scan lines whatever the
  // image's height (1.6 GB for a 6-line EXR 524,296 pixels wide, found by fuzz_scan_folder):
  // a scan-line file of the requested type is read straight into `data`, another type is
  // converted in strips of at most 64 MB. Returns false with error() set.
  virtual bool Read(PixelType type, void* data) = 0;
  // OIIO's plain read_image of all channels as `type` (the camera raw reader's).
  virtual bool ReadWhole(PixelType type, void* data) = 0;
  // The reader's last error, on one line.
  virtual std::string error() = 0;
};

// One image to write: interleaved samples of `type`.
struct ImageToWrite {
  ImageToWrite(int w, int h, int c, PixelType t, const void* d = nullptr)
      : width(w), height(h), channels(c), type(t), data(d) {}
  int width = 0, height = 0, channels = 0;
  PixelType type = PixelType::kUInt8;
  const void* data = nullptr;
  std::vector<std::string> channel_names;  // empty: OIIO's defaults
  bool no_alpha = false;                   // no channel is alpha (spec.alpha_channel = -1)
  std::vector<ImageAttribute> attributes;
};

class OiioModule {
 public:
  virtual ~OiioModule() = default;
  // Opens `path` with the reader named `format` (an extension such as "png", or "raw"), with
  // optional configuration attributes. nullptr with *error set (one line) if no reader or the
  // open fails; *no_reader tells which.
  virtual std::unique_ptr<ImageReader> Open(const std::string& path, const std::string& format,
                                            const std::vector<ImageAttribute>& config,
                                            std::string* error, bool* no_reader) const = 0;
  // Writes `images` to `path` with the writer `format` names ("" : the one its extension
  // names; more than one image: a multi-image file, e.g. an animated GIF). False with *error.
  virtual bool Write(const std::string& path, const std::string& format,
                     const std::vector<ImageToWrite>& images, std::string* error) const = 0;
  // Encodes `images` in memory with the writer `format` names (an extension: "png", "exr"),
  // for core/fs.h's checked writes. False with *error; *no_memory_writer set if that writer
  // cannot write to memory (write a file with Write() and verify it instead).
  virtual bool Encode(const std::string& format, const std::vector<ImageToWrite>& images,
                      std::vector<unsigned char>* bytes, std::string* error,
                      bool* no_memory_writer) const = 0;
  // A global string attribute of OIIO (e.g. "library_list"); its version string.
  virtual std::string GlobalAttribute(const std::string& name) const = 0;
  virtual std::string Version() const = 0;
};

// The module, loaded on the first call. Throws Error(kInternal) if it cannot be loaded.
const OiioModule& Oiio();

// Writes `images` to `path` through the module (format "": the extension's writer), encoded in
// memory and written by core/fs.h's checked writer (a writer without a memory mode: its file is
// read back before it is renamed into place). Throws Error naming the file.
void WriteImagesChecked(const std::filesystem::path& path, const std::string& format,
                        const std::vector<ImageToWrite>& images);

}  // namespace mesoscan
