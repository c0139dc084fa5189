#include "core/fs.h"

#include <unistd.h>

#include <atomic>
#include <fstream>
#include <sstream>

#include "core/error.h"
#include "core/output_dir.h"

namespace mesoscan {
namespace fs = std::filesystem;

fs::path TempSiblingPath(const fs::path& final_path) {
  static std::atomic<int> counter{0};
  const std::string stem = final_path.stem().string();
  const std::string ext = final_path.extension().string();
  return final_path.parent_path() /
         ("." + stem + ".tmp" + std::to_string(getpid()) + "_" + std::to_string(counter++) + ext);
}

void WriteAtomically(const fs::path& final_path,
                     const std::function<void(const fs::path&)>& write) {
  const fs::path tmp = TempSiblingPath(final_path);
  try {
    write(tmp);
    std::error_code ec;
    fs::rename(tmp, final_path, ec);
    if (ec) MESOSCAN_BAD_INPUT(final_path.string() << ": cannot write (" << ec.message() << ")");
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

void WriteTextFile(const fs::path& path, const std::string& text) {
  WriteAtomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    out.close();
    if (!out) MESOSCAN_BAD_INPUT(path.string() << ": cannot write file");
  });
}

std::string ReadTextFile(const fs::path& path) {
  // Only regular files: a FIFO or a device would block or never end.
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (fs::exists(st) && !fs::is_regular_file(st))
    MESOSCAN_BAD_INPUT(path.string() << ": expected a regular file, got "
                                     << (fs::is_directory(st) ? "a folder" : "a special file"));
  std::ifstream in(path, std::ios::binary);
  if (!in) MESOSCAN_BAD_INPUT(path.string() << ": cannot open file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void WriteFolderAtomically(const fs::path& final_dir,
                           const std::function<void(const fs::path&)>& fill) {
  ReplaceFolderAtomically(final_dir, "", fill);
}

}  // namespace mesoscan
