#pragma once
// Atomic file output: write to a temporary name in the same folder, then rename.

#include <filesystem>
#include <functional>
#include <string>

namespace mesoscan {

// A temporary sibling of `final_path` (same folder, so rename is atomic), unique per process
// and call. The extension is kept so format-by-extension writers (OIIO) still work.
std::filesystem::path TempSiblingPath(const std::filesystem::path& final_path);

// Calls write(tmp) then renames tmp to final_path; on any exception removes tmp and rethrows.
void WriteAtomically(const std::filesystem::path& final_path,
                     const std::function<void(const std::filesystem::path& tmp)>& write);

// Writes text (JSON, CSV, ...) atomically. Throws Error naming the file on failure.
void WriteTextFile(const std::filesystem::path& path, const std::string& text);
std::string ReadTextFile(const std::filesystem::path& path);

// Builds a whole output folder atomically: fill(tmp_dir) writes into a fresh temporary sibling
// folder, which then replaces `final_dir` (an existing final_dir is moved aside and removed
// only after the rename succeeds).
void WriteFolderAtomically(const std::filesystem::path& final_dir,
                           const std::function<void(const std::filesystem::path& tmp_dir)>& fill);

}  // namespace mesoscan
