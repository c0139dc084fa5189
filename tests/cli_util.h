#pragma once
// Running the real `mesoscan` binary from pipeline tests (MESOSCAN_EXE is compiled in).

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

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

// A per-process path in the temp folder, <tmp>/mesoscan_<suite>_<pid>_<name>, removed at exit.
inline std::filesystem::path CliTempDir(const std::string& suite, const std::string& name) {
  return TestTempPath(suite, name);
}

}  // namespace mesoscan
