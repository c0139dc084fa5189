// mesoscan doctor: what this build and this machine offer a scan. Library versions, the cameras
// libgphoto2 sees, serial ports (the lens shifter), and the X display (the projector window).
// Always exits 0: it reports problems, it does not fail on them.

#include <OpenEXR/OpenEXRConfig.h>
#include <OpenImageIO/oiioversion.h>
#include <ceres/version.h>
#include <oneapi/tbb/version.h>

#include <Eigen/Core>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core/version.hpp>
#include <sstream>
#include <thread>

#include "app/commands.h"
#include "capture/gphoto2_camera.h"
#include "capture/lens_shifter.h"
#include "capture/projector_window.h"
#include "core/error.h"
#include "core/module.h"
#include "core/oiio_module.h"
#include "render/embree_scene.h"
#include "session/raw_frame.h"

namespace mesoscan {
namespace {

std::string Version3(int a, int b, int c) {
  std::ostringstream oss;
  oss << a << "." << b << "." << c;
  return oss.str();
}

// Runs one probe; an exception becomes a line instead of ending the report.
template <typename Fn>
void Probe(std::ostream& out, const char* what, Fn&& fn) {
  try {
    fn();
  } catch (const std::exception& e) {
    out << what << ": error: " << e.what() << "\n";
  }
}

}  // namespace

void AddDoctorCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "doctor", "Report library versions, cameras, serial ports and the display; always exit 0");
  auto display = std::make_shared<std::string>();
  cmd->add_option("--display", *display, "X display to probe (default: $DISPLAY)");
  cmd->callback([display] {
    std::ostringstream out;
    out << "mesoscan 0.1.0\n";
    out << "libraries (headers this build was compiled against):\n"
        << "  OpenImageIO " << OIIO_VERSION_STRING << "\n"
        << "  OpenEXR " << OPENEXR_VERSION_STRING << "\n"
        << "  Eigen " << Version3(EIGEN_WORLD_VERSION, EIGEN_MAJOR_VERSION, EIGEN_MINOR_VERSION)
        << "\n"
        << "  oneTBB " << TBB_VERSION_STRING << "\n"
        << "  Ceres " << CERES_VERSION_STRING << "\n"
        << "  nlohmann-json "
        << Version3(NLOHMANN_JSON_VERSION_MAJOR, NLOHMANN_JSON_VERSION_MINOR,
                    NLOHMANN_JSON_VERSION_PATCH)
        << "\n"
        << "  CLI11 " << CLI11_VERSION << "\n"
        << "  OpenCV " << CV_VERSION << "\n"
        << "  Embree " << EmbreeVersion() << "\n";
    Probe(out, "  OpenImageIO module", [&] {
      const std::string version = Oiio().Version();
      out << "  OpenImageIO " << version << " (runtime, module " << LoadedModulePath("oiio")
          << ")\n";
    });
    Probe(out, "  LibRaw", [&] {
      const std::string libraw = LibRawVersion();
      out << "  LibRaw " << libraw << " (camera raw frames)\n";
    });
    Probe(out, "  libgphoto2",
          [&] { out << "  libgphoto2 " << Gphoto2Version() << " (runtime)\n"; });

    Probe(out, "cameras", [&] {
      const std::vector<Gphoto2CameraInfo> cameras = DetectGphoto2Cameras();
      out << "cameras (libgphoto2): " << (cameras.empty() ? "none detected" : "") << "\n";
      for (const auto& c : cameras) out << "  " << c.model << " on " << c.port << "\n";
    });

    Probe(out, "serial ports", [&] {
      const std::vector<std::string> ports = ListSerialPorts();
      out << "serial ports (/dev/ttyUSB*, /dev/ttyACM*, /dev/serial/by-id): "
          << (ports.empty() ? "none" : "") << "\n";
      for (const auto& p : ports) out << "  " << p << "\n";
    });

    Probe(out, "display", [&] {
      const DisplayProbe d = ProbeDisplay(*display);
      out << "display: ";
      if (d.opens)
        out << d.name << " opens, " << d.screens << " screen(s), default " << d.width << "x"
            << d.height << "\n";
      else
        out << (d.name.empty() ? std::string("none") : d.name) << ": " << d.error << "\n";
    });
    out << "hardware threads: " << std::thread::hardware_concurrency() << "\n";
    std::cout << out.str() << std::flush;
  });
}

}  // namespace mesoscan
