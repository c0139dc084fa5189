#include "core/output_dir.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "core/error.h"
#include "core/fs.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr const char* kTmpTag = ".mesoscan-tmp.";
constexpr const char* kOldTag = ".mesoscan-old.";

// Absolute, symlinks resolved for the part that exists, `..` folded. Never throws.
fs::path Resolve(const fs::path& p) {
  std::error_code ec;
  fs::path abs = fs::absolute(p, ec);
  if (ec) abs = p;
  fs::path c = fs::weakly_canonical(abs, ec);
  if (ec) c = abs.lexically_normal();
  if (c.has_filename() == false && c.has_parent_path() && c != c.root_path()) c = c.parent_path();
  return c;
}

fs::path Sibling(const fs::path& final_path, const char* tag) {
  static std::atomic<int> counter{0};
  std::string name = ".";
  name.append(final_path.filename().string()).append(tag).append(std::to_string(getpid()));
  name.append(".").append(std::to_string(counter++));
  return final_path.parent_path() / name;
}

bool ProcessAlive(long pid) {
  if (pid <= 0) return false;
  if (pid == static_cast<long>(getpid())) return true;  // this process: never stale
  return kill(static_cast<pid_t>(pid), 0) == 0 || errno == EPERM;
}

std::string MarkerText(const std::string& command) {
  std::string t = "mesoscan ";
  return t.append(command).append("\n");
}

bool HasMarker(const fs::path& dir, const std::string& command) {
  std::ifstream in(dir / kOutputMarker);
  if (!in) return false;
  std::string line;
  std::getline(in, line);
  return line + "\n" == MarkerText(command);
}

// The option naming the output and its path, as data (app/ formats the line).
ErrorSite OutputSite(const OutputSpec& s) {
  ErrorSite site = ErrorSite::File(s.out);
  site.option = s.option;
  return site;
}

[[noreturn]] void Refuse(const OutputSpec& s, const std::string& what) {
  MESOSCAN_THROW_AT(ErrorKind::kUsage, OutputSite(s), what);
}

// An existing output of something else: `noun` is "folder" or "name".
[[noreturn]] void RefuseExisting(const OutputSpec& s, const char* noun) {
  MESOSCAN_THROW_AT(ErrorKind::kUsage, OutputSite(s),
                    "exists and is not an earlier output of 'mesoscan "
                        << s.command << "'; choose a new " << noun << " or add "
                        << OptionRef{"OutputSpec.force"} << " to replace it");
}

// The checks shared by folders and files: not empty, not an input, not around an input.
fs::path CheckAgainstInputs(const OutputSpec& s) {
  if (s.out.empty()) Refuse(s, "expected a path, got an empty string");
  const fs::path out = Resolve(s.out);
  if (out == out.root_path()) Refuse(s, "refusing to write to the filesystem root");
  for (const fs::path& in_raw : s.inputs) {
    if (in_raw.empty()) continue;
    const fs::path in = Resolve(in_raw);
    if (out == in)
      Refuse(s, "is the input " + in_raw.string() +
                    " (it would be overwritten); choose another folder");
    if (PathIsWithin(out, in))
      Refuse(s, "lies inside the input " + in_raw.string() + "; choose a folder outside it");
    if (PathIsWithin(in, out))
      Refuse(s, "contains the input " + in_raw.string() +
                    " (replacing it would delete the input); choose another folder");
  }
  return out;
}

}  // namespace

bool PathIsWithin(const fs::path& inner, const fs::path& outer) {
  auto i = inner.begin(), o = outer.begin();
  for (; o != outer.end(); ++o, ++i) {
    if (o->empty()) continue;  // trailing separator
    if (i == inner.end() || *i != *o) return false;
  }
  return true;
}

namespace {

std::string StripLeadingDots(const std::string& s) {
  const size_t k = s.find_first_not_of('.');
  return k == std::string::npos ? std::string() : s.substr(k);
}

// A temporary or backup sibling of `final_path` left by a process that is gone: `.NAME` + tag +
// PID..., and also the nested staging folders of a writer that staged into its caller's
// temporary (`..NAME.mesoscan-tmp.P.0.mesoscan-tmp.P.1`). *backup: a `.mesoscan-old.` backup
// of NAME itself (not nested).
bool IsStaleSibling(const std::string& name, const std::string& final_name, bool* backup) {
  if (name.empty() || name[0] != '.') return false;
  const std::string base = StripLeadingDots(final_name);
  const std::string bare = StripLeadingDots(name);
  if (base.empty() || bare.rfind(base, 0) != 0) return false;
  const std::string rest = bare.substr(base.size());
  if (rest.rfind(kTmpTag, 0) == 0)
    *backup = false;
  else if (rest.rfind(kOldTag, 0) == 0)
    *backup = name == "." + final_name + rest;
  else
    return false;
  const std::string pid_text = rest.substr(std::string(kTmpTag).size());
  char* end_ptr = nullptr;
  const long pid = std::strtol(pid_text.c_str(), &end_ptr, 10);
  return end_ptr != pid_text.c_str() && !ProcessAlive(pid);
}

// This process's own staging folder (`.NAME.mesoscan-tmp.<our pid>.N`), empty: a writer asked
// to replace it atomically writes straight into it (its caller swaps it into place), rather
// than staging a second, nested temporary next to it.
bool IsOwnEmptyStagingFolder(const fs::path& p) {
  const std::string name = p.filename().string();
  const std::string tag = std::string(kTmpTag) + std::to_string(getpid()) + ".";
  const size_t at = name.rfind(tag);
  if (name.empty() || name[0] != '.' || at == std::string::npos) return false;
  const std::string n = name.substr(at + tag.size());
  if (n.empty() || n.find_first_not_of("0123456789") != std::string::npos) return false;
  std::error_code ec;
  return fs::is_directory(fs::symlink_status(p, ec)) && fs::is_empty(p, ec) && !ec;
}

}  // namespace

void CleanStaleOutputs(const fs::path& final_path) {
  const fs::path dir = final_path.parent_path();
  const std::string final_name = final_path.filename().string();
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return;
  std::vector<std::pair<fs::path, bool>> stale;  // path, is backup
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    bool backup = false;
    if (IsStaleSibling(it->path().filename().string(), final_name, &backup))
      stale.emplace_back(it->path(), backup);
  }
  for (const auto& [p, backup] : stale) {
    std::error_code e2;
    if (backup && !fs::exists(fs::symlink_status(final_path, e2))) {
      fs::rename(p, final_path, e2);  // an interrupted replacement: the old output comes back
      if (!e2) continue;
    }
    fs::remove_all(p, e2);
  }
}

void RestoreInterruptedReplacement(const fs::path& path) {
  std::error_code ec;
  if (fs::exists(fs::symlink_status(path, ec))) return;
  const fs::path final_path = Resolve(path);
  const fs::path dir = final_path.parent_path();
  const std::string final_name = final_path.filename().string();
  if (!fs::is_directory(dir, ec)) return;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    bool backup = false;
    if (IsStaleSibling(it->path().filename().string(), final_name, &backup) && backup) {
      std::error_code e2;
      fs::rename(it->path(), final_path, e2);
      if (!e2) return;
    }
  }
}

fs::path CheckOutputFolder(const OutputSpec& s) {
  const fs::path out = CheckAgainstInputs(s);
  CleanStaleOutputs(out);
  std::error_code ec;
  const fs::file_status st = fs::status(out, ec);
  if (fs::exists(st)) {
    if (!fs::is_directory(st)) Refuse(s, "exists and is not a folder");
    bool ok = s.force || HasMarker(out, s.command) || fs::is_empty(out, ec);
    if (!ok && !s.legacy_signature.empty()) {
      ok = true;
      for (const std::string& f : s.legacy_signature) ok = ok && fs::exists(out / f, ec);
    }
    if (!ok) RefuseExisting(s, "folder");
  }
  return out;
}

void ReplaceFolderAtomically(const fs::path& final_dir, const std::string& marker_command,
                             const std::function<void(const fs::path&)>& fill) {
  fs::path out = Resolve(final_dir);
  std::error_code ec;
  if (IsOwnEmptyStagingFolder(out)) {
    fill(out);  // the caller's staging folder: the caller swaps it into place
    if (!marker_command.empty()) WriteTextFile(out / kOutputMarker, MarkerText(marker_command));
    return;
  }
  CleanStaleOutputs(out);
  fs::create_directories(out.parent_path(), ec);
  const fs::path tmp = Sibling(out, kTmpTag);
  fs::create_directory(tmp, ec);
  if (ec)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(out),
                          "cannot create output folder (" << ec.message() << ")");
  try {
    fill(tmp);
    if (!marker_command.empty()) {
      WriteTextFile(tmp / kOutputMarker, MarkerText(marker_command));
    }
    if (fs::exists(fs::symlink_status(out, ec))) {
      // One atomic step where the filesystem supports it; tmp then holds the old output.
      if (::renameat2(AT_FDCWD, tmp.c_str(), AT_FDCWD, out.c_str(), RENAME_EXCHANGE) == 0) {
        fs::remove_all(tmp, ec);
        return;
      }
      // Fallback: old -> backup, new -> final, remove backup (a kill in between leaves the
      // backup, which CleanStaleOutputs renames back).
      const fs::path old = Sibling(out, kOldTag);
      fs::rename(out, old, ec);
      if (ec)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(out),
                              "cannot replace the existing folder (" << ec.message() << ")");
      fs::rename(tmp, out, ec);
      if (ec) {
        std::error_code e2;
        fs::rename(old, out, e2);
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(out), "cannot write folder (" << ec.message() << ")");
      }
      fs::remove_all(old, ec);
      return;
    }
    fs::rename(tmp, out, ec);
    if (ec)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(out), "cannot write folder (" << ec.message() << ")");
  } catch (const Error& e) {
    // A message about a file in the staging folder names it where the user will look for it.
    fs::remove_all(tmp, ec);
    throw e.WithPathRenamed(tmp.string(), out.string());
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

void WriteOutputFolder(const OutputSpec& s, const std::function<void(const fs::path&)>& fill) {
  ReplaceFolderAtomically(CheckOutputFolder(s), s.command, fill);
}

fs::path CheckOutputFile(const OutputSpec& s,
                         const std::function<bool(const fs::path&)>& accept_existing) {
  const fs::path out = CheckAgainstInputs(s);
  std::error_code ec;
  const fs::file_status st = fs::status(out, ec);
  if (fs::exists(st)) {
    if (fs::is_directory(st)) Refuse(s, "is a folder; expected a file name");
    if (!fs::is_regular_file(st)) Refuse(s, "exists and is not a regular file");
    if (!s.force && !(accept_existing && accept_existing(out))) RefuseExisting(s, "name");
  }
  return out;
}

}  // namespace mesoscan
