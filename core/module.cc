#include "core/module.h"

#include <dlfcn.h>

#include <filesystem>
#include <map>
#include <mutex>
#include <vector>

#include "core/error.h"

#ifndef MESOSCAN_MODULE_DIR
#define MESOSCAN_MODULE_DIR ""
#endif

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct Loaded {
  const void* entry = nullptr;
  std::string path;
};

std::mutex& Mutex() {
  static std::mutex m;
  return m;
}
std::map<std::string, Loaded>& Modules() {
  static std::map<std::string, Loaded> m;
  return m;
}

std::vector<fs::path> SearchFolders() {
  std::vector<fs::path> dirs;
  if (const char* env = std::getenv("MESOSCAN_MODULE_DIR"); env && *env) dirs.emplace_back(env);
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec && exe.has_parent_path()) {
    dirs.push_back(exe.parent_path());
    dirs.push_back(exe.parent_path().parent_path() / "lib" / "mesoscan");
  }
  if (*MESOSCAN_MODULE_DIR) dirs.emplace_back(MESOSCAN_MODULE_DIR);
  return dirs;
}

}  // namespace

const void* LoadModule(const std::string& name) {
  std::lock_guard<std::mutex> lock(Mutex());
  Loaded& m = Modules()[name];
  if (m.entry) return m.entry;
  const std::string file = "libmesoscan_" + name + ".so";
  std::string searched, why;
  for (const fs::path& dir : SearchFolders()) {
    const fs::path path = dir / file;
    searched += (searched.empty() ? "" : ", ") + dir.string();
    std::error_code ec;
    if (!fs::exists(path, ec)) continue;
    void* handle = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
      const char* err = ::dlerror();
      why = err ? err : "dlopen failed";
      continue;
    }
    const std::string symbol = "mesoscan_module_" + name;
    using Entry = const void* (*)();
    auto entry = reinterpret_cast<Entry>(::dlsym(handle, symbol.c_str()));
    if (!entry) {
      why = path.string() + " has no " + symbol;
      ::dlclose(handle);
      continue;
    }
    m.entry = entry();
    m.path = path.string();
    return m.entry;  // never unloaded: its objects live until the process ends
  }
  MESOSCAN_THROW(ErrorKind::kInternal, "cannot load the module "
                                           << file << " (searched " << searched << ")"
                                           << (why.empty() ? "" : ": " + why));
}

std::string LoadedModulePath(const std::string& name) {
  std::lock_guard<std::mutex> lock(Mutex());
  auto it = Modules().find(name);
  return it == Modules().end() ? std::string() : it->second.path;
}

}  // namespace mesoscan
