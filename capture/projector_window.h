#pragma once
// The projector output: a borderless X11 window covering the projector's area of the X screen
// that shows one pattern image at a time, pixel for pixel (no scaling, no colour management).
//
// Show() converts the displayed values in [0, 1] to 8 bits per channel (round(v * 255), grey on
// R = G = B) and puts them into a server-side pixmap that is the window's background, so the X
// server itself repaints exposures and no event loop is needed. Screenshot() reads the window back
// (XGetImage) for tests and for checking that the projector shows what was asked.

#include <memory>
#include <string>

#include "core/image.h"

namespace mesoscan {

struct ProjectorWindowOptions {
  std::string display;  // X display name (":0", ":0.1"); empty: $DISPLAY
  int x = 0, y = 0;     // top-left of the projector's output within the X screen, px (multi-head)
  int width = 0;        // window size in px; 0: the screen width minus x
  int height = 0;       // 0: the screen height minus y
  // Borderless and above everything (override-redirect: the window manager does not decorate,
  // move or resize it). false: a normal window with _NET_WM_STATE_FULLSCREEN (for a WM that
  // handles it, e.g. when the projector is the only output).
  bool override_redirect = true;
  double map_timeout_s = 5.0;  // > 0; deadline for the window to appear
  void Check() const;
};

// What `mesoscan doctor` reports about a display.
struct DisplayProbe {
  std::string name;           // the display name tried ($DISPLAY if none given; may be empty)
  bool opens = false;         // an X connection opened
  int width = 0, height = 0;  // default screen size, px
  int screens = 0;
  std::string error;  // why it did not open
};
DisplayProbe ProbeDisplay(const std::string& name = "");

class ProjectorWindow {
 public:
  // Opens the display and maps the window. Throws Error(kDevice) naming the display.
  explicit ProjectorWindow(const ProjectorWindowOptions& options);
  ~ProjectorWindow();
  ProjectorWindow(const ProjectorWindow&) = delete;
  ProjectorWindow& operator=(const ProjectorWindow&) = delete;

  int width() const;
  int height() const;
  // Shows a 1-channel (grey) or 3-channel (RGB) image of exactly width() x height(); values are
  // clamped to [0, 1], NaN shows black. Returns once the X server has processed it (XSync).
  void Show(const ImageF& image);
  // The window's current pixels, 3 channels R, G, B, 8 bits.
  ImageU8 Screenshot() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace mesoscan
