#pragma once
// Shared by the libFuzzer targets (docs/architecture.md): each writes the fuzzer's bytes to a file
// under a per-process folder and calls the loader the CLI calls. A mesoscan::Error of a
// bad-input or usage kind is the expected answer to a malformed file; anything else (an
// internal error, another exception, a sanitizer report, a hang) is a finding.

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/error.h"

namespace mesoscan::fuzz {

// The per-process folder, removed when the fuzzer exits normally (after a finding it is kept).
inline std::filesystem::path WorkDir() {
  struct Folder {
    std::filesystem::path path;
    Folder()
        : path(std::filesystem::temp_directory_path() /
               ("mesoscan_fuzz_" + std::to_string(getpid()))) {
      std::filesystem::create_directories(path);
    }
    ~Folder() {
      std::error_code ec;
      std::filesystem::remove_all(path, ec);
    }
  };
  static const Folder folder;
  return folder.path;
}

inline std::filesystem::path WriteInput(const std::string& name, const uint8_t* data, size_t size) {
  const auto path = WorkDir() / name;
  std::filesystem::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

template <typename Fn>
void Expect(Fn&& fn) {
  try {
    fn();
  } catch (const Error& e) {
    if (e.kind() == ErrorKind::kInternal) {
      std::fprintf(stderr, "fuzz finding: internal error: %s\n", e.what());
      std::abort();
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuzz finding: exception outside mesoscan::Error: %s\n", e.what());
    std::abort();
  }
}

}  // namespace mesoscan::fuzz
