#include "core/fs.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <streambuf>

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

// The ostream's buffer: 64 KB, flushed through CheckedFile::Write (which records a failure;
// the stream sees eof and sets badbit, Close() throws).
class CheckedFile::Buf final : public std::streambuf {
 public:
  explicit Buf(CheckedFile* file) : file_(file), buf_(1 << 16) { Reset(); }
  bool Flush() {
    const std::ptrdiff_t n = pptr() - pbase();
    Reset();
    if (n <= 0) return !file_->failed();
    try {
      file_->Write(buf_.data(), static_cast<size_t>(n));
    } catch (const Error&) {
      return false;
    }
    return true;
  }

 protected:
  int_type overflow(int_type c) override {
    if (!Flush()) return traits_type::eof();
    if (!traits_type::eq_int_type(c, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(c);
      pbump(1);
    }
    return traits_type::not_eof(c);
  }
  int sync() override { return Flush() ? 0 : -1; }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    if (n >= static_cast<std::streamsize>(buf_.size())) {  // large blocks go straight through
      if (!Flush()) return 0;
      try {
        file_->Write(s, static_cast<size_t>(n));
      } catch (const Error&) {
        return 0;
      }
      return n;
    }
    return std::streambuf::xsputn(s, n);
  }

 private:
  void Reset() { setp(buf_.data(), buf_.data() + buf_.size()); }
  CheckedFile* file_;
  std::vector<char> buf_;
};

CheckedFile::CheckedFile(const fs::path& path, const fs::path& label) : label_(label) {
  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) Fail(std::strerror(errno));
}

CheckedFile::~CheckedFile() {
  if (fd_ >= 0) ::close(fd_);
}

void CheckedFile::Fail(const std::string& reason) {
  if (error_.empty()) error_ = "cannot write (" + reason + ")";
  ThrowError();
}

void CheckedFile::ThrowError() const { MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label_), error_); }

void CheckedFile::Write(const void* data, size_t n) {
  if (!error_.empty()) ThrowError();
  const char* p = static_cast<const char*>(data);
  while (n > 0) {
    const ssize_t w = ::write(fd_, p, std::min<size_t>(n, size_t{1} << 30));
    if (w < 0) {
      if (errno == EINTR) continue;
      Fail(std::strerror(errno));
    }
    if (w == 0) Fail("no byte written");
    p += w;
    n -= static_cast<size_t>(w);
    pos_ += static_cast<uint64_t>(w);
  }
}

void CheckedFile::Seek(uint64_t offset) {
  if (buf_ && !buf_->Flush()) ThrowError();
  if (!error_.empty()) ThrowError();
  if (::lseek(fd_, static_cast<off_t>(offset), SEEK_SET) < 0) Fail(std::strerror(errno));
  pos_ = offset;
}

std::ostream& CheckedFile::stream() {
  if (!stream_) {
    buf_ = std::make_unique<Buf>(this);
    stream_ = std::make_unique<std::ostream>(buf_.get());
  }
  return *stream_;
}

void CheckedFile::Close() {
  if (buf_) buf_->Flush();
  if (stream_ && !stream_->good() && error_.empty()) error_ = "cannot write";
  const int fd = fd_;
  fd_ = -1;
  if (fd >= 0 && ::close(fd) != 0 && error_.empty())
    error_ = std::string("cannot write (") + std::strerror(errno) + ")";
  if (!error_.empty()) ThrowError();
}

void WriteFileChecked(const fs::path& path, const std::function<void(CheckedFile&)>& write) {
  const fs::path tmp = TempSiblingPath(path);
  try {
    {
      CheckedFile file(tmp, path);
      write(file);
      file.Close();
    }
    std::error_code ec;
    fs::rename(tmp, path, ec);
    if (ec) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write (" << ec.message() << ")");
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

void WriteBytesFile(const fs::path& path, const void* data, size_t n) {
  WriteFileChecked(path, [&](CheckedFile& f) { f.Write(data, n); });
}

void WriteTextFile(const fs::path& path, const std::string& text) {
  WriteBytesFile(path, text.data(), text.size());
}

void WriteAtomicallyVerified(const fs::path& final_path,
                             const std::function<void(const fs::path&)>& write, uintmax_t min_bytes,
                             const std::function<void(const fs::path&)>& verify) {
  const fs::path tmp = TempSiblingPath(final_path);
  const ErrorSite site = ErrorSite::File(final_path);
  try {
    write(tmp);
    std::error_code ec;
    const uintmax_t size = fs::file_size(tmp, ec);
    if (ec) MESOSCAN_BAD_INPUT_AT(site, "cannot write (" << ec.message() << ")");
    if (size < min_bytes)
      MESOSCAN_BAD_INPUT_AT(site, "cannot write (" << size << " bytes written, expected at least "
                                                   << min_bytes << ")");
    if (verify) verify(tmp);
    fs::rename(tmp, final_path, ec);
    if (ec) MESOSCAN_BAD_INPUT_AT(site, "cannot write (" << ec.message() << ")");
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

std::string ReadTextFile(const fs::path& path) {
  // Only regular files: a FIFO or a device would block or never end.
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (fs::exists(st) && !fs::is_regular_file(st))
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(path),
        "expected a regular file, got " << (fs::is_directory(st) ? "a folder" : "a special file"));
  std::ifstream in(path, std::ios::binary);
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot open file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void WriteFolderAtomically(const fs::path& final_dir,
                           const std::function<void(const fs::path&)>& fill) {
  ReplaceFolderAtomically(final_dir, "", fill);
}

}  // namespace mesoscan
