#pragma once
// Opening an image for reading, safely (core/image_io.cc; used by the frame decoders too):
// only regular files (a FIFO or /dev/zero would block or never end), with the reader the
// extension names (OIIO's ImageInput::open otherwise tries every format, e.g. its DICOM reader
// on a zero-filled .png), and the header's size checked against the file size and the memory
// budget (core/budget.h) before anything is decoded. Errors throw Error(kBadInput) starting
// with `label` (default: the path).

#include <OpenImageIO/imageio.h>

#include <filesystem>
#include <memory>
#include <string>

namespace mesoscan {

// Throws unless `path` (symlinks followed) is a regular file; a symlink loop, a FIFO, a device
// or a folder is named in the message.
void CheckRegularFile(const std::filesystem::path& path, const std::string& label = "");

std::unique_ptr<OIIO::ImageInput> OpenImageInput(const std::filesystem::path& path,
                                                 const std::string& label = "");

// Reads every pixel of the open image's first subimage as `type`, interleaved, into `data`
// (width x height x nchannels values). OpenImageIO's read_image converts types through a buffer
// of 256 scan lines whatever the image's height (1.6 GB for a 6-line EXR 524,296 pixels wide,
// found by fuzz_scan_folder): here a scan-line file of the requested type is read straight into
// `data`, and another type is converted in strips of at most 64 MB. Returns false with the
// reader's error set, as read_image does.
bool ReadPixels(OIIO::ImageInput& in, OIIO::TypeDesc type, void* data);

}  // namespace mesoscan
