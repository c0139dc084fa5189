// libmesoscan_oiio.so: the one place that calls OpenImageIO (interface: core/oiio_module.h,
// loaded by core/module.h on first use). It calls nothing of mesoscan's libraries: errors come
// back as strings and the callers (core/image_io.cc) turn them into Error.

#include "core/oiio_module.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace mesoscan {
namespace {

namespace oiio = OIIO;

std::string OneLine(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  return s;
}

oiio::TypeDesc ToOiio(PixelType t) {
  switch (t) {
    case PixelType::kUInt8:
      return oiio::TypeDesc::UINT8;
    case PixelType::kUInt16:
      return oiio::TypeDesc::UINT16;
    case PixelType::kHalf:
      return oiio::TypeDesc::HALF;
    case PixelType::kFloat:
      return oiio::TypeDesc::FLOAT;
    case PixelType::kOther:
      break;
  }
  return oiio::TypeDesc::UNKNOWN;
}

PixelType FromOiio(oiio::TypeDesc t) {
  if (t == oiio::TypeDesc::UINT8) return PixelType::kUInt8;
  if (t == oiio::TypeDesc::UINT16) return PixelType::kUInt16;
  if (t == oiio::TypeDesc::HALF) return PixelType::kHalf;
  if (t == oiio::TypeDesc::FLOAT) return PixelType::kFloat;
  return PixelType::kOther;
}

void SetAttributes(oiio::ImageSpec* spec, const std::vector<ImageAttribute>& attributes) {
  for (const ImageAttribute& a : attributes) switch (a.kind) {
      case ImageAttribute::Kind::kInt:
        spec->attribute(a.name, static_cast<int>(a.number));
        break;
      case ImageAttribute::Kind::kFloat:
        spec->attribute(a.name, static_cast<float>(a.number));
        break;
      case ImageAttribute::Kind::kString:
        spec->attribute(a.name, a.text);
        break;
      case ImageAttribute::Kind::kRational:
        spec->attribute(a.name, oiio::TypeRational, a.rational);
        break;
    }
}

ImageHeader HeaderOf(const oiio::ImageInput& in) {
  const oiio::ImageSpec& spec = in.spec();
  ImageHeader h;
  h.width = spec.width;
  h.height = spec.height;
  h.channels = spec.nchannels;
  h.format = FromOiio(spec.format);
  h.format_bytes = static_cast<int>(spec.format.size());
  h.is_float = spec.format.is_floating_point();
  h.bits_per_sample_hint = spec.get_int_attribute("oiio:BitsPerSample", 0);
  h.channel_names = spec.channelnames;
  for (const auto& p : spec.extra_attribs) {
    const oiio::TypeDesc t = p.type();
    if (t == oiio::TypeFloat || t == oiio::TypeInt || t == oiio::TypeDesc::DOUBLE)
      h.numeric_attributes[p.name().string()] = p.get_float();
  }
  h.format_name = in.format_name();
  return h;
}

class Reader final : public ImageReader {
 public:
  explicit Reader(std::unique_ptr<oiio::ImageInput> in)
      : in_(std::move(in)), header_(HeaderOf(*in_)) {}
  const ImageHeader& header() const override { return header_; }

  bool Read(PixelType type_in, void* data) override {
    const oiio::TypeDesc type = ToOiio(type_in);
    const oiio::ImageSpec& spec = in_->spec();
    const int nc = spec.nchannels;
    // Tiles: the buffer is one tile, whose size OpenEXR and libtiff bound. Per-channel
    // formats: OpenImageIO's own conversion (rare in what we read; its buffer is 256 lines).
    if (spec.tile_width > 0 || !spec.channelformats.empty())
      return in_->read_image(0, 0, 0, nc, type, data);
    // The file's own type: straight into `data`, no buffer.
    if (type == spec.format)
      return in_->read_scanlines(0, 0, spec.y, spec.y + spec.height, spec.z, 0, nc,
                                 oiio::TypeDesc::UNKNOWN, data);
    // Another type: strips of native scan lines converted into `data`.
    const size_t values = static_cast<size_t>(spec.width) * nc;
    const size_t native_line = values * spec.format.size();
    const int strip = static_cast<int>(
        std::clamp<size_t>((size_t{64} << 20) / std::max<size_t>(native_line, 1), 1, 256));
    std::vector<unsigned char> buf(std::min(strip, spec.height) * native_line);
    auto* out = static_cast<unsigned char*>(data);
    for (int y = 0; y < spec.height; y += strip) {
      const int rows = std::min(strip, spec.height - y);
      if (!in_->read_native_scanlines(0, 0, spec.y + y, spec.y + y + rows, spec.z, buf.data()) ||
          !oiio::convert_pixel_values(spec.format, buf.data(), type,
                                      out + static_cast<size_t>(y) * values * type.size(),
                                      static_cast<int>(rows * values)))
        return false;
    }
    return true;
  }

  bool ReadWhole(PixelType type, void* data) override {
    return in_->read_image(0, 0, 0, in_->spec().nchannels, ToOiio(type), data);
  }

  std::string error() override { return OneLine(in_->geterror()); }

 private:
  std::unique_ptr<oiio::ImageInput> in_;
  ImageHeader header_;
};

class Module final : public OiioModule {
 public:
  std::unique_ptr<ImageReader> Open(const std::string& path, const std::string& format,
                                    const std::vector<ImageAttribute>& config, std::string* error,
                                    bool* no_reader) const override {
    auto in = format.empty() ? nullptr : oiio::ImageInput::create(format);
    *no_reader = !in;
    if (!in) {
      *error = OneLine(oiio::geterror());  // (and cleared)
      return nullptr;
    }
    oiio::ImageSpec spec, conf;
    SetAttributes(&conf, config);
    const bool ok = config.empty() ? in->open(path, spec) : in->open(path, spec, conf);
    if (!ok) {
      std::string err = in->geterror();
      if (err.empty()) err = oiio::geterror();
      *error = OneLine(err);
      return nullptr;
    }
    return std::make_unique<Reader>(std::move(in));
  }

  bool Write(const std::string& path, const std::string& format,
             const std::vector<ImageToWrite>& images, std::string* error) const override {
    return WriteTo(path, format, images, nullptr, error, nullptr);
  }

  bool Encode(const std::string& format, const std::vector<ImageToWrite>& images,
              std::vector<unsigned char>* bytes, std::string* error,
              bool* no_memory_writer) const override {
    bytes->clear();
    return WriteTo("x." + format, format, images, bytes, error, no_memory_writer);
  }

  // Write() to `path`, or (bytes != nullptr) Encode() into *bytes.
  static bool WriteTo(const std::string& path, const std::string& format,
                      const std::vector<ImageToWrite>& images, std::vector<unsigned char>* bytes,
                      std::string* error, bool* no_memory_writer) {
    if (no_memory_writer) *no_memory_writer = false;
    if (images.empty()) {
      *error = "no image to write";
      return false;
    }
    auto out = oiio::ImageOutput::create(format.empty() ? path : "x." + format);
    if (!out) {
      *error = "no writer for this format";
      oiio::geterror();  // clear
      return false;
    }
    if (images.size() > 1 && !out->supports("multiimage")) {
      *error = std::string("OpenImageIO cannot write several images to a .") + out->format_name() +
               " file";
      return false;
    }
    std::unique_ptr<oiio::Filesystem::IOVecOutput> proxy;
    if (bytes) {
      if (!out->supports("ioproxy")) {
        *error = std::string("OpenImageIO cannot write a .") + out->format_name() + " to memory";
        if (no_memory_writer) *no_memory_writer = true;
        return false;
      }
      proxy = std::make_unique<oiio::Filesystem::IOVecOutput>(*bytes);
      if (!out->set_ioproxy(proxy.get())) {
        *error = OneLine(out->geterror());
        if (no_memory_writer) *no_memory_writer = true;
        return false;
      }
    }
    std::vector<oiio::ImageSpec> specs;
    for (const ImageToWrite& im : images) {
      oiio::ImageSpec spec(im.width, im.height, im.channels, ToOiio(im.type));
      if (!im.channel_names.empty()) spec.channelnames = im.channel_names;
      if (im.no_alpha) spec.alpha_channel = -1;
      SetAttributes(&spec, im.attributes);
      specs.push_back(std::move(spec));
    }
    bool ok = true;
    for (size_t k = 0; k < images.size() && ok; ++k) {
      ok = images.size() == 1 ? out->open(path, specs[0])
           : k == 0           ? out->open(path, static_cast<int>(specs.size()), specs.data())
                              : out->open(path, specs[k], oiio::ImageOutput::AppendSubimage);
      ok = ok && out->write_image(ToOiio(images[k].type), images[k].data);
    }
    ok = ok && out->close();
    if (!ok) *error = OneLine(out->geterror());
    if (ok && proxy && !proxy->error().empty()) {
      *error = OneLine(proxy->error());
      ok = false;
    }
    return ok;
  }

  std::string GlobalAttribute(const std::string& name) const override {
    std::string value;
    oiio::getattribute(name, value);
    return value;
  }
  std::string Version() const override { return OIIO_VERSION_STRING; }
};

}  // namespace
}  // namespace mesoscan

extern "C" __attribute__((visibility("default"))) const void* mesoscan_module_oiio() {
  static const mesoscan::Module module;
  return static_cast<const mesoscan::OiioModule*>(&module);
}
