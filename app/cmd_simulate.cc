// mesoscan simulate: the virtual rig (sim/virtual_rig.h, model in sim/README.md).

#include <cstdio>
#include <regex>
#include <sstream>

#include "app/commands.h"
#include "core/error.h"
#include "core/log.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {

// "7,11,13" -> {7, 11, 13}; "" or "none" -> {}.
std::vector<double> ParsePeriods(const std::string& text) {
  std::vector<double> out;
  if (text.empty() || text == "none") return out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      const double v = std::stod(item, &used);
      if (used != item.size()) throw std::invalid_argument(item);
      out.push_back(v);
    } catch (const std::exception&) {
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "--ps-periods: '" << text << "': expected comma-separated numbers > 2");
    }
  }
  return out;
}

// "WxH+X+Y" -> {W, H, X, Y}.
std::array<int, 4> ParseCrop(const std::string& text) {
  static const std::regex re(R"(^(\d+)x(\d+)\+(\d+)\+(\d+)$)");
  std::smatch m;
  if (!std::regex_match(text, m, re))
    MESOSCAN_THROW(ErrorKind::kUsage, "--crop: '" << text << "': expected WxH+X+Y, e.g. 256x192+960+620");
  std::array<int, 4> c;
  for (int k = 0; k < 4; ++k) {
    const long v = std::stol(m[k + 1].str());
    if (v > 1 << 20) MESOSCAN_THROW(ErrorKind::kUsage, "--crop: '" << text << "': value too large");
    c[k] = static_cast<int>(v);
  }
  return c;
}

}  // namespace

void AddSimulateCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "simulate",
      "Simulate a lens-shift structured-light scan of a procedural object with the virtual rig and "
      "write a session folder with ground truth (model: sim/README.md)");
  struct Args {
    SimulateOptions o;
    std::string out, periods = "7,11,13", crop;
    bool no_white = false, no_black = false, no_shadows = false;
  };
  auto args = std::make_shared<Args>();
  SimulateOptions& o = args->o;
  cmd->add_option("--object", o.object,
                  "coin | plane | ramp | leaf | FILE.exr (a height EXR in the scan-outputs layout)")
      ->capture_default_str();
  cmd->add_option("--rig", o.rig, "paper (built-in rig) | RIG.json (a file with a \"rig\" object)")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Output session folder (written atomically)")->required();
  cmd->add_option("--ps-periods", args->periods,
                  "Sine periods in projector px, comma-separated (> 2), or 'none'")
      ->capture_default_str();
  cmd->add_option("--ps-phases", o.ps_phases, "Phases per sine period (>= 3)")->capture_default_str();
  cmd->add_option("--ls-frames", o.ls_frames,
                  "Lens-shift frames evenly over the shifter range incl. both ends (0 or >= 4)")
      ->capture_default_str();
  cmd->add_flag("--no-white", args->no_white, "Do not write the white frame");
  cmd->add_flag("--no-black", args->no_black, "Do not write the black frame");
  cmd->add_option("--crop", args->crop,
                  "Camera crop WxH+X+Y (pixels of the rig's camera; K's cx, cy are shifted)");
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
  cmd->add_option("--fill-factor", o.fill_factor,
                  "Projector pixel fill factor per axis, (0, 1]")
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
  cmd->add_option("--shift-gain-r", o.shift_gain_r,
                  "Lens-shifter gain: radial term in un^2 + vn^2")
      ->capture_default_str();
  cmd->add_option("--projector-gamma", o.projector_gamma,
                  "Projector response v^g (1 = linear; else written as projector.response)")
      ->capture_default_str();
  cmd->add_option("--exposure", o.exposure,
                  "Frame value of a white-lit albedo-1 surface facing the projector")
      ->capture_default_str();
  cmd->add_option("--ambient", o.ambient, "Ambient/indirect light, relative to the projector's white")
      ->capture_default_str();
  cmd->add_option("--full-well", o.full_well_e, "Electrons at full scale (shot noise)")
      ->capture_default_str();
  cmd->add_option("--read-noise", o.read_noise_e, "Read noise, electrons rms")->capture_default_str();
  cmd->add_option("--adc-bits", o.adc_bits, "ADC bits (8..16), stored in 16-bit PNG")
      ->capture_default_str();
  cmd->add_option("--gain-jitter", o.gain_jitter, "Per-frame gain jitter, relative sigma")
      ->capture_default_str();
  cmd->add_option("--shift-position-error", o.shift_position_error_px,
                  "Lens-shifter position error per frame, RMS in projector px")
      ->capture_default_str();
  cmd->callback([args] {
    SimulateOptions opt = args->o;
    opt.ps_periods_px = ParsePeriods(args->periods);
    if (!args->crop.empty()) opt.crop = ParseCrop(args->crop);
    opt.white = !args->no_white;
    opt.black = !args->no_black;
    opt.shadows = !args->no_shadows;
    const SimulateSummary summary = Simulate(opt, args->out);
    MESOSCAN_LOG(kInfo) << args->out << ": " << summary.BriefReport();
  });
}

}  // namespace mesoscan
