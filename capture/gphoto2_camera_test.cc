#include "capture/gphoto2_camera.h"

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/library_leaks.h"  // libgphoto2's libusb device lists

namespace mesoscan {
namespace {

std::string DeviceErrorOf(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice) << e.what();
    return e.what();
  }
  return "(no error)";
}

TEST(Gphoto2CameraTest, VersionIsReported) {
  MESOSCAN_IGNORE_LIBRARY_LEAKS();
  const std::string v = Gphoto2Version();
  EXPECT_FALSE(v.empty());
  EXPECT_NE(v, "unknown");
  EXPECT_NE(v.find('.'), std::string::npos) << v;
}

TEST(Gphoto2CameraTest, NoCameraIsAClearDeviceError) {
  MESOSCAN_IGNORE_LIBRARY_LEAKS();
  const std::vector<Gphoto2CameraInfo> cameras = DetectGphoto2Cameras();  // must not throw
  // A port no camera can be on: the error names it and lists what was found.
  std::string detected;
  for (const auto& c : cameras)
    detected += (detected.empty() ? "" : ", ") + c.model + " on " + c.port;
  EXPECT_EQ(DeviceErrorOf([] { Gphoto2Camera camera("usb:999,999"); }),
            "camera: none detected by libgphoto2 on port usb:999,999 (detected: " +
                (detected.empty() ? std::string("none") : detected) + ")");
  if (!cameras.empty()) GTEST_SKIP() << "a camera is connected: " << detected;
  EXPECT_EQ(DeviceErrorOf([] { Gphoto2Camera camera; }),
            "camera: none detected by libgphoto2 (connected, switched on, not mounted by the "
            "desktop?)");
}

}  // namespace
}  // namespace mesoscan
