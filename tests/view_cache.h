#pragma once
// Simulated calibration views built once per build of a test binary and kept in the build tree:
// ctest runs every test in its own process, and simulating and decoding a dozen board views
// costs tens of seconds a process. A cache is keyed on the test binary's size and time (the
// simulator and the decoder are linked in statically, so any change to either makes a new key);
// a lock file serialises parallel test processes, and the first one to build a new key removes
// the older caches of the same name.

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/calibrate.h"
#include "core/fs.h"
#include "core/json.h"
#include "session/session.h"
#include "sim/board_sim.h"

namespace mesoscan::testing_support {

namespace fs = std::filesystem;

// An exclusive flock() on `path` while alive.
class FileLock {
 public:
  explicit FileLock(const fs::path& path) : fd_(open(path.c_str(), O_CREAT | O_RDWR, 0644)) {
    if (fd_ < 0 || flock(fd_, LOCK_EX) != 0)
      throw std::runtime_error("cannot lock " + path.string());
  }
  ~FileLock() {
    flock(fd_, LOCK_UN);
    close(fd_);
  }
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

 private:
  int fd_;
};

// <build>/test-cache/<name>_<key> for this test binary.
inline fs::path CacheDir(const std::string& name) {
  const fs::path exe = fs::read_symlink("/proc/self/exe");
  const std::string key = std::to_string(fs::file_size(exe)) + "_" +
                          std::to_string(fs::last_write_time(exe).time_since_epoch().count());
  return fs::path(MESOSCAN_BINARY_DIR) / "test-cache" / (name + "_" + key);
}

// The cache folder `name`, made by build(folder) if this binary has not made it yet.
inline fs::path BuiltOnce(const std::string& name,
                          const std::function<void(const fs::path&)>& build) {
  const fs::path cache = CacheDir(name);
  fs::create_directories(cache.parent_path());
  const FileLock lock(cache.parent_path() / (name + ".lock"));
  if (!fs::exists(cache / "complete")) {
    for (const auto& e : fs::directory_iterator(cache.parent_path()))
      if (e.path().filename().string().rfind(name + "_", 0) == 0) fs::remove_all(e.path());
    fs::create_directories(cache);
    build(cache);
    WriteTextFile(cache / "complete", name + "\n");
  }
  return cache;
}

// One board session per pose (seeds seed0, seed0 + 1, ...), simulated once into the cache folder
// `name`: the sessions' folders, view0, view1, ...
inline std::vector<fs::path> BoardViewsOnce(const std::string& name, SimulateOptions so,
                                            BoardSimOptions bo,
                                            const std::vector<std::array<double, 6>>& poses,
                                            uint64_t seed0) {
  const fs::path cache = BuiltOnce(name, [&](const fs::path& c) {
    for (size_t i = 0; i < poses.size(); ++i) {
      bo.pose = poses[i];
      so.seed = seed0 + i;
      SimulateBoard(so, bo, c / ("view" + std::to_string(i)));
    }
  });
  std::vector<fs::path> sessions;
  for (size_t i = 0; i < poses.size(); ++i)
    sessions.push_back(cache / ("view" + std::to_string(i)));
  return sessions;
}

namespace view_json {

inline Json Points(const std::vector<Vec2d>& p) {
  Json a = Json::array();
  for (const Vec2d& v : p) {
    if (std::isfinite(v.x()) && std::isfinite(v.y()))
      a.push_back({v.x(), v.y()});
    else
      a.push_back(nullptr);  // not seen / not decoded
  }
  return a;
}

inline std::vector<Vec2d> Points(const Json& a) {
  std::vector<Vec2d> p;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const Json& v : a)
    p.push_back(v.is_null() ? Vec2d(nan, nan) : Vec2d(v[0].get<double>(), v[1].get<double>()));
  return p;
}

inline Json ToJson(const CalibrationView& v) {
  return {{"name", v.name},
          {"found", v.found},
          {"problem", v.problem},
          {"codec", v.codec},
          {"size", {v.width, v.height}},
          {"projector_size", {v.projector_width, v.projector_height}},
          {"camera_px", Points(v.camera_px)},
          {"projector_px", Points(v.projector_px)},
          {"projector_inliers", v.projector_inliers},
          {"decode_seconds", v.decode_seconds}};
}

inline CalibrationView FromJson(const Json& j) {
  CalibrationView v;
  v.name = j["name"];
  v.found = j["found"];
  v.problem = j["problem"];
  v.codec = j["codec"];
  v.width = j["size"][0];
  v.height = j["size"][1];
  v.projector_width = j["projector_size"][0];
  v.projector_height = j["projector_size"][1];
  v.camera_px = Points(j["camera_px"]);
  v.projector_px = Points(j["projector_px"]);
  v.projector_inliers = j["projector_inliers"].get<std::vector<int>>();
  v.decode_seconds = j["decode_seconds"];
  return v;
}

}  // namespace view_json

// DetectView on every session, kept in `cache`/`tag`.json: what the detector found (corners in
// the camera and the projector, exactly as doubles) is read back by every later test process.
inline std::vector<CalibrationView> DetectViewsOnce(const fs::path& cache, const std::string& tag,
                                                    const std::vector<fs::path>& sessions,
                                                    const CalibrateOptions& options) {
  const FileLock lock(cache / (tag + ".lock"));
  const fs::path file = cache / (tag + ".json");
  std::vector<CalibrationView> views;
  if (fs::exists(file)) {
    for (const Json& j : ReadJsonFile(file)) views.push_back(view_json::FromJson(j));
    if (views.size() == sessions.size()) return views;
    views.clear();
  }
  Json all = Json::array();
  for (const fs::path& s : sessions) {
    views.push_back(DetectView(ReadSession(s), options));
    all.push_back(view_json::ToJson(views.back()));
  }
  WriteJsonFile(file, all);
  return views;
}

}  // namespace mesoscan::testing_support
