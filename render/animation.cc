#include "render/animation.h"

#include <OpenImageIO/imageio.h>

#include <algorithm>

#include "core/error.h"
#include "core/fs.h"

namespace mesoscan {

void WriteAnimatedGif(const std::filesystem::path& path, const std::vector<ImageU8>& frames,
                      int frames_per_second) {
  namespace oiio = OIIO;
  if (frames.empty()) MESOSCAN_BAD_INPUT(path.string() << ": an animation needs at least one frame");
  const int w = frames[0].width(), h = frames[0].height(), nc = frames[0].channels();
  for (const auto& f : frames)
    MESOSCAN_CHECK(f.width() == w && f.height() == h && f.channels() == nc);
  WriteAtomically(path, [&](const std::filesystem::path& tmp) {
    auto out = oiio::ImageOutput::create("x.gif");
    if (!out || !out->supports("multiimage"))
      MESOSCAN_THROW(ErrorKind::kInternal, "OpenImageIO cannot write animated GIF");
    oiio::ImageSpec spec(w, h, nc, oiio::TypeDesc::UINT8);
    const int fps[2] = {std::max(1, frames_per_second), 1};
    spec.attribute("FramesPerSecond", oiio::TypeRational, fps);
    spec.attribute("oiio:Movie", 1);
    spec.attribute("gif:LoopCount", 0);
    std::vector<oiio::ImageSpec> specs(frames.size(), spec);
    std::vector<uint8_t> inter(static_cast<size_t>(w) * h * nc);
    for (size_t k = 0; k < frames.size(); ++k) {
      const bool ok = k == 0 ? out->open(tmp.string(), static_cast<int>(specs.size()), specs.data())
                             : out->open(tmp.string(), spec, oiio::ImageOutput::AppendSubimage);
      for (int c = 0; c < nc; ++c) {
        const uint8_t* src = frames[k].channel(c);
        for (size_t i = 0; i < frames[k].pixels(); ++i) inter[i * nc + c] = src[i];
      }
      if (!ok || !out->write_image(oiio::TypeDesc::UINT8, inter.data()))
        MESOSCAN_BAD_INPUT(path.string() << ": cannot write animation (" << out->geterror() << ")");
    }
    if (!out->close()) MESOSCAN_BAD_INPUT(path.string() << ": cannot write animation (" << out->geterror() << ")");
  });
}

}  // namespace mesoscan
