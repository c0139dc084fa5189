#pragma once
// SHA-256 of a file's bytes (OpenSSL), as `sha256sum` prints it: a scan's report names the rig
// file it was reconstructed with by path and hash.

#include <filesystem>
#include <string>

namespace mesoscan {

// Lower-case hex digest. Throws Error(kBadInput) naming the file if it cannot be read.
std::string Sha256OfFile(const std::filesystem::path& path);

}  // namespace mesoscan
