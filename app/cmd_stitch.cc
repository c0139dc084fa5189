// mesoscan stitch SCAN... --out SCAN: overlapping scans registered pairwise and globally and
// blended into one scan folder (compare/stitch.h, docs/stitch.md).

#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "app/commands.h"
#include "app/session_checks.h"
#include "compare/stitch.h"
#include "core/error.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct StitchArgs {
  std::vector<std::string> scans, offsets;
  std::string out;
  StitchOptions o;
  bool no_register = false, force = false;
};

Vec2d ParseOffset(const std::string& text) {
  double x = 0, y = 0;
  char comma = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%lf%c%lf%c", &x, &comma, &y, &extra) != 3 || comma != ',' ||
      !std::isfinite(x) || !std::isfinite(y))
    MESOSCAN_BAD_OPTION("StitchOptions.offsets_m", "'" << text << "': expected X,Y (mm)");
  return Vec2d(x, y) * 1e-3;
}

void RunStitch(const StitchArgs& args) {
  StitchOptions o = args.o;
  o.register_scans = !args.no_register;
  for (const std::string& s : args.offsets) o.offsets_m.push_back(ParseOffset(s));
  if (!o.offsets_m.empty() && o.offsets_m.size() != args.scans.size())
    MESOSCAN_THROW(ErrorKind::kUsage, "--offset: expected one per scan ("
                                          << args.scans.size() << "), got " << o.offsets_m.size());
  o.Check();
  std::vector<fs::path> inputs(args.scans.begin(), args.scans.end());
  const OutputSpec spec{"stitch", "--out", args.out, inputs, args.force, {}};
  CheckOutputFolder(spec);
  std::vector<Scan> scans;
  for (const std::string& s : args.scans) {
    scans.push_back(ReadScanFolder(s));
    CheckScanUsable(scans.back(), s);
  }
  StitchResult r = StitchScans(scans, args.scans, o);
  Json sources = Json::array();
  for (const std::string& s : args.scans)
    sources.push_back(fs::absolute(s).lexically_normal().string());
  r.scan.report["stitch"]["sources"] = sources;
  WriteOutputFolder(spec, [&](const fs::path& tmp) { WriteStitchedScan(tmp, r); });
  std::cout << r.BriefReport() << "\n"
            << "scan written to " << fs::absolute(args.out).lexically_normal().string() << "\n";
}

}  // namespace

void AddStitchCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "stitch",
      "Joins overlapping scans of an object larger than one field: pairs registered on their "
      "overlaps, poses solved together, scans blended without seams into one scan folder");
  auto a = std::make_shared<StitchArgs>();
  cmd->add_option("SCAN", a->scans, "Scan folders (two or more; the first fixes the frame)")
      ->required();
  cmd->add_option("--out", a->out, "Output scan folder (written atomically)")->required();
  cmd->add_option("--offset", a->offsets,
                  "Nominal placement X,Y (mm) of each scan in the mosaic, one per scan in order "
                  "(e.g. simulate --field-offset); default 0,0 for all")
      ->take_all()
      ->delimiter(' ');
  cmd->add_option("--feather", a->o.feather,
                  "Border ramp of each scan's weight, fraction of its smaller side")
      ->capture_default_str();
  cmd->add_option("--min-confidence", a->o.min_confidence,
                  "Registration uses points with at least this confidence")
      ->capture_default_str();
  cmd->add_option("--min-overlap", a->o.min_overlap,
                  "Pairs whose nominal footprints overlap by at least this fraction of the smaller "
                  "one are registered")
      ->capture_default_str();
  cmd->add_option("--max-correction-deg", a->o.max_correction_deg,
                  "Largest plausible rotation of a pair's registration from the nominal placement "
                  "(degrees); beyond it the pair is refused")
      ->capture_default_str();
  cmd->add_option("--max-correction", a->o.max_correction_fraction,
                  "Largest plausible displacement of a pair's registration from the nominal "
                  "placement, fraction of the scan's smaller side; beyond it the pair is refused")
      ->capture_default_str();
  cmd->add_option("--max-points", a->o.max_icp_points,
                  "Registration points per scan and pair (evenly subsampled)")
      ->capture_default_str();
  cmd->add_flag("--no-register", a->no_register,
                "Place the scans at their nominal offsets only (the plain mosaic)");
  cmd->add_flag("--force", a->force,
                "Replace an existing --out that is not an earlier output of `mesoscan stitch`");
  cmd->callback([a] { RunStitch(*a); });
}

}  // namespace mesoscan
