// mesoscan simulate: the virtual rig (sim/virtual_rig.h, model in sim/README.md).

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "app/commands.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/rect.h"
#include "session/patterns.h"
#include "session/session.h"
#include "sim/board_sim.h"
#include "sim/virtual_rig.h"

namespace mesoscan {

void AddSimulateCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "simulate",
      "Simulate a lens-shift structured-light scan of a procedural object with the virtual rig and "
      "write a session folder with ground truth (model: sim/README.md)");
  struct Args {
    SimulateOptions o;
    std::string out, periods = "7,11,13", crop;
    bool no_white = false, no_black = false, no_shadows = false, force = false;
    // Calibration boards (--object board:checker:COLSxROWS:SQUARE_MM).
    std::string pose = "0,0,0,0,0,0", periods_y, frame_format = "png16";
    bool low_contrast = false;
    std::string axis = "x";
    // The object's pose and a known change (sim/object_change.h).
    std::string object_pose, field_offset;
    std::vector<std::string> scratches, erosions;
    std::string patterns = "sine";
    bool grey = false;
    std::string grey_card;  // X,Y,SIZE:REFLECTANCE, mm
  };
  auto args = std::make_shared<Args>();
  SimulateOptions& o = args->o;
  cmd->add_option(
         "--object", o.object,
         "coin | plane | ramp | leaf | fabric | metal | impasto[:WxH] (a painting, W x H mm) | "
         "mount (empty) | FILE.exr (a height EXR in "
         "the "
         "scan-outputs layout) | board:checker:COLSxROWS:SQUARE_MM (a calibration session)")
      ->capture_default_str();
  cmd->add_option("--rig", o.rig, "paper (built-in rig) | RIG.json (a file with a \"rig\" object)")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Output session folder (written atomically)")->required();
  cmd->add_option("--ps-periods", args->periods,
                  "Sine periods in projector px, comma-separated (> 2), or 'none'")
      ->capture_default_str();
  cmd->add_option("--axis", args->axis,
                  "Fringe axis of the sines and lens-shift stripes: x (vertical fringes) or y "
                  "(horizontal; the paper rig's projector is then mounted in portrait and its "
                  "lens shifter moves along y)")
      ->check(CLI::IsMember({"x", "y"}))
      ->capture_default_str();
  cmd->add_option("--ps-phases", o.ps_phases, "Phases per sine period (>= 3)")
      ->capture_default_str();
  cmd->add_option("--ls-frames", o.ls_frames,
                  "Lens-shift frames evenly over the shifter range incl. both ends (0 or >= 4)")
      ->capture_default_str();
  cmd->add_flag("--no-white", args->no_white, "Do not write the white frame");
  cmd->add_flag("--no-black", args->no_black, "Do not write the black frame");
  cmd->add_option("--crop", args->crop,
                  "Camera crop X,Y,W,H or WxH+X+Y (pixels of the rig's camera; K's cx, cy are "
                  "shifted)");
  cmd->add_option("--noise", o.noise, "Noise scale: shot, read and gain jitter (0 = noiseless)")
      ->capture_default_str();
  cmd->add_option("--seed", o.seed, "Random seed")->capture_default_str();
  cmd->add_option("--supersample", o.supersample,
                  "Camera pixel-area integration: N x N rays per pixel (1..8)")
      ->capture_default_str();
  cmd->add_flag("--no-shadows", args->no_shadows, "Do not cast shadows towards the projector");
  cmd->add_option("--object-pixel-size", o.object_pixel_size_m,
                  "Grid spacing of procedural objects, m (0 = the object's default)")
      ->capture_default_str();
  cmd->add_option("--object-label", o.object_label, "The session's \"object\" text");
  cmd->add_option("--fill-factor", o.fill_factor, "Projector pixel fill factor per axis, (0, 1]")
      ->capture_default_str();
  cmd->add_option("--blur", o.blur_sigma_px, "Projector blur sigma at focus, projector px")
      ->capture_default_str();
  cmd->add_option("--defocus", o.defocus_px_per_m,
                  "Blur sigma growth per metre of |z - focus height|, px/m")
      ->capture_default_str();
  cmd->add_option("--focus-height", o.focus_height_m,
                  "Height of the projector's focus plane, m (0 = the mount; default: the "
                  "object's mid height)");
  cmd->add_option("--shift-gain-x", o.shift_gain_x, "Lens-shifter gain: linear term in un")
      ->capture_default_str();
  cmd->add_option("--shift-gain-y", o.shift_gain_y, "Lens-shifter gain: linear term in vn")
      ->capture_default_str();
  cmd->add_option("--shift-gain-r", o.shift_gain_r, "Lens-shifter gain: radial term in un^2 + vn^2")
      ->capture_default_str();
  cmd->add_option("--projector-gamma,--proj-gamma", o.projector_gamma,
                  "Projector response v^g (1 = linear; else written as projector.response)")
      ->capture_default_str();
  cmd->add_option("--projector-curve,--proj-curve", o.projector_curve,
                  "s-curve: a projector response that is no power law (a black offset, crushed "
                  "shadows, soft highlights; sim/README.md), unknown to session.json (written "
                  "linear): the decoder must find it from the frames");
  cmd->add_option("--exposure", o.exposure,
                  "Frame value of a white-lit albedo-1 surface facing the projector")
      ->capture_default_str();
  cmd->add_option("--ambient", o.ambient,
                  "Ambient/indirect light, relative to the projector's white")
      ->capture_default_str();
  cmd->add_option("--full-well", o.full_well_e, "Electrons at full scale (shot noise)")
      ->capture_default_str();
  cmd->add_option("--read-noise", o.read_noise_e, "Read noise, electrons rms")
      ->capture_default_str();
  cmd->add_option("--adc-bits", o.adc_bits, "ADC bits (8..16), stored in 16-bit PNG")
      ->capture_default_str();
  cmd->add_option("--gain-jitter", o.gain_jitter, "Per-frame gain jitter, relative sigma")
      ->capture_default_str();
  cmd->add_flag("--force", args->force,
                "Replace an existing --out that is not an earlier output of `mesoscan simulate`");
  cmd->add_option("--pose", args->pose,
                  "Board only: world pose rx,ry,rz,tx,ty,tz (rotation vector in degrees, mm)")
      ->capture_default_str();
  cmd->add_option("--ps-periods-y", args->periods_y,
                  "Board only: sine periods along projector y (default: the projector height "
                  "and 1/16 of it; --ps-periods defaults to the width and 1/16 of it)");
  cmd->add_option("--frame-format", args->frame_format,
                  "Board only: png16 | png8 | bmp | tif8 (8-bit formats ignore --adc-bits)")
      ->capture_default_str();
  cmd->add_flag("--low-contrast", args->low_contrast,
                "Board only: grey squares (albedo 0.45) on white paper (0.8)");
  cmd->add_option("--object-pose", args->object_pose,
                  "The object's pose on the mount: rx,ry,rz,tx,ty,tz (rotation vector in degrees "
                  "about the world origin, then mm), e.g. a re-placed object to compare");
  cmd->add_option("--field-offset", args->field_offset,
                  "X,Y (mm): the camera field's centre over object point X,Y (the object moved "
                  "by -X,-Y before --object-pose): one tile of a mosaic of a large object");
  cmd->add_option("--scratch", args->scratches,
                  "A known change: a groove X0,Y0,X1,Y1,WIDTH,DEPTH (object mm, mm, mm, mm, um, "
                  "um; flat bottom, 60 um walls); repeatable");
  cmd->add_option("--erosion", args->erosions,
                  "A known change: a round patch worn away CX,CY,RADIUS,DEPTH (object mm, mm, mm, "
                  "um; 60 um walls); repeatable");
  cmd->add_option("--wear", o.change.wear_file,
                  "A known change: a height-change EXR (channel Z, signed metres, the scan-outputs "
                  "grid attributes) added to the object's surface in object coordinates");
  cmd->add_option(
         "--patterns", args->patterns,
         "sine (the --ps-periods sets) | heterodyne (three-frequency set: --ps-periods default "
         "42,45,48, 3 steps each, no lens shift; with --proj-gamma the projector's harmonics) | "
         "graycode (a Gray code of the projector's columns "
         "with inverse frames, white, black; no sines, no lens shift) | sine+graycode (one "
         "--ps-periods period with a complementary Gray code of half its width); a board "
         "(--object board:...) takes them along both projector axes (sine+graycode: one "
         "--ps-periods and one --ps-periods-y period)")
      ->capture_default_str();
  cmd->add_flag("--grey", args->grey,
                "Grey object and frames (the fabric and the coin are coloured by default)");
  cmd->add_option("--grey-card", args->grey_card,
                  "A neutral grey card on the mount: X,Y,SIDE:REFLECTANCE (centre and side in mm, "
                  "e.g. -10,8,4:0.18); its camera rectangle goes into session.json");
  cmd->add_option("--projector-falloff", o.projector_falloff,
                  "Projector vignetting f: relative irradiance 1 - f*(un^2 + vn^2), [0, 0.5)")
      ->capture_default_str();
  cmd->add_option("--shift-position-error", o.shift_position_error_px,
                  "Lens-shifter position error per frame, RMS in projector px")
      ->capture_default_str();
  cmd->callback([args, cmd] {
    SimulateOptions opt = args->o;
    if (IsBoardObject(opt.object)) {
      if (!opt.projector_curve.empty())
        MESOSCAN_THROW(ErrorKind::kUsage,
                       "--projector-curve: scan sessions only (not with --object board:...)");
      BoardSimOptions bo;
      bo.board = CalibrationBoard::Parse(opt.object.substr(6), "BoardSimOptions.board");
      bo.pose = ParseBoardPose(args->pose);
      bo.frame_format = args->frame_format;
      if (args->low_contrast) bo.dark_albedo = 0.45, bo.light_albedo = 0.8;
      opt.crop.reset();
      if (!args->crop.empty()) opt.crop = ParsePixelRect(args->crop, "SimulateOptions.crop");
      const Rig rig = ResolveRig(opt);
      // The calibration plan of `capture --plan calibration` (session/patterns.h), periods as
      // given.
      const FramePlanOptions plan = CalibrationPlan(rig.projector.width, rig.projector.height);
      opt.ps_periods_px = cmd->count("--ps-periods") == 0
                              ? plan.periods_px
                              : ParsePeriodList(args->periods, "SimulateOptions.ps_periods_px");
      bo.ps_periods_y_px =
          cmd->count("--ps-periods-y") == 0
              ? plan.cross_periods_px
              : ParsePeriodList(args->periods_y, "BoardSimOptions.ps_periods_y_px");
      // --patterns graycode | sine+graycode: the calibration plan's pattern family along both
      // axes (as `capture --plan calibration --patterns`).
      FramePlanOptions set = plan;
      set.periods_px = opt.ps_periods_px;
      set.cross_periods_px = bo.ps_periods_y_px;
      ApplyPatternSet(args->patterns, rig.projector.width, rig.projector.height, &set,
                      "FramePlanOptions.patterns");
      opt.ps_periods_px = set.periods_px;
      bo.ps_periods_y_px = set.cross_periods_px;
      opt.graycode_bits = set.graycode_bits;
      opt.graycode_block_px = set.graycode_block_px;
      bo.graycode_y_bits = set.cross_graycode_bits;
      bo.graycode_y_block_px = set.cross_graycode_block_px;
      opt.white = !args->no_white;
      opt.black = !args->no_black;
      const OutputSpec board_spec{"simulate",  "--out",
                                  args->out,   {std::filesystem::exists(opt.rig) ? opt.rig : ""},
                                  args->force, {}};
      SimulateSummary summary;
      WriteOutputFolder(board_spec, [&](const std::filesystem::path& tmp) {
        summary = SimulateBoard(opt, bo, tmp);
      });
      MESOSCAN_LOG(kInfo) << args->out << ": " << summary.BriefReport();
      return;
    }
    opt.ps_periods_px = ParsePeriodList(args->periods, "SimulateOptions.ps_periods_px");
    if (!args->object_pose.empty())
      opt.change.pose = ParseBoardPose(args->object_pose, "ObjectChange.pose");
    if (!args->field_offset.empty())
      opt.change.field_offset = ParseFieldOffset(args->field_offset, "ObjectChange.field_offset");
    for (const std::string& s : args->scratches)
      opt.change.scratches.push_back(ParseScratch(s, "ObjectChange.scratches"));
    for (const std::string& s : args->erosions)
      opt.change.erosions.push_back(ParseErosion(s, "ObjectChange.erosions"));
    if (args->patterns == "heterodyne") {
      // Three-frequency heterodyne set: three close periods, three steps each (sine patterns;
      // decoded by the periods' temporal unwrapping), no lens shift unless asked.
      if (cmd->count("--ps-periods") == 0) opt.ps_periods_px = HeterodynePeriods();
      if (cmd->count("--ps-phases") == 0) opt.ps_phases = 3;
      if (cmd->count("--ls-frames") == 0) opt.ls_frames = 0;
    } else if (args->patterns != "sine") {
      const Rig rig = ResolveRig(opt);
      const int extent = args->axis == "y" ? rig.projector.height : rig.projector.width;
      if (args->patterns == "graycode") {
        opt.ps_periods_px.clear();
        opt.graycode_block_px = 1;
      } else if (args->patterns == "sine+graycode") {
        if (opt.ps_periods_px.size() != 1)
          MESOSCAN_THROW(
              ErrorKind::kUsage,
              "--patterns sine+graycode: expected one --ps-periods period, got " << args->periods);
        opt.graycode_block_px = 0.5 * opt.ps_periods_px[0];
        if (!(opt.graycode_block_px >= 1))
          MESOSCAN_THROW(ErrorKind::kUsage, "--patterns sine+graycode: the period must be >= 2 px");
      } else {
        MESOSCAN_THROW(ErrorKind::kUsage,
                       "--patterns: expected sine, heterodyne, graycode or sine+graycode, got "
                           << args->patterns);
      }
      opt.graycode_bits = static_cast<int>(std::ceil(std::log2(extent / opt.graycode_block_px)));
      if (cmd->count("--ls-frames") == 0) opt.ls_frames = 0;
    }
    if (!args->crop.empty()) opt.crop = ParsePixelRect(args->crop, "SimulateOptions.crop");
    opt.axis = args->axis.front();
    // Periods whose phases repeat within the projector make a session nothing can decode:
    // refused before simulating (the session reader would refuse the written session).
    if (!opt.ps_periods_px.empty() && opt.graycode_bits == 0) {
      const Rig rig = ResolveRig(opt);
      const int extent = opt.axis == 'y' ? rig.projector.height : rig.projector.width;
      const double range = UnambiguousRangePx(opt.ps_periods_px, extent);
      if (range < extent)
        MESOSCAN_THROW(ErrorKind::kUsage, "simulate: --ps-periods "
                                              << args->periods << ": the phases repeat after "
                                              << range << " px, expected an unambiguous range "
                                              << "covering the projector's " << extent
                                              << " px (e.g. 7,11,13, or add a period >= " << extent
                                              << ")");
    }

    opt.white = !args->no_white;
    opt.black = !args->no_black;
    opt.shadows = !args->no_shadows;
    opt.colour = !args->grey;
    if (!args->grey_card.empty()) {
      double x = 0, y = 0, side = 0, rho = 0;
      char c1 = 0, c2 = 0, c3 = 0;
      std::istringstream in(args->grey_card);
      if (!(in >> x >> c1 >> y >> c2 >> side >> c3 >> rho) || c1 != ',' || c2 != ',' || c3 != ':' ||
          !(in >> std::ws).eof() || !(side > 0))
        MESOSCAN_THROW(ErrorKind::kUsage, "--grey-card: expected X,Y,SIDE:REFLECTANCE (mm), got '"
                                              << args->grey_card << "'");
      opt.grey_card_x = x * 1e-3;
      opt.grey_card_y = y * 1e-3;
      opt.grey_card_size = side * 1e-3;
      opt.grey_card_reflectance = rho;
    }
    // A FILE.exr object and a RIG.json are inputs: --out must not be, contain or lie in them.
    const auto is_file = [](const std::string& v) { return std::filesystem::exists(v); };
    const OutputSpec out_spec{"simulate",
                              "--out",
                              args->out,
                              {is_file(opt.object) ? opt.object : "",
                               is_file(opt.rig) ? opt.rig : "", opt.change.wear_file},
                              args->force,
                              {}};
    CheckOutputFolder(out_spec);
    // Simulation memory, checked before anything is built: the scene (~300 MB for the procedural
    // objects) and per camera pixel ~100 bytes plus ~30 per supersample ray (measured: 91 and
    // 291 bytes at 1 and 9 rays).
    {
      const Rig rig = ResolveRig(opt);
      const double pixels = static_cast<double>(rig.camera.width) * rig.camera.height;
      CheckMemoryBudget("simulate: a " + std::to_string(rig.camera.width) + "x" +
                            std::to_string(rig.camera.height) + " camera",
                        300e6 + pixels * (100.0 + 30.0 * opt.supersample * opt.supersample));
    }
    SimulateSummary summary;
    WriteOutputFolder(out_spec, [&](const std::filesystem::path& tmp) {
      summary = Simulate(opt, tmp);  // writes straight into our staging folder
    });
    MESOSCAN_LOG(kInfo) << args->out << ": " << summary.BriefReport();
  });
}

}  // namespace mesoscan
