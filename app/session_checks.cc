#include "app/session_checks.h"

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/progress.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

// Reconstruct(), its bad-input errors that carry no location located at the session's
// session.json: the decoders' refusals (periods, phases, unwrapping) are about what it describes.
Scan ReconstructLocated(const Session& session, const ReconstructOptions& options,
                        ReconstructSummary* summary) {
  try {
    return Reconstruct(session, options, summary);
  } catch (const Error& e) {
    const ErrorSite& site = e.site();
    const bool located =
        !site.file.empty() || !site.key.empty() || site.frame >= 0 || !site.option.empty();
    if (e.kind() != ErrorKind::kBadInput || located) throw;
    throw e.At(ErrorSite::File(session.root / "session.json"));
  }
}

// Why no point came out (or why few did): the stage that rejected most of the pixels, in the
// user's terms.
std::string WhyNoPoint(const ReconstructSummary& s, const ReconstructOptions& options) {
  if (s.pixels_roi == 0) return "the ROI and mask select no pixel";
  if (s.pixels_saturated * 2 >= s.pixels_roi)
    return std::to_string(s.pixels_saturated) +
           " of them are saturated in some frame: lower the exposure";
  if (s.pixels_lit == 0)
    return "none is lit and modulated by the patterns: are the frames dark, identical, "
           "low-contrast or NaN?";
  if (s.consistency.ambiguous_stripes * 2 > s.consistency.decoded && s.consistency.decoded > 0)
    return "the sine periods fix the projector column too coarsely for the 2-px lens-shift "
           "stripes (their noise allows a wrong stripe period): add shorter periods";
  const std::pair<int64_t, std::string> reasons[] = {
      {s.pixels_rejected_unwrap,
       "the sine periods' phases disagree at every pixel (unwrapping failed): are the periods "
       "and phases in session.json those of the frames?"},
      {s.pixels_rejected_combination,
       "the lens-shift stripes disagree with the sines' column: are the shifts and periods in "
       "session.json those of the frames?"},
      {s.pixels_rejected_confidence,
       "the lens-shift profiles are noise (low confidence): too dark, defocused or "
       "low-contrast stripes?"},
      {s.pixels_rejected_isolated,
       "the decoded columns are noise (isolated fringe orders): too dark or low-contrast "
       "frames?"},
      {s.pixels_rejected_inconsistent, "the frames' phases contradict each other"},
      {s.pixels_rejected_ambiguous,
       "the frames are too noisy for the code (a wrong fringe order or a depth error over 100 um "
       "would be likely): too dark or low-contrast frames?"},
      {s.pixels_rejected_uncertain,
       "the code fixes the projector column too coarsely: the points' predicted depth sigma "
       "exceeds " +
           std::to_string(std::lround(options.consistency.max_depth_sigma_m * 1e6)) +
           " um (or, where larger, " +
           std::to_string(std::lround(options.consistency.max_depth_sigma_per_footprint * 100)) +
           "% of the camera footprint), so they could lie 100 um or more from the surface: add "
           "shorter "
           "sine periods or lens-shift frames, or raise the exposure"},
      {s.pixels_rejected_discontinuity, "the points lie on depth steps or shadow edges"}};
  const auto* best = &reasons[0];
  for (const auto& r : reasons)
    if (r.first > best->first) best = &r;
  return best->second;
}

// The refusal of a scan with no point, or too few to make a height grid of 2x2 samples (what
// check, export, maps and render need), naming why most pixels were rejected; none if the scan
// is usable.
std::optional<Error> NoPointError(const Session& session, const ReconstructOptions& options,
                                  const ReconstructSummary& summary, const Scan& scan) {
  size_t points = 0;
  const ImageF& xyz = scan.points.xyz;
  if (xyz.channels() == 3)
    for (size_t i = 0; i < xyz.pixels(); ++i) points += std::isfinite(xyz.channel(2)[i]);
  const bool grid = scan.height.width() >= 2 && scan.height.height() >= 2;
  if (points > 0 && (grid || options.load.roi.w != 0)) return std::nullopt;
  ErrorMessage msg;
  msg << (points ? "too few points" : "no point") << " could be reconstructed from the "
      << summary.pixels_roi << " pixels tried (" << summary.pixels_lit << " lit and modulated"
      << (points ? ", " + std::to_string(points) + " points" : std::string())
      << "): " << WhyNoPoint(summary, options);
  return Error(ErrorKind::kBadInput, ErrorSite::File(session.root / "session.json"), msg.Parts());
}

}  // namespace

Scan ReconstructOrExplain(const Session& session, const ReconstructOptions& options,
                          ReconstructSummary* summary_out) {
  ReconstructSummary local;
  ReconstructSummary* summary = summary_out ? summary_out : &local;
  Scan scan = ReconstructLocated(session, options, summary);
  if (std::optional<Error> e = NoPointError(session, options, *summary, scan)) throw *e;
  // A scan that kept fewer than half of its lit pixels is said loudly, with the main reason.
  // It is also kept in report.json's "warnings".
  if (summary->pixels_lit > 0 && summary->pixels_valid * 2 < summary->pixels_lit) {
    const std::string warning =
        "only " + std::to_string(summary->pixels_valid) + " of " +
        std::to_string(summary->pixels_lit) + " lit pixels gave a point (" +
        std::to_string(std::lround(100.0 * summary->pixels_valid / summary->pixels_lit)) +
        "%): " + WhyNoPoint(*summary, options);
    MESOSCAN_LOG(kWarning) << (session.root / "session.json").string() << ": " << warning;
    scan.report["warnings"].push_back(warning);
  }
  return scan;
}

void CheckSessionLikeReconstruct(const Session& session) {
  // Every frame decoded whole: a truncated or corrupt body fails here.
  for (size_t i = 0; i < session.frames.size(); ++i) {
    const ImageF im = ReadImage(session.FramePath(i));
    bool finite = false;
    for (const float v : im.data())
      if (std::isfinite(v)) {
        finite = true;
        break;
      }
    if (!finite)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(session.frames[i].file),
                            "no finite sample (frames[" << i << "])");
  }
  // A calibration session has no calibrated rig to reconstruct with: its frames are checked
  // above, its decoding is calibrate's.
  if (session.rig.uncalibrated) return;
  // The reconstruction's own tests (periods, phases, unwrapping, the frames' consistency,
  // projector size) on a 32x32 window at the image centre; where it gives no point, on up to 8
  // more windows over the image: a session none of them reconstructs is refused as reconstruct
  // would refuse it (naming why).
  const int w = session.rig.camera.width, h = session.rig.camera.height;
  const int ww = std::min(32, w), wh = std::min(32, h);
  std::vector<PixelRect> windows = {{std::max(0, w / 2 - 16), std::max(0, h / 2 - 16), ww, wh}};
  for (int gy = 0; gy < 3; ++gy)
    for (int gx = 0; gx < 3; ++gx)
      if (gx != 1 || gy != 1)
        windows.push_back({(w - ww) * (2 * gx + 1) / 6, (h - wh) * (2 * gy + 1) / 6, ww, wh});
  Progress::SetEnabled(false);  // check prints its summary, not the window's progress bars
  const LogLevel level = GetLogLevel();
  SetLogLevel(LogLevel::kError);  // the window's own statistics are not the user's business
  try {
    std::optional<Error> first;
    for (const PixelRect& roi : windows) {
      ReconstructOptions o;
      o.load.roi = roi;
      // A refusal of the session itself (its periods, its frames' contradictions) is final; a
      // window without points tries the next.
      ReconstructSummary summary;
      const Scan scan = ReconstructLocated(session, o, &summary);
      std::optional<Error> e = NoPointError(session, o, summary, scan);
      if (!e) {
        first.reset();
        break;
      }
      if (!first) first = std::move(e);
    }
    if (first) throw *first;
  } catch (...) {
    SetLogLevel(level);
    throw;
  }
  SetLogLevel(level);
}

void CheckScanUsable(const Scan& scan, const fs::path& dir) {
  const HeightField& hf = scan.height;
  const ErrorSite file = ErrorSite::File(dir / "height.exr");
  if (hf.width() < 2 || hf.height() < 2)
    MESOSCAN_BAD_INPUT_AT(file, "a " << hf.width() << "x" << hf.height()
                                     << " height grid, expected at least 2x2 samples");
  if (!std::isfinite(hf.x0) || !std::isfinite(hf.y0) || !(hf.pixel_size > 0) ||
      !std::isfinite(hf.pixel_size) || std::abs(hf.x0) > 1e6 || std::abs(hf.y0) > 1e6 ||
      hf.pixel_size > 1e3)
    MESOSCAN_BAD_INPUT_AT(
        file, kAttrX0 << ", " << kAttrY0 << ", " << kAttrPixelSize
                      << " must be finite (|x0|, |y0| <= 1e6 m, 0 < pixel size <= 1e3 m), "
                         "got "
                      << hf.x0 << ", " << hf.y0 << ", " << hf.pixel_size);
  // A height beyond 100 times the field's extent is no surface the rig can see: a damaged
  // sample that would flatten every quantised map and put a vertex kilometres away.
  const double extent = std::max(hf.width(), hf.height()) * hf.pixel_size;
  const double limit = std::min(100 * extent, 1e3);
  bool any = false, block = false;
  const int w = hf.width(), h = hf.height();
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float z = hf.z(x, y);
      if (!std::isfinite(z)) continue;
      any = true;
      if (std::abs(z) > limit)
        MESOSCAN_BAD_INPUT_AT(file, "sample (" << x << ", " << y << ") is " << z
                                               << " m, beyond 100 times the field's " << extent
                                               << " m extent (a damaged file?)");
      if (!hf.confidence.empty()) {
        const float c = hf.confidence(x, y);
        if (!(c >= 0 && c <= 1))
          MESOSCAN_BAD_INPUT_AT(file, "sample (" << x << ", " << y << "): confidence " << c
                                                 << ", expected a value in [0, 1]");
      }
      block = block || (x + 1 < w && y + 1 < h && std::isfinite(hf.z(x + 1, y)) &&
                        std::isfinite(hf.z(x, y + 1)) && std::isfinite(hf.z(x + 1, y + 1)));
    }
  if (!any) MESOSCAN_BAD_INPUT_AT(file, "no valid (finite) height sample");
  if (!block)
    MESOSCAN_BAD_INPUT_AT(file,
                          "no 2x2 block of known samples (isolated samples only): no "
                          "surface to export");
}

}  // namespace mesoscan
