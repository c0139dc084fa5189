#pragma once
// A fast writer for 8-bit PNGs whose rows do not predict each other (false-colour maps of noise,
// e.g. error_map.png): every row unfiltered (filter type 0), the zlib stream deflated in
// parallel pieces on the pool, as pigz does: each piece of rows is compressed on its own
// (primed with the 32 KB of rows before it as the dictionary, so matches still reach back),
// ended by a sync flush so the pieces concatenate into one standard zlib stream, whose Adler-32
// is combined from the pieces'. Any PNG reader decodes it; the samples are exactly the image's.
// No OpenImageIO (core/oiio_module.h) is involved. Written atomically (temp file + rename).

#include <filesystem>

#include "core/image.h"

namespace mesoscan {

// image: 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA) channels. level: zlib level 0..9.
// Throws Error(kBadInput) naming the file if it cannot be written.
void WritePng8Unfiltered(const std::filesystem::path& path, const ImageU8& image, int level);

}  // namespace mesoscan
