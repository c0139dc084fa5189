#include "capture/gphoto2_camera.h"

#include <gphoto2/gphoto2-version.h>
#include <gphoto2/gphoto2.h>

#include "core/error.h"
#include "core/fs.h"

namespace mesoscan {

namespace {

std::string GpError(int code) { return gp_result_as_string(code); }

// RAII for the list types libgphoto2 hands out.
struct ListGuard {
  CameraList* list = nullptr;
  ListGuard() { gp_list_new(&list); }
  ~ListGuard() {
    if (list) gp_list_free(list);
  }
};

}  // namespace

struct Gphoto2Camera::Impl {
  GPContext* context = nullptr;
  Camera* camera = nullptr;
  ~Impl() {
    if (camera) {
      gp_camera_exit(camera, context);
      gp_camera_unref(camera);
    }
    if (context) gp_context_unref(context);
  }
};

std::vector<Gphoto2CameraInfo> DetectGphoto2Cameras() {
  GPContext* context = gp_context_new();
  ListGuard guard;
  std::vector<Gphoto2CameraInfo> cameras;
  const int n = gp_camera_autodetect(guard.list, context);
  for (int i = 0; i < n; ++i) {
    const char* name = nullptr;
    const char* value = nullptr;
    gp_list_get_name(guard.list, i, &name);
    gp_list_get_value(guard.list, i, &value);
    cameras.push_back({name ? name : "", value ? value : ""});
  }
  gp_context_unref(context);
  return cameras;
}

std::string Gphoto2Version() {
  const char** v = gp_library_version(GP_VERSION_SHORT);
  return v && v[0] ? v[0] : "unknown";
}

Gphoto2Camera::Gphoto2Camera(const std::string& port) : impl_(std::make_unique<Impl>()) {
  const std::vector<Gphoto2CameraInfo> found = DetectGphoto2Cameras();
  const Gphoto2CameraInfo* chosen = nullptr;
  for (const auto& c : found)
    if (port.empty() || c.port == port) {
      chosen = &c;
      break;
    }
  if (!chosen) {
    if (port.empty())
      MESOSCAN_THROW(ErrorKind::kDevice,
                     "camera: none detected by libgphoto2 (connected, switched on, not mounted by "
                     "the desktop?)");
    std::string list;
    for (const auto& c : found) list += (list.empty() ? "" : ", ") + c.model + " on " + c.port;
    MESOSCAN_THROW(ErrorKind::kDevice,
                   "camera: none detected by libgphoto2 on port "
                       << port << " (detected: " << (list.empty() ? "none" : list) << ")");
  }
  info_ = *chosen;
  const std::string who = "camera '" + info_.model + "' on " + info_.port;
  Impl& m = *impl_;
  m.context = gp_context_new();
  gp_camera_new(&m.camera);

  // Bind the camera object to the detected model and port (otherwise gp_camera_init would pick
  // the first camera again).
  CameraAbilitiesList* abilities = nullptr;
  gp_abilities_list_new(&abilities);
  gp_abilities_list_load(abilities, m.context);
  const int model = gp_abilities_list_lookup_model(abilities, info_.model.c_str());
  CameraAbilities a;
  const int ra = model < 0 ? model : gp_abilities_list_get_abilities(abilities, model, &a);
  if (ra >= GP_OK) gp_camera_set_abilities(m.camera, a);
  gp_abilities_list_free(abilities);
  if (ra < GP_OK)
    MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(who),
                      "unknown model (" << GpError(ra) << ")");

  GPPortInfoList* ports = nullptr;
  gp_port_info_list_new(&ports);
  gp_port_info_list_load(ports);
  const int p = gp_port_info_list_lookup_path(ports, info_.port.c_str());
  GPPortInfo port_info;
  const int rp = p < 0 ? p : gp_port_info_list_get_info(ports, p, &port_info);
  if (rp >= GP_OK) gp_camera_set_port_info(m.camera, port_info);
  gp_port_info_list_free(ports);
  if (rp < GP_OK)
    MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(who),
                      "unknown port (" << GpError(rp) << ")");

  const int ri = gp_camera_init(m.camera, m.context);
  if (ri < GP_OK)
    MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(who),
                      "cannot open (" << GpError(ri) << "; is another program using it?)");
}

Gphoto2Camera::~Gphoto2Camera() = default;

void Gphoto2Camera::CaptureToFile(const std::filesystem::path& path) {
  Impl& m = *impl_;
  const std::string who = "camera '" + info_.model + "' on " + info_.port;
  CameraFilePath on_card;
  const int rc = gp_camera_capture(m.camera, GP_CAPTURE_IMAGE, &on_card, m.context);
  if (rc < GP_OK)
    MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(who),
                      "capture failed (" << GpError(rc) << ")");
  CameraFile* file = nullptr;
  gp_file_new(&file);
  const int rg = gp_camera_file_get(m.camera, on_card.folder, on_card.name, GP_FILE_TYPE_NORMAL,
                                    file, m.context);
  if (rg < GP_OK) {
    gp_file_free(file);
    MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(who),
                      "download of " << on_card.folder << "/" << on_card.name << " failed ("
                                     << GpError(rg) << ")");
  }
  try {
    const char* data = nullptr;
    unsigned long size = 0;
    const int rs = gp_file_get_data_and_size(file, &data, &size);
    if (rs < GP_OK || data == nullptr)
      MESOSCAN_THROW_AT(ErrorKind::kDevice, ErrorSite::File(path),
                        "cannot save the capture (" << GpError(rs) << ")");
    WriteBytesFile(path, data, size);
  } catch (...) {
    gp_file_free(file);
    throw;
  }
  gp_file_free(file);
  // Keep the card from filling up during a 60-frame scan; a failure here is not fatal.
  gp_camera_file_delete(m.camera, on_card.folder, on_card.name, m.context);
}

}  // namespace mesoscan
