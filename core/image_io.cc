#include "core/image_io.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFloatAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfTestFile.h>
#include <OpenEXR/ImfThreading.h>
#include <OpenEXR/openexr.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

#include "core/budget.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_input.h"
#include "core/module.h"
#include "core/png_gray16.h"
#include "core/png_write.h"

MESOSCAN_DECLARE_MODULE(oiio);

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

ImageInfo InfoFromHeader(const ImageHeader& h) {
  ImageInfo info;
  info.width = h.width;
  info.height = h.height;
  info.channels = h.channels;
  info.bits_per_sample = h.format_bytes * 8;
  info.is_float = h.is_float;
  info.channel_names = h.channel_names;
  info.float_attributes = h.numeric_attributes;
  // The PNG/TIFF "oiio:BitsPerSample" hint (e.g. 12 bits in 16) is reported if present.
  if (h.bits_per_sample_hint > 0) info.bits_per_sample = h.bits_per_sample_hint;
  return info;
}

std::unique_ptr<ImageReader> OpenInput(const fs::path& path) { return OpenImageInput(path); }

// Interleaved -> planar.
void Deinterleave(const std::vector<float>& inter, ImageF* out) {
  const int nc = out->channels();
  const size_t n = out->pixels();
  for (int c = 0; c < nc; ++c) {
    float* dst = out->channel(c);
    for (size_t i = 0; i < n; ++i) dst[i] = inter[i * nc + c];
  }
}

template <typename T>
std::vector<T> Interleave(const Image<T>& im) {
  const int nc = im.channels();
  const size_t n = im.pixels();
  std::vector<T> inter(n * nc);
  for (int c = 0; c < nc; ++c) {
    const T* src = im.channel(c);
    for (size_t i = 0; i < n; ++i) inter[i * nc + c] = src[i];
  }
  return inter;
}

// OpenEXR's output stream over a CheckedFile (every write checked, errors named).
class CheckedExrStream final : public Imf::OStream {
 public:
  explicit CheckedExrStream(CheckedFile* file) : Imf::OStream(file->label().c_str()), f_(file) {}
  void write(const char c[], int n) override { f_->Write(c, static_cast<size_t>(n)); }
  uint64_t tellp() override { return f_->Tell(); }
  void seekp(uint64_t pos) override { f_->Seek(pos); }

 private:
  CheckedFile* f_;
};

void WriteWithOiio(const fs::path& path, ImageToWrite image) {
  WriteImagesChecked(path, "", {std::move(image)});
}

}  // namespace

const OiioModule& Oiio() {
  static const OiioModule* const module = static_cast<const OiioModule*>(MESOSCAN_MODULE(oiio));
  return *module;
}

void WriteImagesChecked(const fs::path& path, const std::string& format,
                        const std::vector<ImageToWrite>& images) {
  std::string fmt = format;
  if (fmt.empty()) {
    fmt = path.extension().string();
    if (!fmt.empty() && fmt[0] == '.') fmt = fmt.substr(1);
  }
  std::vector<unsigned char> bytes;
  std::string err;
  bool no_memory_writer = false;
  if (Oiio().Encode(fmt, images, &bytes, &err, &no_memory_writer)) {
    WriteBytesFile(path, bytes.data(), bytes.size());
    return;
  }
  if (!no_memory_writer)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write image (" << err << ")");
  // A writer that writes files only: the file is read back whole before it is renamed into
  // place (a write it did not check shows as a file that does not decode).
  WriteAtomicallyVerified(
      path,
      [&](const fs::path& tmp) {
        if (!Oiio().Write(tmp.string(), fmt, images, &err))
          MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write image (" << err << ")");
      },
      1,
      [&](const fs::path& tmp) {
        std::string e2;
        bool no_reader = false;
        auto in = Oiio().Open(tmp.string(), fmt, {}, &e2, &no_reader);
        if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write image (" << e2 << ")");
        const ImageHeader& h = in->header();
        std::vector<float> all(static_cast<size_t>(h.width) * h.height * h.channels);
        if (!in->Read(PixelType::kFloat, all.data()))
          MESOSCAN_BAD_INPUT_AT(
              ErrorSite::File(path),
              "cannot write image (written file does not read back: " << in->error() << ")");
      });
}

// Only regular files are opened (a FIFO or a device would block or never end), with the reader
// the file's extension names (OIIO's open() otherwise tries every format in turn, e.g. DICOM
// on a zero-filled .png), and the header's size is checked against the file size and the memory
// budget before anything is decoded.
void CheckRegularFile(const fs::path& path, const std::string& label_in) {
  const std::string label = label_in.empty() ? path.string() : label_in;
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec && ec != std::errc::no_such_file_or_directory)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "cannot open (" << ec.message() << ")");
  if (!fs::exists(st)) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "file not found");
  if (!fs::is_regular_file(st))
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(label),
        "expected a regular image file, got "
            << (fs::is_directory(st)                                 ? "a folder"
                : fs::is_fifo(st)                                    ? "a FIFO"
                : fs::is_character_file(st) || fs::is_block_file(st) ? "a device"
                                                                     : "a special file"));
}

// OpenEXR's C++ reader (behind OpenImageIO) trusts the sizes in a header: a 651-byte file whose
// string attribute claims 1.9 GB made it allocate and clear that much before failing (seconds, and
// over the fuzzer's 10-s limit under load; found by fuzz_frame), and a data window far larger than
// the file makes it allocate and read the whole chunk offset table. OpenEXR's core C API checks
// attribute sizes and reads the headers alone: a file it refuses is refused with its first
// message, and the chunk tables (8 bytes a chunk) must fit in the file before the C++ reader
// sees it.
void CheckExrHeader(const fs::path& path, const std::string& label) {
  std::string first_error;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.user_data = &first_error;
  init.error_handler_fn = [](exr_const_context_t ctx, exr_result_t, const char* msg) {
    void* user = nullptr;
    if (exr_get_user_data(ctx, &user) == EXR_ERR_SUCCESS && user) {
      auto* err = static_cast<std::string*>(user);
      if (err->empty() && msg) *err = msg;
    }
  };
  exr_context_t ctx = nullptr;
  const exr_result_t rc = exr_start_read(&ctx, path.c_str(), &init);
  int parts = 0;
  double chunks = 0;
  if (rc == EXR_ERR_SUCCESS && exr_get_count(ctx, &parts) == EXR_ERR_SUCCESS)
    for (int p = 0; p < parts; ++p) {
      int32_t n = 0;
      if (exr_get_chunk_count(ctx, p, &n) == EXR_ERR_SUCCESS) chunks += n;
    }
  exr_finish(&ctx);
  // The core reports some header errors and still succeeds: an attribute of a type it does not
  // know whose size runs past the end of the file is skipped with a message, while the C++
  // reader allocates that size first (fuzz_scan_folder: 1.7-20 GB for a 580-byte file).
  if (rc != EXR_ERR_SUCCESS || !first_error.empty()) {
    std::string why = first_error.empty() ? exr_get_default_error_message(rc) : first_error;
    // The core's messages start with the file name; the label says which file already.
    const std::string prefix = path.string() + ": ";
    if (why.rfind(prefix, 0) == 0) why = why.substr(prefix.size());
    std::replace(why.begin(), why.end(), '\n', ' ');
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                          "cannot read image (not a valid EXR header: " << why << ")");
  }
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  if (!ec && chunks * 8.0 > static_cast<double>(size))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                          "cannot read image (its header declares "
                              << chunks
                              << " chunks, whose offset table alone needs more than the file's "
                              << size << " bytes)");
}

void CheckImageBudget(const std::string& label, int width, int height, int channels) {
  CheckMemoryBudget("a " + std::to_string(width) + "x" + std::to_string(height) + "x" +
                        std::to_string(channels) + " image",
                    static_cast<double>(width) * height * channels * 8.0, ErrorKind::kBadInput,
                    ErrorSite::File(label));
}

std::unique_ptr<ImageReader> OpenImageInput(const fs::path& path, const std::string& label_in) {
  const std::string label = label_in.empty() ? path.string() : label_in;
  CheckRegularFile(path, label);
  std::error_code ec;
  std::string ext = path.extension().string();
  if (!ext.empty()) ext = ext.substr(1);
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == "exr") CheckExrHeader(path, label);
  std::string err;
  bool no_reader = false;
  auto in = Oiio().Open(path.string(), ext, {}, &err, &no_reader);
  if (no_reader)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                          "cannot read image (no reader for the extension '." << ext << "')");
  if (!in) {
    if (err.empty()) err = "not a valid ." + ext + " file";
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "cannot read image (" << err << ")");
  }
  const ImageHeader& h = in->header();
  if (h.width <= 0 || h.height <= 0 || h.channels <= 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "header declares " << h.width << "x" << h.height
                                                                     << "x" << h.channels
                                                                     << " pixels");
  const double values = static_cast<double>(h.width) * h.height * h.channels;
  CheckImageBudget(label, h.width, h.height, h.channels);
  // No format we read stores more than ~2x its raw pixel size plus headers (EXR offset tables,
  // PNG filter bytes and chunks): a bigger file does not hold what its header says.
  const double raw = values * static_cast<double>(h.format_bytes);
  const auto size = fs::file_size(path, ec);
  if (!ec && static_cast<double>(size) > 2.0 * raw + (1 << 20))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "file is " << size << " bytes, more than its "
                                                             << h.width << "x" << h.height << "x"
                                                             << h.channels << " header allows");
  return in;
}

ImageInfo ReadImageInfo(const fs::path& path) { return InfoFromHeader(OpenInput(path)->header()); }

namespace {

// The checks OpenImageInput makes on a header, for the layouts read without it; false if the
// file is larger than its header allows (OpenImageInput then refuses it with its message).
bool LayoutFits(const fs::path& path, const ImageInfo& info) {
  const double values = static_cast<double>(info.width) * info.height * info.channels;
  CheckImageBudget(path.string(), info.width, info.height, info.channels);
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  return !ec && static_cast<double>(size) <= 2.0 * values * (info.bits_per_sample / 8) + (1 << 20);
}

bool ReadPngLayout(const fs::path& path, ImageInfo* info) {
  uint8_t head[kPngHeaderBytes];
  {
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
    if (!f || std::fread(head, 1, sizeof head, f.get()) != sizeof head) return false;
  }
  PngHeader header;
  if (!ParsePngHeader(head, &header)) return false;
  const uint32_t w = header.width, h = header.height;
  const int depth = header.bit_depth, colour = header.colour_type;
  static const char* const kNames[7][4] = {{"Y"},      {}, {"R", "G", "B"},     {},
                                           {"Y", "A"}, {}, {"R", "G", "B", "A"}};
  static const int kChannels[7] = {1, 0, 3, 0, 2, 0, 4};
  if (w == 0 || h == 0 || w > 0x7fffffffu || h > 0x7fffffffu || (depth != 8 && depth != 16) ||
      colour > 6 || kChannels[colour] == 0)
    return false;
  info->width = static_cast<int>(w);
  info->height = static_cast<int>(h);
  info->channels = kChannels[colour];
  info->bits_per_sample = depth;
  info->is_float = false;
  info->channel_names.assign(kNames[colour], kNames[colour] + info->channels);
  return true;
}

bool ReadExrLayout(const fs::path& path, ImageInfo* info) {
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = [](exr_const_context_t, exr_result_t, const char*) {};
  exr_context_t ctx = nullptr;
  bool ok = exr_start_read(&ctx, path.c_str(), &init) == EXR_ERR_SUCCESS;
  int parts = 0;
  exr_attr_box2i_t dw{};
  const exr_attr_chlist_t* channels = nullptr;
  ok = ok && exr_get_count(ctx, &parts) == EXR_ERR_SUCCESS && parts == 1 &&
       exr_get_data_window(ctx, 0, &dw) == EXR_ERR_SUCCESS &&
       exr_get_channels(ctx, 0, &channels) == EXR_ERR_SUCCESS && channels &&
       channels->num_channels > 0;
  int bits = 16;
  if (ok) {
    info->channel_names.clear();
    for (int c = 0; c < channels->num_channels; ++c) {
      const exr_attr_chlist_entry_t& e = channels->entries[c];
      ok = ok && e.x_sampling == 1 && e.y_sampling == 1 &&
           (e.pixel_type == EXR_PIXEL_HALF || e.pixel_type == EXR_PIXEL_FLOAT);
      if (e.pixel_type == EXR_PIXEL_FLOAT) bits = 32;
      info->channel_names.emplace_back(e.name.str, static_cast<size_t>(e.name.length));
    }
  }
  exr_finish(&ctx);
  const int64_t w = int64_t{dw.max.x} - dw.min.x + 1, h = int64_t{dw.max.y} - dw.min.y + 1;
  if (!ok || w <= 0 || h <= 0 || w > 0x7fffffff || h > 0x7fffffff) return false;
  info->width = static_cast<int>(w);
  info->height = static_cast<int>(h);
  info->channels = channels ? static_cast<int>(info->channel_names.size()) : 0;
  info->bits_per_sample = bits;
  info->is_float = true;
  return true;
}

}  // namespace

ImageInfo ReadImageLayout(const fs::path& path) {
  CheckRegularFile(path, path.string());
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  ImageInfo info;
  if (ext == ".png" && ReadPngLayout(path, &info) && LayoutFits(path, info)) return info;
  if (ext == ".exr") {
    CheckExrHeader(path, path.string());
    if (ReadExrLayout(path, &info) && LayoutFits(path, info)) return info;
  }
  return ReadImageInfo(path);
}

ImageF ReadImage(const fs::path& path, ImageInfo* info) {
  auto in = OpenInput(path);
  const ImageHeader& h = in->header();
  if (info) *info = InfoFromHeader(h);
  ImageF out(h.width, h.height, h.channels);
  std::vector<float> inter(out.pixels() * h.channels);
  if (!in->Read(PixelType::kFloat, inter.data())) {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot decode image (" << in->error() << ")");
  }
  Deinterleave(inter, &out);
  return out;
}

ImageF ReadImageGrey(const fs::path& path, ImageInfo* info) {
  ImageInfo local;
  ImageF im = ReadImage(path, &local);
  if (info) *info = local;
  if (im.channels() == 1) return im;
  // Grey = mean of the colour channels; an alpha channel is ignored.
  int nc = im.channels();
  if (nc == 2 || nc == 4) --nc;
  ImageF grey(im.width(), im.height(), 1);
  const size_t n = im.pixels();
  for (int c = 0; c < nc; ++c) {
    const float* src = im.channel(c);
    float* dst = grey.channel(0);
    for (size_t i = 0; i < n; ++i) dst[i] += src[i] / nc;
  }
  return grey;
}

bool ReadExrPlanes(const fs::path& path, const std::vector<std::string>& names,
                   const std::vector<std::string>& required, ImageF* image, ImageInfo* info) {
  const std::string file = path.string();
  if (!Imf::isOpenExrFile(file.c_str())) return false;
  try {
    Imf::InputFile in(file.c_str(), Imf::globalThreadCount());
    const Imf::ChannelList& channels = in.header().channels();
    for (const std::string& c : required)
      if (channels.findChannel(c) == nullptr)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(file), "missing channel '" << c << "'");
    std::vector<std::string> present;
    for (const std::string& c : names)
      if (channels.findChannel(c) != nullptr) present.push_back(c);
    const Imath::Box2i dw = in.header().dataWindow();
    const int64_t w = static_cast<int64_t>(dw.max.x) - dw.min.x + 1,
                  h = static_cast<int64_t>(dw.max.y) - dw.min.y + 1;
    if (w <= 0 || h <= 0 || w > (1 << 20) || h > (1 << 20))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(file),
                            "data window " << w << "x" << h << " is not an image size");
    CheckMemoryBudget("channels " + std::to_string(present.size()),
                      static_cast<double>(w) * h * present.size() * sizeof(float),
                      ErrorKind::kBadInput, ErrorSite::File(file));
    *image = ImageF(static_cast<int>(w), static_cast<int>(h), static_cast<int>(present.size()),
                    std::numeric_limits<float>::quiet_NaN());
    Imf::FrameBuffer fb;
    for (size_t k = 0; k < present.size(); ++k) {
      // OpenEXR addresses pixel (x, y) of the data window at base + x * xs + y * ys.
      char* base = reinterpret_cast<char*>(image->channel(static_cast<int>(k))) -
                   (static_cast<ptrdiff_t>(dw.min.x) + static_cast<ptrdiff_t>(dw.min.y) * w) *
                       static_cast<ptrdiff_t>(sizeof(float));
      fb.insert(present[k], Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * w, 1, 1,
                                       std::numeric_limits<float>::quiet_NaN()));
    }
    in.setFrameBuffer(fb);
    in.readPixels(dw.min.y, dw.max.y);
    *info = ImageInfo();
    info->width = static_cast<int>(w);
    info->height = static_cast<int>(h);
    info->channels = static_cast<int>(present.size());
    info->bits_per_sample = 32;
    info->is_float = true;
    info->channel_names = std::move(present);
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(file), "cannot read the OpenEXR file: " << e.what());
  }
  return true;
}

ImageF ReadExrChannels(const fs::path& path, const std::vector<std::string>& names,
                       std::map<std::string, double>* float_attributes) {
  ImageInfo info;
  if (float_attributes == nullptr) {
    ImageF planes;
    if (ReadExrPlanes(path, names, names, &planes, &info)) return planes;
  }
  ImageF all = ReadImage(path, &info);
  ImageF out(all.width(), all.height(), static_cast<int>(names.size()));
  for (size_t k = 0; k < names.size(); ++k) {
    auto it = std::find(info.channel_names.begin(), info.channel_names.end(), names[k]);
    if (it == info.channel_names.end())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "missing channel '" << names[k] << "'");
    const int c = static_cast<int>(it - info.channel_names.begin());
    std::copy(all.channel(c), all.channel(c) + all.pixels(), out.channel(static_cast<int>(k)));
  }
  if (float_attributes) *float_attributes = info.float_attributes;
  return out;
}

void WriteExr(const fs::path& path, const ImageF& image, const std::vector<std::string>& names,
              const std::map<std::string, double>& float_attributes,
              const std::map<std::string, std::string>& string_attributes,
              const std::string& compression) {
  MESOSCAN_CHECK_EQ(static_cast<int>(names.size()), image.channels());
  ImageToWrite w(image.width(), image.height(), image.channels(), PixelType::kFloat);
  w.channel_names = names;
  w.no_alpha = true;
  w.attributes.push_back(ImageAttribute::String("compression", compression));
  for (const auto& [k, v] : float_attributes) w.attributes.push_back(ImageAttribute::Float(k, v));
  for (const auto& [k, v] : string_attributes) w.attributes.push_back(ImageAttribute::String(k, v));
  const std::vector<float> inter = Interleave(image);
  w.data = inter.data();
  WriteWithOiio(path, std::move(w));
}

void WriteExrPlanes(const fs::path& path, const std::vector<ExrPlane>& planes,
                    const std::map<std::string, double>& float_attributes) {
  MESOSCAN_CHECK(!planes.empty() && planes[0].image != nullptr);
  const int width = planes[0].image->width(), height = planes[0].image->height();
  MESOSCAN_CHECK(width > 0 && height > 0);
  for (const ExrPlane& p : planes)
    MESOSCAN_CHECK(p.image != nullptr && p.image->width() == width && p.image->height() == height &&
                   (p.channel == -1 ? p.image->channels() == 1
                                    : p.channel >= 0 && p.channel < p.image->channels()));
  WriteFileChecked(path, [&](CheckedFile& out) {
    try {
      Imf::Header header(width, height);
      header.compression() = Imf::NO_COMPRESSION;
      for (const auto& [k, v] : float_attributes)
        header.insert(k, Imf::FloatAttribute(static_cast<float>(v)));
      Imf::FrameBuffer fb;
      for (const ExrPlane& p : planes) {
        header.channels().insert(p.name, Imf::Channel(Imf::FLOAT));
        const float* data = p.image->channel(std::max(p.channel, 0));
        fb.insert(p.name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(const_cast<float*>(data)),
                                     sizeof(float), sizeof(float) * static_cast<size_t>(width)));
      }
      CheckedExrStream stream(&out);
      Imf::OutputFile file(stream, header, /*numThreads=*/1);
      file.setFrameBuffer(fb);
      file.writePixels(height);
      // The line offsets are written by the destructor, which swallows a failure: the
      // CheckedFile remembers it and Close() throws.
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      std::string err = e.what();
      std::replace(err.begin(), err.end(), '\n', ' ');
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write image (" << err << ")");
    }
  });
}

void WritePng16(const fs::path& path, const ImageU16& image, int compression_level) {
  ImageToWrite w(image.width(), image.height(), image.channels(), PixelType::kUInt16);
  if (compression_level >= 0)
    w.attributes.push_back(
        ImageAttribute::Int("png:compressionLevel", std::min(compression_level, 9)));
  const std::vector<uint16_t> inter = Interleave(image);
  w.data = inter.data();
  WriteWithOiio(path, std::move(w));
}

void WritePng8(const fs::path& path, const ImageU8& image, int compression_level,
               bool filter_rows) {
  if (!filter_rows)
    return WritePng8Unfiltered(path, image, compression_level < 0 ? 6 : compression_level);
  ImageToWrite w(image.width(), image.height(), image.channels(), PixelType::kUInt8);
  if (compression_level >= 0)
    w.attributes.push_back(
        ImageAttribute::Int("png:compressionLevel", std::min(compression_level, 9)));
  const std::vector<uint8_t> inter = Interleave(image);
  w.data = inter.data();
  WriteWithOiio(path, std::move(w));
}

ImageU16 QuantizeU16(const ImageF& image) {
  ImageU16 out(image.width(), image.height(), image.channels());
  const auto& src = image.data();
  auto& dst = out.data();
  for (size_t i = 0; i < src.size(); ++i) {
    const float v = std::isfinite(src[i]) ? std::clamp(src[i], 0.0f, 1.0f) : 0.0f;
    dst[i] = static_cast<uint16_t>(std::lround(v * 65535.0f));
  }
  return out;
}

ImageU8 QuantizeU8(const ImageF& image, bool srgb_encode) {
  ImageU8 out(image.width(), image.height(), image.channels());
  const auto& src = image.data();
  auto& dst = out.data();
  for (size_t i = 0; i < src.size(); ++i) {
    float v = std::isfinite(src[i]) ? std::clamp(src[i], 0.0f, 1.0f) : 0.0f;
    if (srgb_encode) v = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
    dst[i] = static_cast<uint8_t>(std::lround(v * 255.0f));
  }
  return out;
}

}  // namespace mesoscan
