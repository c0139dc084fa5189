// mesoscan compare A B --out DIR: B registered onto A, the deviation map and the change test
// (compare/compare.h, docs/compare.md).

#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include "app/commands.h"
#include "app/session_checks.h"
#include "compare/compare.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct CompareArgs {
  std::string a, b, reference, out, region = "object", exclude;
  CompareOptions o;
  bool force = false;
};

// A mask image on A's height grid: nonzero = set.
ImageF ReadMask(const std::string& path) {
  if (!fs::is_regular_file(path)) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "no such file");
  return ReadImageGrey(path);
}

void RunCompare(const CompareArgs& args) {
  CompareOptions o = args.o;
  std::string mask_file;
  if (args.region == "object")
    o.region = CompareOptions::Region::kObject;
  else if (args.region == "all")
    o.region = CompareOptions::Region::kAll;
  else
    mask_file = args.region;  // a mask: compared where nonzero, the mount included
  if (!mask_file.empty()) o.region = CompareOptions::Region::kAll;
  o.Check();
  if (args.b.empty() == args.reference.empty())
    MESOSCAN_THROW(ErrorKind::kUsage, "compare: give either scan folder B or --reference MESH, not "
                                          << (args.b.empty() ? "neither" : "both"));
  const std::string b_name = args.b.empty() ? args.reference : args.b;
  const OutputSpec spec{"compare",  "--out",
                        args.out,   {args.a, b_name, mask_file, args.exclude},
                        args.force, {"deviation.exr", "report.json"}};
  CheckOutputFolder(spec);
  if (!mask_file.empty()) o.mask = ReadMask(mask_file);
  if (!args.exclude.empty()) o.exclude = ReadMask(args.exclude);
  const Scan a = ReadScanFolder(args.a);
  CheckScanUsable(a, args.a);
  // A reference mesh is seen on A's pixel size.
  const Scan b =
      args.b.empty() ? ScanFromMesh(args.reference, a.height.pixel_size) : ReadScanFolder(args.b);
  if (!args.b.empty()) CheckScanUsable(b, args.b);
  CompareResult r = CompareScans(a, b, o, args.a, b_name);
  r.report["a"] = fs::absolute(args.a).lexically_normal().string();
  r.report[args.b.empty() ? "reference" : "b"] = fs::absolute(b_name).lexically_normal().string();
  if (!mask_file.empty()) r.report["options"]["mask"] = mask_file;
  if (!args.exclude.empty()) r.report["options"]["exclude"] = args.exclude;
  WriteOutputFolder(spec, [&](const fs::path& tmp) { WriteComparison(tmp, r); });
  std::cout << r.BriefReport() << "\n";
  if (r.report.contains("warnings"))
    for (const auto& w : r.report["warnings"]) MESOSCAN_LOG(kWarning) << w.get<std::string>();
  std::cout << "comparison in " << fs::absolute(args.out).lexically_normal().string()
            << ": deviation.exr, deviation.png, report.json\n";
}

}  // namespace

void AddCompareCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "compare",
      "Registers scan B onto scan A (re-placed object) and maps the deviation of B from A: "
      "deviation.exr, deviation.png, report.json (transform, RMS, changed area, repeatability)");
  auto a = std::make_shared<CompareArgs>();
  cmd->add_option("A", a->a, "Reference scan folder (the deviation is on its height grid)")
      ->required();
  cmd->add_option("B", a->b, "Scan folder compared with A (or --reference)");
  cmd->add_option("--reference", a->reference,
                  "Another scanner's mesh instead of B: MESH.ply|.stl|.obj (metres, z up) or "
                  ".glb (as export writes it); no change test (a mesh carries no noise)");
  cmd->add_option("--out", a->out, "Output folder (written atomically)")->required();
  cmd->add_option("--region", a->region,
                  "object (points above the mount plane; a re-placed object's mount does not "
                  "move with it) | all | MASK.png (on A's height grid: compared where nonzero)")
      ->capture_default_str();
  cmd->add_option("--exclude", a->exclude,
                  "MASK.png on A's height grid: nonzero pixels neither register nor compare");
  cmd->add_option("--k-sigma", a->o.k_sigma,
                  "Change test: k times the predicted sigma of the window mean")
      ->capture_default_str();
  cmd->add_option("--window", a->o.window, "Change test: window of N x N pixels (odd)")
      ->capture_default_str();
  cmd->add_option("--min-confidence", a->o.min_confidence,
                  "Registration uses points with at least this confidence")
      ->capture_default_str();
  cmd->add_option("--mount-clearance", a->o.mount_clearance_m,
                  "--region object: height above the mount (m) that counts as object")
      ->capture_default_str();
  cmd->add_option("--coarse-voxel", a->o.coarse_voxel_m,
                  "Coarse alignment's voxel (m); 0: 4 height-grid pixels")
      ->capture_default_str();
  cmd->add_option("--max-points", a->o.max_icp_points,
                  "Fine registration: at most this many points of B (four times as many of A)")
      ->capture_default_str();
  cmd->add_option("--seed", a->o.seed, "Random seed of the coarse alignment (RANSAC)")
      ->capture_default_str();
  cmd->add_flag("--force", a->force,
                "Replace an existing --out that is not an earlier output of `mesoscan compare`");
  cmd->callback([a] { RunCompare(*a); });
}

}  // namespace mesoscan
