// mesoscan: the command-line tool. The only place that wires modules together and catches
// errors for the user: one clear line on stderr and a distinct exit code (README "Exit codes").

#include <cstdio>
#include <exception>

#include "app/commands.h"
#include "app/error_line.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/log.h"
#include "core/progress.h"
#include "core/stderr_filter.h"

namespace {

// The subcommand that ran ("reconstruct", "brdf plot"): its flags name the options in errors.
std::string CommandName(CLI::App* app) {
  std::string name;
  for (const CLI::App* sub = app; sub;) {
    const auto subs = sub->get_subcommands();
    sub = subs.empty() ? nullptr : subs.front();
    if (sub) name += (name.empty() ? "" : " ") + sub->get_name();
  }
  return name;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace mesoscan;
  FilterLibraryNoiseOnStderr();  // no stray "libpng error:" line before ours
  CLI::App app{"mesoscan: lens-shifted structured light to calibrated height fields", "mesoscan"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "mesoscan 0.1.0");
  bool quiet = false, verbose = false;
  app.add_flag("-q,--quiet", quiet, "Only errors; no progress bars");
  app.add_flag("-v,--verbose", verbose, "Debug messages");
  app.parse_complete_callback([&] {
    if (quiet) {
      SetLogLevel(LogLevel::kError);
      Progress::SetEnabled(false);
    }
    if (verbose) SetLogLevel(LogLevel::kDebug);
  });

  AddCaptureCommand(&app);
  AddSimulateCommand(&app);
  AddCalibrateCommand(&app);
  AddReconstructCommand(&app);
  AddExportCommand(&app);
  AddMapsCommand(&app);
  AddCompareCommand(&app);
  AddStitchCommand(&app);
  AddCheckCommand(&app);
  AddBrdfCommand(&app);
  AddRenderCommand(&app);
  AddDoctorCommand(&app);

  try {
    MemoryBudgetBytes();  // a malformed MESOSCAN_MEMORY_BUDGET_MB is a usage error, said first
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "mesoscan: %s (see 'mesoscan --help')\n", e.what());
    return static_cast<int>(ErrorKind::kUsage);
  } catch (const Error& e) {
    std::fprintf(stderr, "mesoscan: %s\n", FormatErrorLine(e, CommandName(&app)).c_str());
    return e.exit_code();
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "mesoscan: out of memory\n");
    return static_cast<int>(ErrorKind::kInternal);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mesoscan: internal error: %s\n", e.what());
    return static_cast<int>(ErrorKind::kInternal);
  }
  return 0;
}
