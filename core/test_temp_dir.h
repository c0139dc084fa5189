#pragma once
// Test support: per-process paths in the temp folder that the test process removes when it
// exits, so that `make test` leaves nothing behind (each ctest case is its own process).

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <string>
#include <system_error>
#include <vector>

namespace mesoscan {

// Removes `path` (a file or a folder, recursively) when this process exits normally, including
// after failed tests. Not in a forked child (its exit leaves the parent's files alone), and not
// when the environment sets MESOSCAN_KEEP_TEST_FILES (to look at a failing test's files).
inline void RemoveAtExit(const std::filesystem::path& path) {
  struct Registry {
    std::mutex mutex;
    pid_t owner = getpid();
    std::vector<std::filesystem::path> paths;
    ~Registry() {
      if (getpid() != owner || std::getenv("MESOSCAN_KEEP_TEST_FILES") != nullptr) return;
      std::error_code ec;
      for (const auto& p : paths) std::filesystem::remove_all(p, ec);
    }
  };
  static Registry registry;
  std::lock_guard<std::mutex> lock(registry.mutex);
  registry.paths.push_back(path);
}

// <temp>/mesoscan_<suite>_<pid>_<name>, removed now if a stale one exists and again at exit;
// not created (for outputs that must not exist yet).
inline std::filesystem::path TestTempPath(const std::string& suite, const std::string& name) {
  const std::filesystem::path p =
      std::filesystem::temp_directory_path() /
      ("mesoscan_" + suite + "_" + std::to_string(getpid()) + "_" + name);
  std::error_code ec;
  std::filesystem::remove_all(p, ec);
  RemoveAtExit(p);
  return p;
}

// The same path, created as an empty folder.
inline std::filesystem::path TestTempDir(const std::string& suite, const std::string& name) {
  const std::filesystem::path p = TestTempPath(suite, name);
  std::filesystem::create_directories(p);
  return p;
}

}  // namespace mesoscan
