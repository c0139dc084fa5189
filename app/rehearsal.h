#pragma once
// `mesoscan capture --rehearse`: a full capture without hardware. The
// projector window opens on a private Xvfb server, the screen camera reads it back, and the
// lens-shifter controller is the simulator of capture/lens_shifter_sim.h on a pseudo-terminal,
// driven through the same serial protocol as the real one.

#include <memory>
#include <string>

namespace mesoscan {

class LensShifterSim;

class Rehearsal {
 public:
  // Starts Xvfb (screen at least width x height) unless `display` is non-empty, and a shifter
  // simulator over `range` if `with_shifter`. Throws Error(kDevice) if Xvfb cannot start.
  Rehearsal(const std::string& display, int width, int height, bool with_shifter, int range_lo,
            int range_hi);
  ~Rehearsal();  // stops the simulator and the X server
  Rehearsal(const Rehearsal&) = delete;
  Rehearsal& operator=(const Rehearsal&) = delete;

  const std::string& display() const { return display_; }
  std::string shifter_port() const;  // empty without a shifter

 private:
  int xvfb_pid_ = -1;
  std::string display_;
  std::unique_ptr<LensShifterSim> shifter_;
};

}  // namespace mesoscan
