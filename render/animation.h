#pragma once
// Animated GIF through OpenImageIO's GIF writer (one subimage per frame, looping). OIIO 2.4's
// WebP writer takes single images only, so the turntable's animation is a GIF; the frames are
// also written as a PNG sequence by the caller.

#include <filesystem>
#include <vector>

#include "core/image.h"

namespace mesoscan {

// frames: 3-channel 8-bit sRGB images of the same size (>= 1). Written atomically.
void WriteAnimatedGif(const std::filesystem::path& path, const std::vector<ImageU8>& frames,
                      int frames_per_second);

}  // namespace mesoscan
