// mesoscan reconstruct SESSION --out SCAN: a capture session to a scan folder
// (docs/formats.md) through heightfield/reconstruct.h.

#include <tbb/parallel_invoke.h>

#include <cmath>
#include <filesystem>
#include <future>
#include <optional>
#include <sstream>

#include "app/commands.h"
#include "app/map_options.h"
#include "app/session_checks.h"
#include "calibration/rig_file.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/json.h"
#include "core/log.h"
#include "core/malloc_tuning.h"
#include "core/output_dir.h"
#include "core/parallel.h"
#include "core/scan_folder.h"
#include "core/stage_timer.h"
#include "heightfield/reconstruct.h"
#include "maps/export.h"
#include "session/session.h"
#include "sim/error_map_png.h"
#include "sim/ground_truth.h"

namespace mesoscan {
namespace {

struct ReconstructArgs {
  std::string session, out, roi, mask, rig, fitter = "fast", phase_harmonics = "auto";
  std::string export_formats, export_dir;  // --export: formats for `mesoscan export`
  bool no_lens_shift = false, box_filter = false, no_normalize = false, force = false;
  int threads = 0;
  double pixel_size_um = 0.0;
  MapArgs maps;  // with --export: also a finished map set in EXPORT_DIR/maps
};

void Run(const ReconstructArgs& a) {
  TuneAllocatorForReconstruction();  // core/malloc_tuning.h: large blocks reused across stages
  const ThreadLimit thread_limit(a.threads);  // --threads: every stage and write below
  const Stopwatch t0;
  const double cpu0 = ProcessCpuSeconds();
  ReconstructOptions opt;
  if (!a.roi.empty()) opt.load.roi = ParsePixelRect(a.roi, "FrameLoadOptions.roi");
  opt.classify.mask_path = a.mask;
  opt.lens_shift.fitter = ParseLensShiftFitter(a.fitter, "LensShiftStageOptions.fitter");
  opt.plan.use_lens_shift = !a.no_lens_shift;
  opt.lens_shift.box_filter = a.box_filter;
  opt.gains.normalize_luminance = !a.no_normalize;
  opt.phase_shift.harmonics.mode = a.phase_harmonics == "on"    ? HarmonicsMode::kOn
                                   : a.phase_harmonics == "off" ? HarmonicsMode::kOff
                                                                : HarmonicsMode::kAuto;
  opt.resample.pixel_size = a.pixel_size_um * 1e-6;
  opt.Check();
  ExportOptions export_options;
  if (!a.export_formats.empty()) {
    ParseExportFormats(a.export_formats, &export_options);
    export_options.name = ScanName(a.out);  // files named after the scan, as `export` names them
    export_options.Check();
  }
  std::optional<MapsOptions> maps;
  if (a.maps.any()) {
    if (a.export_formats.empty())
      MESOSCAN_THROW(ErrorKind::kUsage, "--fill/--flatten/--tile/--maps need --export FORMATS");
    maps = a.maps.ToOptions(ScanName(a.out), "");
    if (!a.maps.fill.empty()) export_options.fill = maps->fill;
  }

  // --out (and --export-dir) must not be, contain or lie inside an input: checked before any work.
  OutputSpec out_spec{"reconstruct", "--out",
                      a.out,         {a.session, a.mask, a.rig, a.export_dir},
                      a.force,       {"report.json", "height.exr"}};
  CheckOutputFolder(out_spec);
  OutputSpec export_spec{"export", "--export-dir",   a.export_dir, {a.session, a.mask, a.out},
                         a.force,  {"manifest.json"}};
  if (!a.export_formats.empty() && !a.export_dir.empty()) CheckOutputFolder(export_spec);

  Session session = ReadSession(a.session);
  std::optional<RigFile> rig_file;
  if (!a.rig.empty()) {
    rig_file = ReadRigFile(a.rig);
    UseRigFile(*rig_file, &session);
  }
  // The ground truth (simulations) is read while the last stages run: started once the frames
  // are released (the memory peak is behind), on its own thread.
  std::future<GroundTruthPoints> gt_read;
  if (session.ground_truth)
    opt.on_frames_released = [&] {
      ReleaseFreedHeap();
      gt_read =
          std::async(std::launch::async, [&session] { return ReadGroundTruthPoints(session); });
    };
  ReconstructSummary summary;
  Scan scan = ReconstructOrExplain(session, opt, &summary);  // names session.json; no empty scan
  // A scan its own check, export, maps and render refuse is not written.
  if (scan.height.width() < 2 || scan.height.height() < 2)  // (ReconstructOrExplain: no --roi)
    MESOSCAN_THROW(ErrorKind::kUsage, "reconstruct: --roi "
                                          << a.roi << ": the points span a " << scan.height.width()
                                          << "x" << scan.height.height()
                                          << " height grid, expected at least 2x2 samples: "
                                             "choose a larger --roi");
  scan.report["session"] = std::filesystem::absolute(a.session).lexically_normal().string();
  scan.report["object"] = session.object;
  scan.report["options"]["threads"] = a.threads;
  if (rig_file) {
    // Which rig made the points, and how many of them lie where the calibration saw no corner.
    Json r = rig_file->ToJson();
    const CalibratedRegionCheck region = CheckCalibratedRegion(*rig_file, scan.points);
    r["calibrated_region"] = region.ToJson();
    if (rig_file->calibration.contains("warnings") && !rig_file->calibration["warnings"].empty())
      r["calibration_warnings"] = rig_file->calibration["warnings"];
    scan.report["rig"] = r;
    if (region.known && region.OutsideFraction() > 0.1 &&
        (rig_file->camera_distorted || rig_file->projector_distorted))
      MESOSCAN_LOG(kWarning) << a.rig << ": " << std::lround(region.OutsideFraction() * 100)
                             << "% of the points lie outside the image region the calibration's "
                                "board corners covered: the lens model is extrapolated there "
                                "(report.json rig.calibrated_region)";
    if (r.contains("calibration_warnings"))
      MESOSCAN_LOG(kWarning) << a.rig << ": made with " << r["calibration_warnings"].size()
                             << " calibration warning(s) (report.json rig.calibration_warnings)";
  }
  // The scan's EXRs, and the ground-truth comparison with its error map when the session has
  // ground truth (simulations), in parallel; the report last (it holds their figures).
  std::optional<GroundTruthErrors> gt;
  const bool export_inside = !a.export_formats.empty() && a.export_dir.empty();
  std::optional<ExportSummary> export_summary;
  std::optional<MapsSummary> maps_summary;
  // Writes the exports (and the map set, if asked for) into `dir`.
  const auto write_exports = [&](const std::filesystem::path& dir) {
    ExportSummary es = ExportScan(scan, export_options, dir);
    if (maps) maps_summary = BuildMapSet(scan, *maps, dir / "maps");
    return es;
  };
  WriteOutputFolder(out_spec, [&](const std::filesystem::path& tmp) {
    // Wall time of each task (they run at once), for the report.
    double points_s = 0, height_s = 0, normal_s = 0, gt_s = 0, error_map_s = 0;
    const Stopwatch write_clock;
    tbb::parallel_invoke(
        [&] {
          const Stopwatch c;
          WritePointsExr(tmp / "points.exr", scan.points);
          points_s = c.Seconds();
        },
        [&] {
          const Stopwatch c;
          WriteHeightExr(tmp / "height.exr", scan.height);
          height_s = c.Seconds();
        },
        [&] {
          const Stopwatch c;
          WriteNormalExr(tmp / "normal.exr", scan.height, scan.normals);
          normal_s = c.Seconds();
        },
        [&] {
          if (!session.ground_truth) return;
          Stopwatch c;
          gt = EvaluateAgainstGroundTruth(
              gt_read.valid() ? gt_read.get() : ReadGroundTruthPoints(session), scan.points,
              opt.load.roi);
          gt_s = c.Restart();
          WriteErrorMapPng(tmp / "error_map.png", gt->error);
          error_map_s = c.Seconds();
        });
    scan.report["write_timings_s"] = {
        {"points_exr", points_s}, {"height_exr", height_s},       {"normal_exr", normal_s},
        {"ground_truth", gt_s},   {"error_map_png", error_map_s}, {"all", write_clock.Seconds()}};
    if (gt) scan.report["ground_truth"] = gt->ToJson();
    const double total = t0.Seconds();
    scan.report["wall_time_s"] = total;
    // The process's own figures (comparable with bench_reconstruct's full-resolution row): CPU
    // time of every thread since the start (session reading and loading the libraries excluded)
    // and peak RSS so far (the report is written last but for --export inside the scan).
    scan.report["cpu_time_s"] = ProcessCpuSeconds() - cpu0;
    scan.report["peak_rss_mb"] = PeakRssMegabytes();
    WriteJsonFile(tmp / "report.json", scan.report);
    // Default --export-dir (SCAN/export) is written with the scan, inside the same swap.
    if (export_inside) export_summary = write_exports(tmp / "export");
  });
  MESOSCAN_LOG(kInfo) << summary.BriefReport();
  if (gt) {
    std::ostringstream mixed;
    if (gt->footprint_known)
      mixed << " (" << gt->pixels_mixed << " lit pixels mix two surfaces or light and shadow, "
            << gt->mixed_kept << " of them kept; coverage of the others "
            << gt->coverage_single * 100 << "%)";
    MESOSCAN_LOG(kInfo) << "ground truth: coverage " << gt->coverage * 100 << "%, depth RMS "
                        << gt->rms_m * 1e6 << " um, median |error| " << gt->median_abs_m * 1e6
                        << " um, p99 " << gt->p99_abs_m * 1e6 << " um, gross " << gt->gross_fraction
                        << mixed.str();
  }
  MESOSCAN_LOG(kInfo) << "scan written to " << a.out << " ("
                      << scan.report["wall_time_s"].get<double>() << " s wall, "
                      << scan.report["cpu_time_s"].get<double>() << " CPU-s, peak RSS "
                      << scan.report["peak_rss_mb"].get<double>() << " MB)";
  if (!a.export_formats.empty()) {
    // The same exports as `mesoscan export SCAN --format ...`, from the scan in memory.
    const std::filesystem::path dir = a.export_dir.empty() ? std::filesystem::path(a.out) / "export"
                                                           : std::filesystem::path(a.export_dir);
    ExportSummary es;
    if (export_summary) {
      es = *export_summary;
    } else {
      WriteOutputFolder(export_spec,
                        [&](const std::filesystem::path& tmp) { es = write_exports(tmp); });
    }
    MESOSCAN_LOG(kInfo) << es.BriefReport();
    MESOSCAN_LOG(kInfo) << "exports written to " << dir.string() << " (manifest.json lists them)";
    if (maps_summary) PrintMapSet(*maps_summary, dir / "maps");
  }
}

}  // namespace

void AddReconstructCommand(CLI::App* app) {
  auto args = std::make_shared<ReconstructArgs>();
  auto* cmd = app->add_subcommand(
      "reconstruct", "Reconstruct a capture session into a scan folder (points, height field)");
  cmd->add_option("session", args->session, "Session folder (session.json)")->required();
  cmd->add_option("--out", args->out, "Scan folder to write (replaced atomically)")->required();
  cmd->add_option("--rig", args->rig,
                  "Rig file (`mesoscan calibrate --out`) used instead of the session's rig; the "
                  "scan's report.json records its path and SHA-256");
  cmd->add_option("--roi", args->roi, "Camera pixels to reconstruct: x,y,w,h");
  cmd->add_option("--mask", args->mask, "Mask image on the camera grid (0 = skip the pixel)");
  cmd->add_option("--fitter", args->fitter, "Lens-shift fitter: fast, lm or ceres")
      ->capture_default_str();
  cmd->add_flag("--no-lens-shift", args->no_lens_shift,
                "Ignore lens-shift frames (phase shifting alone)");
  cmd->add_flag("--box-filter", args->box_filter,
                "5-sample box filter along each lens-shift profile (paper Sec. 5.1)");
  cmd->add_flag("--no-normalize", args->no_normalize, "No per-frame luminance normalisation");
  cmd->add_option("--phase-harmonics", args->phase_harmonics,
                  "Projector response (harmonics) estimated from the sine phases and undone: auto "
                  "(where clearly non-linear), on, or off (the plain decode)")
      ->check(CLI::IsMember({"auto", "on", "off"}))
      ->capture_default_str();
  cmd->add_option("--pixel-size-um", args->pixel_size_um,
                  "Height-field grid pixel (um); 0 = camera footprint")
      ->check(CLI::Range(0.0, 1e6));
  cmd->add_option("--export", args->export_formats,
                  "Also export for DCC tools, as `mesoscan export`: formats " + ExportFormatList());
  cmd->add_option("--export-dir", args->export_dir, "Folder for --export (default SCAN/export)");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)")
      ->check(CLI::Range(0, 4096));
  AddMapOptions(cmd, &args->maps, /*standalone=*/false);
  cmd->add_flag("--force", args->force,
                "Replace an existing --out (or --export-dir) that is not an earlier output of "
                "this command");
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
