#pragma once
// File output: every byte written through one checked writer (CheckedFile), into a temporary
// name in the same folder, then renamed. A failed or short write (disk full, quota, file size
// limit, I/O error) throws Error naming the file and the system's reason, and the temporary is
// removed: nothing half-written is left under any name.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace mesoscan {

// A temporary sibling of `final_path` (same folder, so rename is atomic), unique per process
// and call. The extension is kept so format-by-extension writers (OIIO) still work.
std::filesystem::path TempSiblingPath(const std::filesystem::path& final_path);

// An open file whose every write is checked. Write() retries short writes and throws Error
// (exit 3) "FILE: cannot write (REASON)" naming the final file (`label`) on the first failure;
// the failure is also remembered, so that a library that swallows it (a destructor, an ostream)
// still fails the file in Close(). Close() flushes stream(), closes the descriptor (NFS reports
// some errors there) and throws the remembered failure.
class CheckedFile {
 public:
  CheckedFile(const std::filesystem::path& path, const std::filesystem::path& label);
  ~CheckedFile();
  CheckedFile(const CheckedFile&) = delete;
  CheckedFile& operator=(const CheckedFile&) = delete;

  void Write(const void* data, size_t n);
  void Write(std::string_view s) { Write(s.data(), s.size()); }
  // The write position (seek for formats that patch their header at the end: OpenEXR's line
  // offsets).
  void Seek(uint64_t offset);
  uint64_t Tell() const { return pos_; }
  // A buffered ostream over Write(); a failed write sets its badbit and fails Close().
  std::ostream& stream();
  void Close();
  bool failed() const { return !error_.empty(); }
  const std::filesystem::path& label() const { return label_; }

 private:
  class Buf;
  [[noreturn]] void Fail(const std::string& reason);
  [[noreturn]] void ThrowError() const;  // Error at label_: error_
  int fd_ = -1;
  uint64_t pos_ = 0;
  std::filesystem::path label_;
  std::string error_;  // the first failure, without the file ("cannot write (No space left...)")
  std::unique_ptr<Buf> buf_;
  std::unique_ptr<std::ostream> stream_;
};

// Writes `path` through a CheckedFile on a temporary sibling, then renames it into place; on any
// exception (or a failed write a library swallowed) the temporary is removed and Error thrown.
void WriteFileChecked(const std::filesystem::path& path,
                      const std::function<void(CheckedFile& file)>& write);
// The same for bytes already in memory.
void WriteBytesFile(const std::filesystem::path& path, const void* data, size_t n);

// Writes text (JSON, CSV, ...) atomically. Throws Error naming the file on failure.
void WriteTextFile(const std::filesystem::path& path, const std::string& text);
std::string ReadTextFile(const std::filesystem::path& path);

// For writers that can only write to a path (a device's SDK): write(tmp) writes a temporary
// sibling, which is then checked (a regular file of at least min_bytes; verify(tmp), if given,
// may read it back) and renamed into place. Prefer WriteFileChecked: only it sees each write.
void WriteAtomicallyVerified(const std::filesystem::path& final_path,
                             const std::function<void(const std::filesystem::path& tmp)>& write,
                             uintmax_t min_bytes,
                             const std::function<void(const std::filesystem::path& tmp)>& verify);

// Builds a whole output folder atomically: fill(tmp_dir) writes into a fresh temporary sibling
// folder, which then replaces `final_dir` (an existing final_dir is moved aside and removed
// only after the rename succeeds).
void WriteFolderAtomically(const std::filesystem::path& final_dir,
                           const std::function<void(const std::filesystem::path& tmp_dir)>& fill);

}  // namespace mesoscan
