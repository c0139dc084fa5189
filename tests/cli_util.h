#pragma once
// Running the real `mesoscan` binary from pipeline tests (MESOSCAN_EXE is compiled in).

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "core/test_temp_dir.h"

namespace mesoscan {

struct CliResult {
  int code = -1;       // exit code; -1 if the process did not exit normally
  std::string output;  // stdout + stderr
};

// Runs `mesoscan <args>` through the shell, capturing stdout and stderr together.
inline CliResult RunMesoscan(const std::string& args) {
  const std::string cmd = std::string(MESOSCAN_EXE) + " " + args + " 2>&1";
  CliResult r;
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  const int status = pclose(pipe);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// The binary under test: MESOSCAN_TEST_EXE overrides the one built here (to run a test against an
// older build and see it fail).
inline std::string MesoscanExe() {
  const char* e = std::getenv("MESOSCAN_TEST_EXE");
  return e && *e ? e : MESOSCAN_EXE;
}

struct CliRun {
  int code = -1;         // exit code; -1: killed by a signal
  std::string out, err;  // stdout, stderr
  double seconds = 0;
  int ErrLines() const {
    int n = 0;
    for (char c : err) n += c == '\n';
    return n;
  }
};

// `mesoscan -q <args>` with stdout and stderr apart, a 120 s timeout (a hang exits -1) and a
// 6 GB address space. `prefix` runs in the same shell first (e.g. "ulimit -f 64; trap '' XFSZ;"
// to make writes past 64 KB fail with EFBIG, as on a full disk), `env` is prepended to the
// command (e.g. "MESOSCAN_MEMORY_BUDGET_MB=8").
inline CliRun RunCli(const std::string& args, const std::filesystem::path& work,
                     const std::string& prefix = "", const std::string& env = "") {
  const std::filesystem::path out = work / ".stdout.txt", err = work / ".stderr.txt";
  const std::string cmd = "ulimit -v 6000000; " + prefix + " " + env + " timeout -s KILL 120 " +
                          MesoscanExe() + " -q " + args + " >'" + out.string() + "' 2>'" +
                          err.string() + "'";
  const auto t0 = std::chrono::steady_clock::now();
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  if (r.code == 137) r.code = -1;  // the shell's "killed" (timeout)
  auto slurp = [](const std::filesystem::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  r.out = slurp(out);
  r.err = slurp(err);
  std::error_code ec;
  std::filesystem::remove(out, ec);
  std::filesystem::remove(err, ec);
  return r;
}

// Every regular file below `dir` with its size and modification time: "untouched" means equal.
inline std::map<std::string, std::pair<uintmax_t, int64_t>> FileSnapshot(
    const std::filesystem::path& dir) {
  std::map<std::string, std::pair<uintmax_t, int64_t>> m;
  if (!std::filesystem::exists(dir)) return m;
  if (std::filesystem::is_regular_file(dir)) {
    m[dir.filename().string()] = {std::filesystem::file_size(dir),
                                  std::filesystem::last_write_time(dir).time_since_epoch().count()};
    return m;
  }
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    m[std::filesystem::relative(e.path(), dir).string()] = {
        e.file_size(), e.last_write_time().time_since_epoch().count()};
  }
  return m;
}

// Names in `dir` (recursively) that look like temporaries of an interrupted or failed write:
// hidden files other than the output marker, `.mesoscan-tmp.` / `.mesoscan-old.` folders.
inline std::vector<std::string> TemporariesIn(const std::filesystem::path& dir) {
  std::vector<std::string> found;
  if (!std::filesystem::is_directory(dir)) return found;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.empty() || name[0] != '.' || name == ".mesoscan-output" || name == ".stdout.txt" ||
        name == ".stderr.txt")
      continue;
    found.push_back(e.path().string());
  }
  return found;
}

// A per-process path in the temp folder, <tmp>/mesoscan_<suite>_<pid>_<name>, removed at exit.
inline std::filesystem::path CliTempDir(const std::string& suite, const std::string& name) {
  return TestTempPath(suite, name);
}

}  // namespace mesoscan
