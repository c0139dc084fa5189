#include "capture/projector_window.h"

#include <X11/Xatom.h>
#include <X11/Xlib.h>
#include <X11/Xutil.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <thread>
#include <vector>

#include "core/error.h"

namespace mesoscan {

namespace {

std::string DisplayName(const std::string& name) {
  if (!name.empty()) return name;
  const char* env = std::getenv("DISPLAY");
  return env ? env : "";
}

// Xlib's default error handler exits the process; turn protocol errors into a flag instead.
// (Xlib calls it from the thread that made the request; windows are driven from one thread.)
int g_x_error = 0;
int RecordXError(Display*, XErrorEvent* e) {
  g_x_error = e->error_code;
  return 0;
}

// Position of a colour channel in a TrueColor pixel: shift of the lowest set bit of its mask.
int MaskShift(unsigned long mask) { return mask ? std::countr_zero(mask) : 0; }

uint8_t ToByte(float v) {
  if (!(v > 0)) return 0;  // also NaN
  if (v >= 1) return 255;
  return static_cast<uint8_t>(std::lround(v * 255.0f));
}

}  // namespace

void ProjectorWindowOptions::Check() const {
  if (width < 0 || height < 0 || x < 0 || y < 0)
    MESOSCAN_BAD_INPUT("projector window: x, y, width, height: expected >= 0");
  if (!(map_timeout_s > 0)) MESOSCAN_BAD_INPUT("projector window: map_timeout_s: expected > 0");
}

DisplayProbe ProbeDisplay(const std::string& name) {
  DisplayProbe probe;
  probe.name = DisplayName(name);
  if (probe.name.empty()) {
    probe.error = "DISPLAY is not set";
    return probe;
  }
  Display* d = XOpenDisplay(probe.name.c_str());
  if (!d) {
    probe.error = "cannot open X display '" + probe.name + "'";
    return probe;
  }
  probe.opens = true;
  probe.screens = ScreenCount(d);
  probe.width = DisplayWidth(d, DefaultScreen(d));
  probe.height = DisplayHeight(d, DefaultScreen(d));
  XCloseDisplay(d);
  return probe;
}

struct ProjectorWindow::Impl {
  std::string name;
  Display* display = nullptr;
  Window window = 0;
  Pixmap pixmap = 0;
  GC gc = nullptr;
  Colormap colormap = 0;
  Visual* visual = nullptr;
  int depth = 0;
  int width = 0, height = 0;
  int red_shift = 0, green_shift = 0, blue_shift = 0;

  [[noreturn]] void Fail(const std::string& what) const {
    MESOSCAN_THROW(ErrorKind::kDevice, "X display '" << name << "': " << what);
  }

  ~Impl() {
    if (!display) return;
    if (gc) XFreeGC(display, gc);
    if (pixmap) XFreePixmap(display, pixmap);
    if (window) XDestroyWindow(display, window);
    if (colormap) XFreeColormap(display, colormap);
    XCloseDisplay(display);
  }
};

ProjectorWindow::ProjectorWindow(const ProjectorWindowOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Check();
  Impl& m = *impl_;
  m.name = DisplayName(options.display);
  if (m.name.empty())
    MESOSCAN_THROW(ErrorKind::kDevice, "projector window: DISPLAY is not set and no display given");
  m.display = XOpenDisplay(m.name.c_str());
  if (!m.display) MESOSCAN_THROW(ErrorKind::kDevice, "cannot open X display '" << m.name << "'");
  XSetErrorHandler(RecordXError);
  g_x_error = 0;
  const int screen = DefaultScreen(m.display);
  const int screen_w = DisplayWidth(m.display, screen), screen_h = DisplayHeight(m.display, screen);
  m.width = options.width ? options.width : screen_w - options.x;
  m.height = options.height ? options.height : screen_h - options.y;
  if (m.width <= 0 || m.height <= 0 || options.x + m.width > screen_w ||
      options.y + m.height > screen_h)
    m.Fail("window " + std::to_string(m.width) + "x" + std::to_string(m.height) + " at " +
           std::to_string(options.x) + "," + std::to_string(options.y) + " does not fit the " +
           std::to_string(screen_w) + "x" + std::to_string(screen_h) + " screen");

  // A TrueColor visual of depth 24 or 32: exact 8-bit grey levels, no palette.
  XVisualInfo want{};
  want.screen = screen;
  want.c_class = TrueColor;
  int count = 0;
  XVisualInfo* infos = XGetVisualInfo(m.display, VisualScreenMask | VisualClassMask, &want, &count);
  for (int i = 0; i < count && !m.visual; ++i) {
    if (infos[i].depth != 24 && infos[i].depth != 32) continue;
    m.visual = infos[i].visual;
    m.depth = infos[i].depth;
    m.red_shift = MaskShift(infos[i].red_mask);
    m.green_shift = MaskShift(infos[i].green_mask);
    m.blue_shift = MaskShift(infos[i].blue_mask);
  }
  if (infos) XFree(infos);
  if (!m.visual) m.Fail("no 24-bit TrueColor visual (8 bits per channel are needed)");

  const Window root = RootWindow(m.display, screen);
  XSetWindowAttributes attrs{};
  attrs.override_redirect = options.override_redirect ? True : False;
  attrs.background_pixel = 0;
  attrs.border_pixel = 0;
  m.colormap = XCreateColormap(m.display, root, m.visual, AllocNone);
  attrs.colormap = m.colormap;
  attrs.event_mask = StructureNotifyMask | ExposureMask;
  m.window = XCreateWindow(
      m.display, root, options.x, options.y, m.width, m.height, 0, m.depth, InputOutput, m.visual,
      CWOverrideRedirect | CWBackPixel | CWBorderPixel | CWColormap | CWEventMask, &attrs);
  XStoreName(m.display, m.window, "mesoscan projector");
  if (!options.override_redirect) {
    const Atom state = XInternAtom(m.display, "_NET_WM_STATE", False);
    const Atom fullscreen = XInternAtom(m.display, "_NET_WM_STATE_FULLSCREEN", False);
    XChangeProperty(m.display, m.window, state, XA_ATOM, 32, PropModeReplace,
                    reinterpret_cast<const unsigned char*>(&fullscreen), 1);
  }
  m.pixmap = XCreatePixmap(m.display, m.window, m.width, m.height, m.depth);
  m.gc = XCreateGC(m.display, m.pixmap, 0, nullptr);
  XSetForeground(m.display, m.gc, 0);
  XFillRectangle(m.display, m.pixmap, m.gc, 0, 0, m.width, m.height);
  XSetWindowBackgroundPixmap(m.display, m.window, m.pixmap);
  XMapRaised(m.display, m.window);
  XSync(m.display, False);
  if (g_x_error) m.Fail("X protocol error " + std::to_string(g_x_error) + " creating the window");

  // Wait (bounded) until the server reports the window mapped.
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(options.map_timeout_s);
  for (bool mapped = false; !mapped;) {
    XEvent e;
    while (XCheckTypedWindowEvent(m.display, m.window, MapNotify, &e)) mapped = true;
    if (mapped) break;
    if (std::chrono::steady_clock::now() > deadline)
      m.Fail("the projector window did not appear within " + std::to_string(options.map_timeout_s) +
             " s");
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
}

ProjectorWindow::~ProjectorWindow() = default;

int ProjectorWindow::width() const { return impl_->width; }
int ProjectorWindow::height() const { return impl_->height; }

void ProjectorWindow::Show(const ImageF& image) {
  Impl& m = *impl_;
  if (image.width() != m.width || image.height() != m.height ||
      (image.channels() != 1 && image.channels() != 3))
    MESOSCAN_BAD_INPUT("projector window: image " << image.width() << "x" << image.height() << "x"
                                                  << image.channels() << ", expected " << m.width
                                                  << "x" << m.height << " with 1 or 3 channels");
  g_x_error = 0;
  // 32-bit ZPixmap in the visual's channel layout; XPutImage converts byte order if needed.
  const size_t n = image.pixels();
  std::vector<uint32_t> pixels(n);
  const int g = image.channels() == 3 ? 1 : 0, b = image.channels() == 3 ? 2 : 0;
  const float* r_in = image.channel(0);
  const float* g_in = image.channel(g);
  const float* b_in = image.channel(b);
  for (size_t i = 0; i < n; ++i)
    pixels[i] = (uint32_t{ToByte(r_in[i])} << m.red_shift) |
                (uint32_t{ToByte(g_in[i])} << m.green_shift) |
                (uint32_t{ToByte(b_in[i])} << m.blue_shift);
  XImage* xi = XCreateImage(m.display, m.visual, m.depth, ZPixmap, 0,
                            reinterpret_cast<char*>(pixels.data()), m.width, m.height, 32, 0);
  if (!xi) m.Fail("XCreateImage failed");
  xi->byte_order = std::endian::native == std::endian::little ? LSBFirst : MSBFirst;  // host order
  XPutImage(m.display, m.pixmap, m.gc, xi, 0, 0, 0, 0, m.width, m.height);
  xi->data = nullptr;  // owned by `pixels`
  XDestroyImage(xi);
  XClearWindow(m.display, m.window);  // repaint from the background pixmap
  XSync(m.display, False);
  if (g_x_error) m.Fail("X protocol error " + std::to_string(g_x_error) + " showing a pattern");
}

ImageU8 ProjectorWindow::Screenshot() const {
  const Impl& m = *impl_;
  XSync(m.display, False);
  XImage* xi = XGetImage(m.display, m.window, 0, 0, m.width, m.height, AllPlanes, ZPixmap);
  if (!xi) m.Fail("XGetImage failed (window not viewable?)");
  ImageU8 out(m.width, m.height, 3);
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x) {
      const unsigned long p = XGetPixel(xi, x, y);
      out(x, y, 0) = static_cast<uint8_t>((p & xi->red_mask) >> MaskShift(xi->red_mask));
      out(x, y, 1) = static_cast<uint8_t>((p & xi->green_mask) >> MaskShift(xi->green_mask));
      out(x, y, 2) = static_cast<uint8_t>((p & xi->blue_mask) >> MaskShift(xi->blue_mask));
    }
  XDestroyImage(xi);
  return out;
}

}  // namespace mesoscan
