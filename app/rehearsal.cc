#include "app/rehearsal.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <thread>

#include "capture/lens_shifter_sim.h"
#include "capture/projector_window.h"
#include "core/error.h"
#include "core/log.h"

namespace mesoscan {

Rehearsal::Rehearsal(const std::string& display, int width, int height, bool with_shifter,
                     int range_lo, int range_hi) {
  display_ = display;
  if (display_.empty()) {
    const char* xvfb = "/usr/bin/Xvfb";
    if (::access(xvfb, X_OK) != 0)
      MESOSCAN_THROW(
          ErrorKind::kDevice,
          "capture --rehearse: " << xvfb << " not found (Debian package xvfb), or pass --display");
    char screen[64];
    std::snprintf(screen, sizeof(screen), "%dx%dx24", std::max(width, 64), std::max(height, 64));
    for (int attempt = 0; attempt < 20 && display_.empty(); ++attempt) {
      const int n = 900 + static_cast<int>((getpid() + attempt * 37) % 2000);
      char lock[64], name[16];
      std::snprintf(lock, sizeof(lock), "/tmp/.X%d-lock", n);
      std::snprintf(name, sizeof(name), ":%d", n);
      if (std::filesystem::exists(lock)) continue;
      const pid_t pid = fork();
      if (pid == 0) {
        const int null = ::open("/dev/null", O_WRONLY);
        dup2(null, 1);
        dup2(null, 2);
        execl(xvfb, "Xvfb", name, "-screen", "0", screen, "-nolisten", "tcp", "-noreset",
              static_cast<char*>(nullptr));
        _exit(127);
      }
      xvfb_pid_ = pid;
      for (int i = 0; i < 500; ++i) {  // up to 10 s
        if (ProbeDisplay(name).opens) {
          display_ = name;
          break;
        }
        int status = 0;
        if (waitpid(pid, &status, WNOHANG) == pid) {
          xvfb_pid_ = -1;
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      if (display_.empty() && xvfb_pid_ > 0) {
        kill(xvfb_pid_, SIGTERM);
        waitpid(xvfb_pid_, nullptr, 0);
        xvfb_pid_ = -1;
      }
    }
    if (display_.empty())
      MESOSCAN_THROW(ErrorKind::kDevice,
                     "capture --rehearse: could not start Xvfb (" << screen << ")");
    MESOSCAN_LOG(kInfo) << "rehearsal: Xvfb on display " << display_ << " (" << screen << ")";
  }
  if (with_shifter) {
    LensShifterSimOptions o;
    o.range_steps = {range_lo, range_hi};
    shifter_ = std::make_unique<LensShifterSim>(o);
    MESOSCAN_LOG(kInfo) << "rehearsal: simulated lens shifter on " << shifter_->Port();
  }
}

Rehearsal::~Rehearsal() {
  shifter_.reset();
  if (xvfb_pid_ > 0) {
    kill(xvfb_pid_, SIGTERM);
    waitpid(xvfb_pid_, nullptr, 0);
  }
}

std::string Rehearsal::shifter_port() const { return shifter_ ? shifter_->Port() : std::string(); }

}  // namespace mesoscan
