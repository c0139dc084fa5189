#pragma once
// Test helpers of the capture module (capture unit tests and the `mesoscan capture` CLI test): a
// private X server (Xvfb) for the projector window, and a small valid rig.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include "capture/projector_window.h"
#include "session/session.h"

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

// A GoogleTest fixture base: one Xvfb server per test suite (display()); a test skips when Xvfb
// is not installed.
class XvfbTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = new XvfbServer(); }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  void SetUp() override {
    if (server_->display().empty()) GTEST_SKIP() << "Xvfb not available";
  }
  static const std::string& display() { return server_->display(); }
  static inline XvfbServer* server_ = nullptr;
};

// A small valid rig for tests: camera (fx = fy = 100) and projector (fx = fy = 200) looking
// straight down from 0.25 m, 5 cm apart, principal points at the image centres; an optional lens
// shifter along x, 2048 steps per px over [-2048, 2048).
inline Rig SmallTestRig(int cam_w, int cam_h, int proj_w, int proj_h, bool lens_shifter) {
  Rig rig;
  rig.camera.width = cam_w;
  rig.camera.height = cam_h;
  rig.camera.K << 100, 0, (cam_w - 1) / 2.0, 0, 100, (cam_h - 1) / 2.0, 0, 0, 1;
  rig.camera.world_from_device.rotation = Eigen::Vector3d(1, -1, -1).asDiagonal();
  rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  rig.projector.width = proj_w;
  rig.projector.height = proj_h;
  rig.projector.K << 200, 0, (proj_w - 1) / 2.0, 0, 200, (proj_h - 1) / 2.0, 0, 0, 1;
  rig.projector.world_from_device = rig.camera.world_from_device;
  rig.projector.world_from_device.translation = Vec3d(0.05, 0, 0.25);
  if (lens_shifter) rig.lens_shifter = LensShifter{'x', 2048, {-2048, 2048}};
  return rig;
}

}  // namespace mesoscan
