#include "app/error_line.h"

#include <string_view>

namespace mesoscan {
namespace {

struct OptionFlag {
  std::string_view field;    // "Struct.field", as the library names it
  std::string_view command;  // the subcommand where this flag sets it; "" = every subcommand
  std::string_view flag;
};

// Every options field a library error may name, with the flag that sets it. A field set by
// different flags in different subcommands has one row per subcommand, the specific rows first.
constexpr OptionFlag kOptionFlags[] = {
    // Outputs (core/output_dir.h; the caller names the output itself).
    {"OutputSpec.force", "", "--force"},
    // capture
    {"FramePlanOptions.periods_px", "", "--periods"},
    {"FramePlanOptions.cross_periods_px", "", "--periods-y"},
    {"FramePlanOptions.patterns", "", "--patterns"},
    {"SequencerOptions.settle_s", "", "--settle"},
    {"SequencerOptions.max_new_frames", "", "--max-frames"},
    {"SequencerOptions.force", "", "--force"},
    // simulate
    {"SimulateOptions.object", "", "--object"},
    {"SimulateOptions.object_pixel_size_m", "", "--object-pixel-size"},
    {"SimulateOptions.rig", "", "--rig"},
    {"SimulateOptions.crop", "", "--crop"},
    {"SimulateOptions.grey_card_size", "", "--grey-card"},
    {"SimulateOptions.grey_card_reflectance", "", "--grey-card"},
    {"SimulateOptions.projector_falloff", "", "--projector-falloff"},
    {"SimulateOptions.axis", "", "--axis"},
    {"SimulateOptions.graycode_bits", "", "--patterns"},
    {"SimulateOptions.graycode_block_px", "", "--patterns"},
    {"SimulateOptions.ps_periods_px", "", "--ps-periods"},
    {"SimulateOptions.ps_phases", "", "--ps-phases"},
    {"SimulateOptions.ls_frames", "", "--ls-frames"},
    {"SimulateOptions.supersample", "", "--supersample"},
    {"SimulateOptions.fill_factor", "", "--fill-factor"},
    {"SimulateOptions.blur_sigma_px", "", "--blur"},
    {"SimulateOptions.defocus_px_per_m", "", "--defocus"},
    {"SimulateOptions.focus_height_m", "", "--focus-height"},
    {"SimulateOptions.shift_gain_x", "", "--shift-gain-x"},
    {"SimulateOptions.shift_gain_y", "", "--shift-gain-y"},
    {"SimulateOptions.shift_gain_r", "", "--shift-gain-r"},
    {"SimulateOptions.shift_position_error_px", "", "--shift-position-error"},
    {"SimulateOptions.projector_gamma", "", "--projector-gamma"},
    {"SimulateOptions.projector_curve", "", "--projector-curve"},
    {"SimulateOptions.exposure", "", "--exposure"},
    {"SimulateOptions.ambient", "", "--ambient"},
    {"SimulateOptions.noise", "", "--noise"},
    {"SimulateOptions.full_well_e", "", "--full-well"},
    {"SimulateOptions.read_noise_e", "", "--read-noise"},
    {"SimulateOptions.adc_bits", "", "--adc-bits"},
    {"SimulateOptions.gain_jitter", "", "--gain-jitter"},
    {"SimulateOptions.change", "", "--object-pose/--scratch/--erosion"},
    {"ObjectChange.pose", "", "--object-pose"},
    {"ObjectChange.field_offset", "", "--field-offset"},
    {"StitchOptions.offsets_m", "", "--offset"},
    {"StitchOptions.feather", "", "--feather"},
    {"StitchOptions.min_confidence", "", "--min-confidence"},
    {"StitchOptions.min_overlap", "", "--min-overlap"},
    {"StitchOptions.max_correction_deg", "", "--max-correction-deg"},
    {"StitchOptions.max_correction_fraction", "", "--max-correction"},
    {"StitchOptions.max_icp_points", "", "--max-points"},
    {"ObjectChange.scratches", "", "--scratch"},
    {"ObjectChange.erosions", "", "--erosion"},
    {"BoardSimOptions.board", "", "--object"},
    {"BoardSimOptions.pose", "", "--pose"},
    {"BoardSimOptions.ps_periods_y_px", "", "--ps-periods-y"},
    {"BoardSimOptions.graycode_y_bits", "", "--patterns"},
    {"BoardSimOptions.graycode_y_block_px", "", "--patterns"},
    {"BoardSimOptions.frame_format", "", "--frame-format"},
    // calibrate
    {"CalibrateOptions.board", "", "--board"},
    {"CalibrateOptions.fix", "", "--fix"},
    {"CalibrateOptions.model", "", "--model"},
    // reconstruct
    {"FrameLoadOptions.roi", "", "--roi"},
    {"LensShiftStageOptions.fitter", "", "--fitter"},
    // export, maps, reconstruct --export
    {"ExportOptions.formats", "reconstruct", "--export"},
    {"ExportOptions.formats", "", "--format"},
    {"ExportOptions.crop", "", "--crop"},
    {"ExportOptions.pixel_size_m", "", "--pixel-size"},
    {"ExportOptions.max_triangles", "", "--max-triangles"},
    {"GridMeshOptions.max_triangles", "", "--max-triangles"},
    {"ExportOptions.name", "", "--name"},
    {"MapsOptions.crop", "", "--crop"},
    {"MapsOptions.name", "", "--name"},
    {"MapsOptions.maps", "", "--maps"},
    {"FillOptions.method", "", "--fill"},
    {"FlattenOptions.method", "", "--flatten"},
    {"FlattenOptions.poly_degree", "", "--flatten"},
    {"FlattenOptions.highpass_wavelength_m", "", "--flatten"},
    {"TileOptions.size_m", "", "--tile"},
    {"TileOptions.method", "", "--tile-method"},
    {"TileOptions.at_px", "", "--tile-at"},
    {"MapsOptions.size_px", "", "--size"},
    {"MapsOptions.roughness", "", "--roughness"},
    {"MapsOptions.grey_card", "", "--grey-card"},
    // compare
    {"CompareOptions.mount_clearance_m", "", "--mount-clearance"},
    {"CompareOptions.min_confidence", "", "--min-confidence"},
    {"CompareOptions.k_sigma", "", "--k-sigma"},
    {"CompareOptions.window", "", "--window"},
    {"CompareOptions.mask", "", "--region"},
    {"CompareOptions.exclude", "", "--exclude"},
    {"CompareOptions.coarse_voxel_m", "", "--coarse-voxel"},
    {"CompareOptions.max_icp_points", "", "--max-points"},
    // brdf, render
    {"MerlOptions.accept_invalid_entries", "", "--accept-invalid"},
    {"RenderOptions.size", "", "--size"},
    {"RenderOptions.max_spp", "", "--spp"},
    {"RenderOptions.noise", "", "--noise"},
    {"RenderOptions.time_limit_s", "", "--time"},
    {"RenderOptions.camera", "", "--camera"},
};

}  // namespace

std::string FlagForOption(const std::string& command, const std::string& field) {
  for (const OptionFlag& f : kOptionFlags)
    if (f.field == field && (f.command.empty() || f.command == command)) return std::string(f.flag);
  return field;
}

std::string FormatErrorLine(const Error& error, const std::string& command) {
  return error.Format([&](const std::string& field) { return FlagForOption(command, field); });
}

}  // namespace mesoscan
