#pragma once
// The one line a user reads for a mesoscan::Error: the library names options by their field
// ("TileOptions.size_m"), the command line by its flags; this is the one place that maps
// the first to the second (README "Exit codes": the exit code is the error's kind).

#include <string>

#include "core/error.h"

namespace mesoscan {

// The flag that sets the options field `field` in the subcommand `command` ("reconstruct",
// "brdf plot"); `field` itself when no flag sets it (an option no command line reaches).
std::string FlagForOption(const std::string& command, const std::string& field);

// The error's line without the "mesoscan: " prefix, every options field named by its flag.
std::string FormatErrorLine(const Error& error, const std::string& command);

}  // namespace mesoscan
