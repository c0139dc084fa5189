#pragma once
// The camera driver: a libgphoto2 wrapper (autodetect, capture one image to a file). libgphoto2
// headers appear only in gphoto2_camera.cc (architecture.md). Every failure is Error(kDevice)
// naming the camera or saying that none was found.

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace mesoscan {

struct Gphoto2CameraInfo {
  std::string model;  // e.g. "Nikon DSC D800E"
  std::string port;   // e.g. "usb:001,004"
};

// Cameras libgphoto2 detects now (none is fine: returns an empty list).
std::vector<Gphoto2CameraInfo> DetectGphoto2Cameras();
// "2.5.30" (the linked library's version).
std::string Gphoto2Version();

class Gphoto2Camera {
 public:
  // Opens the camera on `port` (as DetectGphoto2Cameras reports it), or the first one detected
  // if `port` is empty. Throws Error(kDevice):
  //   "camera: none detected by libgphoto2 (connected, switched on, not mounted by the desktop?)"
  //   "camera: none detected by libgphoto2 on port <port> (detected: <model> on <port>, ...)"
  explicit Gphoto2Camera(const std::string& port = "");
  ~Gphoto2Camera();
  Gphoto2Camera(const Gphoto2Camera&) = delete;
  Gphoto2Camera& operator=(const Gphoto2Camera&) = delete;

  const Gphoto2CameraInfo& info() const { return info_; }
  // Triggers one capture and downloads the image to `path` (atomically: temp + rename), then
  // deletes it from the camera's card. The extension should match the camera's output format
  // (.nef, .cr2, .jpg ...).
  void CaptureToFile(const std::filesystem::path& path);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  Gphoto2CameraInfo info_;
};

}  // namespace mesoscan
