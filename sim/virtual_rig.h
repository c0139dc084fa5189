#pragma once
// The virtual rig: ray-casts a procedural object (assets/objects.h) lying on the mount with
// Embree (render/embree_scene.h), evaluates the projector's light for every frame of a lens-shift
// scan, adds sensor noise and writes a session folder (docs/formats.md) with
// ground truth. The model, its formulas and defaults are documented in sim/README.md; every
// parameter below is also recorded under the top-level "simulation" key of session.json.

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "core/json.h"
#include "core/rect.h"
#include "session/patterns.h"
#include "session/session.h"
#include "sim/object_change.h"

namespace mesoscan {

struct SimulateOptions {
  // ---- scene and rig ----
  // "coin", "plane", "ramp", "leaf" or a height EXR in the scan-outputs layout.
  std::string object = "coin";
  // Grid spacing of procedural objects in metres (> 0), or 0 for the object's default
  // (coin 10 um, ramp 20 um, leaf 20 um, plane 50 um). Ignored for EXR objects.
  double object_pixel_size_m = 0.0;
  // "paper" (the built-in rig, sim/README.md) or a JSON file holding a "rig" object in the
  // session format.
  std::string rig = "paper";
  // Camera crop in pixels of the rig's camera: the output camera is w x h with cx -= x,
  // cy -= y (a valid camera of its own). Must lie inside the rig's camera.
  std::optional<PixelRect> crop;
  // The object's natural colour (assets/objects.h ColourObject: a dyed fabric, a patinated coin):
  // RGB frames and gt_albedo.exr. false (or an object without one): grey frames, as before.
  bool colour = true;
  // A neutral grey card on the mount (world metres: centre x, y and side), under the object where
  // they overlap; size 0 = none. Its camera pixel rectangle is recorded in session.json
  // ("simulation"."grey_card") for reconstruction's reference.
  double grey_card_x = 0, grey_card_y = 0, grey_card_size = 0;
  double grey_card_reflectance = 0.18;  // in (0, 1]
  // The session's "object" text; empty: the object's name.
  std::string object_label;
  // The object's pose on the mount and a known change to its surface (scratches, erosion, a
  // wear EXR), applied before ray casting (sim/object_change.h); empty: the object as generated.
  ObjectChange change;

  // ---- frame plan (patterns vary along projector u, axis "x", or v, axis "y") ----
  // Fringe axis of every sine and stripes frame: 'x' (vertical fringes) or 'y' (horizontal). With
  // 'y' the rig's lens shifter must move along y; the "paper" rig then has its projector mounted
  // in portrait (PortraitProjector), so that its rows, not its columns, span the baseline.
  char axis = 'x';
  std::vector<double> ps_periods_px{7, 11, 13};  // sine periods, each > 2 px
  int ps_phases = 3;                             // phases per period (>= 3), 2*pi*k/phases
  // Gray code along `axis` (FramePlanOptions::graycode_*): 0 bits = none.
  int graycode_bits = 0;
  double graycode_block_px = 1.0;
  bool graycode_inverse = true;
  int ls_frames = 50;  // lens-shift (1-px stripes) frames evenly over the shifter range incl.
                       // both ends, shift_steps rounded to integers; 0 or >= 4
  bool white = true;   // a white frame
  bool black = true;   // a black frame

  // ---- sampling ----
  int supersample = 3;  // camera pixel-area integration: S x S rays per pixel (1..8)
  bool shadows = true;  // occlusion rays towards the projector (cast shadows)

  // ---- projector optics ----
  double fill_factor = 0.9;     // lit fraction of the pixel pitch along each axis, (0, 1]
  double blur_sigma_px = 0.35;  // Gaussian blur sigma at the focus distance, projector px, > 0
  // The projector is focused on the plane z = focus_height_m (a Scheimpflug projector focused
  // parallel to the mount); sigma = blur_sigma_px + defocus_px_per_m * |z - focus_height_m|.
  double defocus_px_per_m = 200;  // sigma growth per metre off the focus plane, >= 0
  // World height of the focus plane, metres; NaN (the default): the object's mid height, half
  // way between the lowest and the highest point of its height field (as an operator focuses).
  double focus_height_m = std::numeric_limits<double>::quiet_NaN();
  // Lens-shifter gain g(u, v) = 1 + gx * un + gy * vn + gr * (un^2 + vn^2), with un = (u - cx) /
  // (W/2), vn = (v - cy) / (H/2) the projector coordinates of the surface point at shift 0.
  // The true displacement of the image is shift_steps / steps_per_px * g. |g - 1| < 0.5.
  double shift_gain_x = 0.04;
  double shift_gain_y = -0.02;
  double shift_gain_r = 0.03;
  // Lens-shifter position errors (missed steps, backlash, lead-screw non-linearity): every
  // lens-shift frame's shifter position is off by an independent N(0, this^2) error in projector
  // px (seeded; not scaled by `noise`), the same for all pixels. >= 0, < 0.5.
  double shift_position_error_px = 0.0;
  // Projector response: displayed value v emits light v^gamma. 1 = linear (no response key
  // written); otherwise projector.response = {"gamma": g}. In (0, 5].
  double projector_gamma = 1.0;
  // A projector response that is no power law (scans; not written to session.json, which
  // describes linear or gamma only: the decoder must find it from the frames): "" = none (the
  // gamma above), or "s-curve": light 0.03 + 0.97 L(v), L a logistic step of slope 7 centred at
  // 0.6 scaled to [0, 1] (a black offset, crushed shadows and a soft clip of the highlights).
  // Not with projector_gamma != 1.
  std::string projector_curve;

  // Projector falloff (vignetting) recorded as rig.projector.falloff: relative irradiance
  // 1 - f * (un^2 + vn^2) (session/session.h ProjectorFalloff), f in [0, 0.5); 0 = none.
  double projector_falloff = 0.0;

  // ---- radiometry (frame values normalised to [0, 1] = ADC full scale) ----
  // Frame value of a white, fully lit, albedo-1 surface facing the projector at the reference
  // distance r0 (projector centre to world origin), before noise. > 0.
  double exposure = 0.85;
  // Ambient / indirect light: adds exposure * ambient * albedo to every frame (also black). >= 0.
  double ambient = 0.03;

  // ---- sensor noise ----
  double noise = 1.0;          // scale of all random noise (shot, read, gain jitter); 0 = none
  double full_well_e = 20000;  // electrons at frame value 1.0 (shot noise), > 0
  double read_noise_e = 8.0;   // read noise, electrons rms, >= 0
  int adc_bits = 14;           // ADC depth; frames are 16-bit PNG with bit replication, 8..16
  double gain_jitter = 0.005;  // per-frame multiplicative gain, relative sigma, >= 0
  uint64_t seed = 1;           // random seed (frames are deterministic for a seed)

  void Check() const;  // throws Error(kUsage) at the field at fault
};

// Per-pixel noise of a frame in normalised units [0, 1] (sim/README.md "Noise"): for a noise-free
// value m, the recorded value is m * (1 + jitter) + e, with e ~ N(0, Variance(m)) independent per
// pixel and frame, and jitter ~ N(0, GainJitterSigma()) shared by all pixels of a frame.
struct NoiseModel {
  double scale = 1.0;
  double full_well_e = 20000;
  double read_noise_e = 8;
  int adc_bits = 14;
  double gain_jitter = 0.005;

  // Per-pixel variance (normalised units^2) of a pixel whose noise-free value is `mean`:
  // scale^2 * (mean / full_well + (read / full_well)^2) + q^2 / 12, q = 1 / (2^bits - 1).
  double Variance(double mean) const;
  double Sigma(double mean) const;
  double GainJitterSigma() const { return scale * gain_jitter; }
};
NoiseModel MakeNoiseModel(const SimulateOptions& options);

// The built-in "paper" rig (sim/README.md "The paper rig").
Rig PaperRig();
// `rig` with its projector turned 90 degrees about its optical axis (portrait mount): device
// x' = -y, y' = x, width and height swapped, K's focal lengths and centre swapped (the centre
// mirrored along the new x), distortion kept (the paper rig's is zero), lens shifter along y. The
// new row v' equals the old column u, so rows span the baseline as the columns did.
Rig PortraitProjector(Rig rig);
// options.rig resolved ("paper", turned portrait for axis 'y', or a file), with options.crop
// applied.
Rig ResolveRig(const SimulateOptions& options);
// Applies a camera crop; throws Error(kUsage) at SimulateOptions.crop if it leaves the camera.
PinholeCamera CropCamera(const PinholeCamera& camera, const PixelRect& crop);

// The lens-shifter gain g(u, v) of the options at projector pixel (u, v).
double ShifterGain(const SimulateOptions& options, const PinholeCamera& projector, double u,
                   double v);

// The frame plan the options ask for (session/patterns.h: sines along x, lens shift over the rig's
// shifter range, white, black); throws Error(kUsage) at SimulateOptions.ls_frames when the rig
// cannot do it.
FramePlanOptions SimulationFramePlan(const SimulateOptions& options, const Rig& rig);
// MakeStandardFrames of that plan: files frames/*.png.
std::vector<Frame> MakeSimulationFrames(const SimulateOptions& options, const Rig& rig);

struct SimulateSummary {
  int width = 0, height = 0;  // camera image size
  int frames = 0;
  int64_t rays = 0;            // camera rays cast (subsamples + centre rays)
  int64_t lit_pixels = 0;      // pixels whose centre sees a surface lit by the projector
  int64_t unrefined_hits = 0;  // hits kept in float precision (EmbreeScene::unrefined_hits)
  double seconds_scene = 0, seconds_raycast = 0, seconds_frames = 0, seconds_total = 0;
  std::string BriefReport() const;
};

// Simulates the scan and writes the session folder `out_dir` atomically (an existing folder is
// replaced only on success): session.json, frames/*.png, gt_points.exr, gt_height.exr.
SimulateSummary Simulate(const SimulateOptions& options, const std::filesystem::path& out_dir);

}  // namespace mesoscan
