#include "render/animation.h"

#include <algorithm>

#include "core/error.h"
#include "core/fs.h"
#include "core/oiio_module.h"

namespace mesoscan {

void WriteAnimatedGif(const std::filesystem::path& path, const std::vector<ImageU8>& frames,
                      int frames_per_second) {
  if (frames.empty())
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "an animation needs at least one frame");
  const int w = frames[0].width(), h = frames[0].height(), nc = frames[0].channels();
  for (const auto& f : frames)
    MESOSCAN_CHECK(f.width() == w && f.height() == h && f.channels() == nc);
  std::vector<std::vector<uint8_t>> inter(frames.size());
  std::vector<ImageToWrite> images;
  for (size_t k = 0; k < frames.size(); ++k) {
    inter[k].resize(static_cast<size_t>(w) * h * nc);
    for (int c = 0; c < nc; ++c) {
      const uint8_t* src = frames[k].channel(c);
      for (size_t i = 0; i < frames[k].pixels(); ++i) inter[k][i * nc + c] = src[i];
    }
    ImageToWrite im(w, h, nc, PixelType::kUInt8, inter[k].data());
    im.attributes = {ImageAttribute::Rational("FramesPerSecond", std::max(1, frames_per_second), 1),
                     ImageAttribute::Int("oiio:Movie", 1), ImageAttribute::Int("gif:LoopCount", 0)};
    images.push_back(std::move(im));
  }
  WriteImagesChecked(path, "gif", images);
}

}  // namespace mesoscan
