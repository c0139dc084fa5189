#pragma once
// Opening an image for reading, safely (core/image_io.cc; used by the frame decoders too):
// only regular files (a FIFO or /dev/zero would block or never end), with the reader the
// extension names (OIIO's ImageInput::open otherwise tries every format, e.g. its DICOM reader
// on a zero-filled .png), and the header's size checked against the file size and the memory
// budget (core/budget.h) before anything is decoded. Errors throw Error(kBadInput) starting
// with `label` (default: the path).

#include <filesystem>
#include <memory>
#include <string>

#include "core/oiio_module.h"

namespace mesoscan {

// Throws unless `path` (symlinks followed) is a regular file; a symlink loop, a FIFO, a device
// or a folder is named in the message.
void CheckRegularFile(const std::filesystem::path& path, const std::string& label = "");

// Throws unless decoding a width x height x channels image (as float, interleaved then planar:
// 8 bytes per value) fits the memory budget (core/budget.h); the message starts with `label`.
void CheckImageBudget(const std::string& label, int width, int height, int channels);

// Opens through OpenImageIO (core/oiio_module.h: the module is loaded on the first call).
std::unique_ptr<ImageReader> OpenImageInput(const std::filesystem::path& path,
                                            const std::string& label = "");

// Every pixel of the open image's first subimage as `type`, interleaved (ImageReader::Read:
// no 256-line buffer). Returns false with the reader's error set.
inline bool ReadPixels(ImageReader& in, PixelType type, void* data) { return in.Read(type, data); }

}  // namespace mesoscan
