#include "app/commands.h"
#include "core/error.h"

namespace mesoscan {

// Placeholder until the owning issue lands: refuses clearly rather than pretending.
void AddExportCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand("export", "(not implemented yet)");
  cmd->allow_extras();
  cmd->callback([] {
    MESOSCAN_THROW(ErrorKind::kInternal, "'export' is not implemented yet");
  });
}

}  // namespace mesoscan
