#include "core/stderr_filter.h"

#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <string_view>

namespace mesoscan {
namespace {

struct FilterState {
  bool at_line_start = true;
  bool dropping = false;
};
FilterState g_state;

bool IsNoise(std::string_view s) {
  return s.rfind("libpng error: ", 0) == 0 || s.rfind("libpng warning: ", 0) == 0;
}

void WriteAll(const char* p, size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(STDERR_FILENO, p, n);
    if (w <= 0) return;
    p += w;
    n -= static_cast<size_t>(w);
  }
}

// Called under the FILE's lock (stdio serialises writers of one stream).
ssize_t FilterWrite(void*, const char* buf, size_t size) {
  std::string_view s(buf, size);
  while (!s.empty()) {
    if (g_state.at_line_start && !g_state.dropping && IsNoise(s)) g_state.dropping = true;
    const size_t nl = s.find('\n');
    const std::string_view part = nl == std::string_view::npos ? s : s.substr(0, nl + 1);
    if (!g_state.dropping) WriteAll(part.data(), part.size());
    g_state.at_line_start = nl != std::string_view::npos;
    if (nl != std::string_view::npos) g_state.dropping = false;
    s.remove_prefix(part.size());
  }
  return static_cast<ssize_t>(size);
}

}  // namespace

void FilterLibraryNoiseOnStderr() {
  static bool installed = false;
  if (installed) return;
  cookie_io_functions_t io{};
  io.write = FilterWrite;
  FILE* f = fopencookie(nullptr, "w", io);
  if (!f) return;
  setvbuf(f, nullptr, _IONBF, 0);
  std::fflush(stderr);
  stderr = f;  // libpng and our own fprintf(stderr, ...) both go through it
  installed = true;
}

}  // namespace mesoscan
