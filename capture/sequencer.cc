#include "capture/sequencer.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>
#include <thread>

#include "capture/gphoto2_camera.h"
#include "capture/lens_shifter.h"
#include "capture/projector_window.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/progress.h"
#include "session/patterns.h"
#include "session/raw_frame.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr const char* kJournalFormat = "mesoscan-capture-journal/1";

std::string Hex(uint64_t v) {
  std::ostringstream oss;
  oss << std::hex << v;
  return oss.str();
}

// Runs one device call; anything but a mesoscan::Error becomes Error(kDevice) naming the device,
// so the user always gets one line that says which device failed.
template <typename Fn>
auto DeviceCall(const std::string& device, Fn&& fn) -> decltype(fn()) {
  try {
    return fn();
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    MESOSCAN_THROW(ErrorKind::kDevice, device << ": " << e.what());
  }
}

struct JournalEntry {
  std::string file;
  uint64_t bytes = 0;
  std::string hash;
};

struct Journal {
  std::string created;
  Json plan;
  std::map<size_t, JournalEntry> frames;
};

// Reads the journal; a torn last line (a crash while appending) ends the list of frames.
// Returns false if the header cannot be read.
bool ReadJournal(const fs::path& path, Journal* journal) {
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line)) return false;
  try {
    const Json header = Json::parse(line);
    if (header.value("journal", "") != kJournalFormat || !header.contains("plan")) return false;
    journal->created = header.value("created", "");
    journal->plan = header["plan"];
  } catch (const std::exception&) {
    return false;
  }
  while (std::getline(in, line)) {
    try {
      const Json e = Json::parse(line);
      journal->frames[e.at("frame").get<size_t>()] = {e.at("file").get<std::string>(),
                                                      e.at("bytes").get<uint64_t>(),
                                                      e.at("fnv1a64").get<std::string>()};
    } catch (const std::exception&) {
      break;
    }
  }
  return true;
}

// Appends one line and makes it durable before the next frame is taken.
void AppendLine(const fs::path& path, const std::string& line) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "cannot append to the capture journal (" << std::strerror(errno) << ")");
  const std::string text = line + "\n";
  const ssize_t w = ::write(fd, text.data(), text.size());
  const int write_errno = w < 0 ? errno : ENOSPC;  // a short append: the disk is full
  const bool written = w == static_cast<ssize_t>(text.size());
  const bool synced = written && ::fsync(fd) == 0;
  const int sync_errno = errno;
  ::close(fd);
  if (!written || !synced)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "cannot append to the capture journal ("
                              << std::strerror(written ? sync_errno : write_errno) << ")");
}

Json HeaderLine(const std::string& created, const Json& plan) {
  return Json{{"journal", kJournalFormat}, {"created", created}, {"plan", plan}};
}

Json EntryLine(size_t i, const JournalEntry& e) {
  return Json{{"frame", i}, {"file", e.file}, {"bytes", e.bytes}, {"fnv1a64", e.hash}};
}

}  // namespace

ImageU8 ProjectorDevice::Screenshot() const {
  MESOSCAN_THROW(ErrorKind::kDevice, Name() << ": cannot be read back");
}

void SequencerOptions::Check() const {
  if (!(settle_s >= 0.0 && std::isfinite(settle_s)))
    MESOSCAN_BAD_OPTION("SequencerOptions.settle_s", "expected seconds >= 0, got " << settle_s);
  if (max_new_frames < -1)
    MESOSCAN_BAD_OPTION("SequencerOptions.max_new_frames",
                        "expected -1 (no limit) or >= 0, got " << max_new_frames);
}

std::string SequencerSummary::BriefReport() const {
  std::ostringstream oss;
  oss << "capture: " << reused + captured << " of " << frames << " frames (" << reused
      << " reused, " << captured << " captured) in " << std::fixed << std::setprecision(1)
      << seconds << " s; "
      << (complete ? "session.json written" : "incomplete, run the same command again to resume");
  return oss.str();
}

uint64_t HashFile(const fs::path& path, uint64_t* size) {
  std::ifstream in(path, std::ios::binary);
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot read");
  uint64_t h = 1469598103934665603ull, n = 0;
  char buf[1 << 16];
  while (in) {
    in.read(buf, sizeof(buf));
    const std::streamsize got = in.gcount();
    for (std::streamsize i = 0; i < got; ++i) {
      h ^= static_cast<uint8_t>(buf[i]);
      h *= 1099511628211ull;
    }
    n += static_cast<uint64_t>(got);
  }
  if (size) *size = n;
  return h;
}

Session PlanForCamera(const Session& plan, const CameraDevice& camera) {
  Session s = plan;
  const std::string ext = camera.FrameExtension();
  for (Frame& f : s.frames) f.file = fs::path(f.file).replace_extension(ext).string();
  return s;
}

SequencerSummary RunAcquisition(const Session& plan_in, CameraDevice& camera,
                                ProjectorDevice& projector, ShifterDevice* shifter,
                                const SequencerOptions& options) {
  options.Check();
  const auto start = std::chrono::steady_clock::now();
  Session s = PlanForCamera(plan_in, camera);
  const fs::path& root = s.root;
  const size_t n = s.frames.size();

  // Step 1: the plan must be a valid session (the reader's checks, without frame files), the
  // devices must match the rig.
  {
    Json check = SessionToJson(s);
    check["created"] = "2000-01-01T00:00:00Z";
    ParseSession(check, root, "capture plan");
  }
  size_t shifted = 0;
  for (const Frame& f : s.frames) shifted += f.shift_steps != 0;
  if (shifted > 0 && !shifter)
    MESOSCAN_THROW(ErrorKind::kUsage, "capture: " << shifted
                                                  << " frames of the plan need the lens shifter "
                                                     "(shift_steps != 0) but none was given");
  const int pw = DeviceCall(projector.Name(), [&] { return projector.width(); });
  const int ph = DeviceCall(projector.Name(), [&] { return projector.height(); });
  if (pw != s.rig.projector.width || ph != s.rig.projector.height)
    MESOSCAN_THROW(ErrorKind::kDevice, projector.Name() << ": shows " << pw << "x" << ph
                                                        << " px, the rig's projector is "
                                                        << s.rig.projector.width << "x"
                                                        << s.rig.projector.height);

  // Step 2: a completed session is left alone unless forced.
  const fs::path manifest = root / "session.json";
  const fs::path journal_path = root / kCaptureJournal;
  if (fs::exists(manifest) && fs::exists(journal_path) && !options.force) {
    // Killed between writing session.json and removing the journal (step 5): if the journal is
    // this plan's and session.json is the completed plan, finish that step and report done.
    Json plan_json = SessionToJson(s);
    plan_json.erase("created");
    Journal left;
    bool same = ReadJournal(journal_path, &left) && left.plan == plan_json;
    if (same) {
      try {
        Json written = ReadJsonFile(manifest);
        written.erase("created");
        same = written == plan_json;
      } catch (const Error&) {
        same = false;
      }
    }
    if (same) {
      fs::remove(journal_path);
      SequencerSummary done;
      done.frames = static_cast<int>(n);
      done.reused = static_cast<int>(n);
      done.complete = true;
      done.seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      MESOSCAN_LOG(kInfo) << manifest.string()
                          << ": complete; removed the capture journal an interrupted run left";
      return done;
    }
  }
  if (fs::exists(manifest)) {
    if (!options.force)
      MESOSCAN_THROW_AT(ErrorKind::kUsage, ErrorSite::File(manifest),
                        "a completed session is there; pass " << OptionRef{"SequencerOptions.force"}
                                                              << " to capture it again");
    fs::remove(manifest);
    fs::remove(journal_path);
  }
  for (const Frame& f : s.frames) fs::create_directories((root / f.file).parent_path());

  // Step 3: the journal: same plan -> verify its frames in order; another plan -> refuse.
  Json plan_json = SessionToJson(s);
  plan_json.erase("created");
  Journal journal;
  const bool have_journal = fs::exists(journal_path) && ReadJournal(journal_path, &journal);
  if (fs::exists(journal_path) && (!have_journal || journal.plan != plan_json)) {
    if (!options.force)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(journal_path),
                            "written for another plan, rig or camera (or unreadable); pass "
                                << OptionRef{"SequencerOptions.force"} << " to start over");
    journal = Journal();
  } else if (!have_journal) {
    journal = Journal();
  }
  if (journal.created.empty()) journal.created = s.created.empty() ? SessionTimeNow() : s.created;
  s.created = journal.created;

  size_t first_missing = 0;
  std::vector<JournalEntry> entries(n);
  for (; first_missing < n; ++first_missing) {
    const auto it = journal.frames.find(first_missing);
    if (it == journal.frames.end() || it->second.file != s.frames[first_missing].file) break;
    const fs::path path = s.FramePath(first_missing);
    if (!fs::exists(path)) break;
    uint64_t bytes = 0;
    const std::string hash = Hex(HashFile(path, &bytes));
    if (bytes != it->second.bytes || hash != it->second.hash) {
      MESOSCAN_LOG(kWarning) << path.string()
                             << ": differs from the capture journal; capturing again from here";
      break;
    }
    entries[first_missing] = it->second;
  }
  // The journal from now on: header + the verified frames (stale entries after them dropped).
  {
    std::string text = HeaderLine(journal.created, plan_json).dump() + "\n";
    for (size_t i = 0; i < first_missing; ++i) text += EntryLine(i, entries[i]).dump() + "\n";
    WriteTextFile(journal_path, text);
  }

  SequencerSummary summary;
  summary.frames = static_cast<int>(n);
  summary.reused = static_cast<int>(first_missing);
  if (first_missing > 0)
    MESOSCAN_LOG(kInfo) << root.string() << ": resuming at frame " << first_missing << " of " << n
                        << " (" << first_missing << " verified)";

  // Step 4: show, move, settle, trigger, journal, for every missing frame.
  const auto interrupted = [&] {
    return options.interrupt && options.interrupt->load(std::memory_order_relaxed);
  };
  const auto stop_interrupted = [&](size_t i) {
    MESOSCAN_THROW(ErrorKind::kDevice, "capture: interrupted after "
                                           << i << " of " << n << " frames (journal "
                                           << journal_path.string()
                                           << "); run the same command again to resume");
  };
  {
    Progress progress("capture frames", static_cast<int64_t>(n));
    progress.Advance(static_cast<int64_t>(first_missing));
    for (size_t i = first_missing; i < n; ++i) {
      if (interrupted()) stop_interrupted(i);
      if (options.max_new_frames >= 0 && summary.captured >= options.max_new_frames) break;
      const Frame& f = s.frames[i];
      const ImageF image = RenderPattern(f.pattern, pw, ph);
      DeviceCall(projector.Name(), [&] { projector.Show(image); });
      if (shifter) {
        const int reached =
            DeviceCall(shifter->Name(), [&] { return shifter->MoveTo(f.shift_steps); });
        if (reached != f.shift_steps)
          MESOSCAN_THROW(ErrorKind::kDevice, shifter->Name()
                                                 << ": asked to move to " << f.shift_steps
                                                 << " steps, reports " << reached);
      }
      if (options.settle_s > 0)
        std::this_thread::sleep_for(std::chrono::duration<double>(options.settle_s));
      if (interrupted()) stop_interrupted(i);
      const fs::path path = s.FramePath(i);
      DeviceCall(camera.Name(), [&] { camera.CaptureToFile(path); });
      if (!fs::exists(path))
        MESOSCAN_THROW(ErrorKind::kDevice, camera.Name() << ": reported a capture but "
                                                         << path.string() << " is missing");
      JournalEntry e;
      e.file = f.file;
      e.hash = Hex(HashFile(path, &e.bytes));
      AppendLine(journal_path, EntryLine(i, e).dump());
      ++summary.captured;
      progress.Advance();
    }
  }

  // Step 5: all frames there -> check their headers against the rig, write session.json, drop
  // the journal. The shifter goes back to its neutral position (where the projector model holds).
  if (static_cast<size_t>(summary.reused + summary.captured) == n) {
    if (shifter) DeviceCall(shifter->Name(), [&] { return shifter->MoveTo(0); });
    CheckSessionFiles(s);
    WriteSessionJson(s);
    fs::remove(journal_path);
    summary.complete = true;
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

// ---- the real devices ----

namespace {

class WindowProjector : public ProjectorDevice {
 public:
  explicit WindowProjector(const ProjectorWindowOptions& o) : window_(o) {
    const char* env = std::getenv("DISPLAY");
    name_ = "projector window on display " +
            (o.display.empty() ? std::string(env ? env : "(none)") : o.display);
  }
  std::string Name() const override { return name_; }
  int width() const override { return window_.width(); }
  int height() const override { return window_.height(); }
  void Show(const ImageF& image) override { window_.Show(image); }
  ImageU8 Screenshot() const override { return window_.Screenshot(); }

 private:
  ProjectorWindow window_;
  std::string name_;
};

// The controller's errors start with the port; they are re-labelled "lens shifter on <port>" so
// the user reads which device failed.
Error LabelShifterError(const Error& e, const std::string& port) {
  std::string m = e.what();
  if (m.rfind(port + ": ", 0) == 0) m = m.substr(port.size() + 2);
  return Error("lens shifter on " + port + ": " + m, e.kind());
}

class SerialShifter : public ShifterDevice {
 public:
  explicit SerialShifter(const LensShifterOptions& o) : controller_(o), port_(o.port) {}
  std::string Name() const override { return "lens shifter on " + port_; }
  int MoveTo(int steps) override {
    try {
      return controller_.MoveTo(steps);
    } catch (const Error& e) {
      throw LabelShifterError(e, port_);
    }
  }

 private:
  LensShifterController controller_;
  std::string port_;
};

class Gphoto2CameraDevice : public CameraDevice {
 public:
  Gphoto2CameraDevice(const std::string& port, const std::string& extension)
      : camera_(port), extension_(extension) {}
  std::string Name() const override {
    return "camera '" + camera_.info().model + "' on " + camera_.info().port;
  }
  std::string FrameExtension() const override { return extension_; }
  void CaptureToFile(const fs::path& path) override { camera_.CaptureToFile(path); }

 private:
  Gphoto2Camera camera_;
  std::string extension_;
};

class ScreenCamera : public CameraDevice {
 public:
  ScreenCamera(const ProjectorDevice& projector, int width, int height, bool raw)
      : projector_(projector), width_(width), height_(height), raw_(raw) {
    MESOSCAN_CHECK(width > 0 && height > 0);
  }
  std::string Name() const override { return "screen camera (reads " + projector_.Name() + ")"; }
  std::string FrameExtension() const override { return raw_ ? ".dng" : ".png"; }
  void CaptureToFile(const fs::path& path) override {
    const ImageU8 shot = projector_.Screenshot();
    // Box resampling: camera pixel (x, y) averages the screen pixels [x0, x1) x [y0, y1) with
    // x0 = floor(x * W / w) (at least one pixel).
    const int sw = shot.width(), sh = shot.height();
    ImageU16 grey(width_, height_);
    for (int y = 0; y < height_; ++y) {
      const int y0 = y * sh / height_, y1 = std::max(y0 + 1, (y + 1) * sh / height_);
      for (int x = 0; x < width_; ++x) {
        const int x0 = x * sw / width_, x1 = std::max(x0 + 1, (x + 1) * sw / width_);
        double sum = 0.0;
        for (int v = y0; v < y1; ++v)
          for (int u = x0; u < x1; ++u) sum += shot(u, v, 0);
        grey(x, y) =
            static_cast<uint16_t>(std::lround(sum / ((x1 - x0) * (y1 - y0)) * (65535.0 / 255.0)));
      }
    }
    if (!raw_) {
      WritePng16(path, grey);
      return;
    }
    ImageU16 mosaic(2 * width_, 2 * height_);
    for (int y = 0; y < 2 * height_; ++y)
      for (int x = 0; x < 2 * width_; ++x) mosaic(x, y) = grey(x / 2, y / 2);
    WriteCfaDng(path, mosaic);
  }

 private:
  const ProjectorDevice& projector_;
  int width_, height_;
  bool raw_;
};

}  // namespace

std::unique_ptr<ProjectorDevice> MakeWindowProjector(const ProjectorWindowOptions& options) {
  try {
    return std::make_unique<WindowProjector>(options);
  } catch (const Error& e) {
    const std::string m = e.what();
    throw Error(m.rfind("projector window", 0) == 0 ? m : "projector window: " + m, e.kind());
  }
}

std::unique_ptr<ShifterDevice> MakeSerialShifter(const LensShifterOptions& options) {
  try {
    return std::make_unique<SerialShifter>(options);
  } catch (const Error& e) {
    throw LabelShifterError(e, options.port);
  }
}

std::unique_ptr<CameraDevice> MakeGphoto2Camera(const std::string& which,
                                                const std::string& extension) {
  std::string port = which;
  if (!which.empty() && which.find(':') == std::string::npos) {  // a model name
    port.clear();
    std::string seen;
    for (const Gphoto2CameraInfo& c : DetectGphoto2Cameras()) {
      if (c.model == which) port = c.port;
      seen += (seen.empty() ? "" : ", ") + c.model + " on " + c.port;
    }
    if (port.empty())
      MESOSCAN_THROW(ErrorKind::kDevice, "camera: no '" << which << "' detected by libgphoto2 ("
                                                        << (seen.empty() ? "none" : seen)
                                                        << " detected)");
  }
  return std::make_unique<Gphoto2CameraDevice>(port, extension);
}

std::unique_ptr<CameraDevice> MakeScreenCamera(const ProjectorDevice& projector, int width,
                                               int height, bool raw) {
  return std::make_unique<ScreenCamera>(projector, width, height, raw);
}

}  // namespace mesoscan
