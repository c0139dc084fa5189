#pragma once
// The CLI is a table of subcommands (COLMAP exe/colmap.cc): each Add*Command registers one
// subcommand on the root app, with its options and a callback. Callbacks throw mesoscan::Error;
// main() turns it into one line on stderr and the error's exit code.

#include <CLI/CLI.hpp>

namespace mesoscan {

void AddCheckCommand(CLI::App* app);        // cmd_check.cc
void AddDoctorCommand(CLI::App* app);       // cmd_doctor.cc
void AddSimulateCommand(CLI::App* app);     // cmd_simulate.cc
void AddReconstructCommand(CLI::App* app);  // cmd_reconstruct.cc
void AddExportCommand(CLI::App* app);       // cmd_export.cc
void AddBrdfCommand(CLI::App* app);         // cmd_brdf.cc
void AddRenderCommand(CLI::App* app);       // cmd_render.cc
void AddCaptureCommand(CLI::App* app);      // cmd_capture.cc
void AddMapsCommand(CLI::App* app);         // cmd_maps.cc
void AddCalibrateCommand(CLI::App* app);    // cmd_calibrate.cc
void AddCompareCommand(CLI::App* app);      // cmd_compare.cc
void AddStitchCommand(CLI::App* app);       // cmd_stitch.cc

}  // namespace mesoscan
