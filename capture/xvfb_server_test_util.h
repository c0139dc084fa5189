#pragma once
// A private X server (Xvfb) for tests that open the projector window (capture/projector_window.h):
// the capture unit tests and the `mesoscan capture` CLI test.

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include "capture/projector_window.h"

namespace mesoscan {

// A private X server (Xvfb) for the test suite: 320x240, 24-bit.
class XvfbServer {
 public:
  XvfbServer() {
    if (::access("/usr/bin/Xvfb", X_OK) != 0) return;
    // A display number unlikely to collide with parallel tests: 100 + pid % 800, skipping locks.
    for (int attempt = 0; attempt < 20 && display_.empty(); ++attempt) {
      const int n = 100 + static_cast<int>((getpid() + attempt * 37) % 800);
      char lock[64], name[16];  // snprintf: GCC 12 -Wrestrict misfires on "literal" + string
      std::snprintf(lock, sizeof(lock), "/tmp/.X%d-lock", n);
      std::snprintf(name, sizeof(name), ":%d", n);
      if (std::filesystem::exists(lock)) continue;
      pid_ = fork();
      if (pid_ == 0) {
        const int null = ::open("/dev/null", O_WRONLY);
        dup2(null, 1);
        dup2(null, 2);
        execl("/usr/bin/Xvfb", "Xvfb", name, "-screen", "0", "320x240x24", "-nolisten", "tcp",
              "-noreset", static_cast<char*>(nullptr));
        _exit(127);
      }
      // Wait up to 5 s for the server to accept connections.
      for (int i = 0; i < 250; ++i) {
        if (ProbeDisplay(name).opens) {
          display_ = name;
          break;
        }
        int status = 0;
        if (waitpid(pid_, &status, WNOHANG) == pid_) {  // died (display taken?): next number
          pid_ = -1;
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      if (display_.empty() && pid_ > 0) Stop();
    }
  }
  ~XvfbServer() { Stop(); }
  const std::string& display() const { return display_; }

 private:
  void Stop() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);
    int status = 0;
    waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  pid_t pid_ = -1;
  std::string display_;
};

}  // namespace mesoscan
