#pragma once
// Output safety shared by every command that writes a folder or a file named by --out
// (reconstruct, export, render, simulate, brdf plot/tabulate, and later maps/calibrate):
//
//  - --out must not be, contain, or lie inside any of the command's inputs (exit 2, nothing
//    touched). Paths are compared after weakly_canonical, so symlinks and `..` do not hide it.
//  - An existing --out folder is replaced only if it is empty or a previous output of the same
//    command (the hidden marker file kOutputMarker names the command), unless force is set.
//    An existing --out that is a file (or a folder where a file is expected) is refused (exit 2).
//  - The output is written into a temporary sibling folder and then swapped into place:
//    renameat2(RENAME_EXCHANGE) where the filesystem has it (one atomic step), otherwise
//    old -> backup name, new -> final, remove backup. A kill at any point leaves either the
//    old or the new output under the final name (or, between the two fallback renames, the old
//    one under the backup name, which the next run of any command reading or writing that
//    path renames back: RestoreInterruptedReplacement).
//  - A writer asked to replace a folder that is this process's own empty staging folder (a
//    command staging a library writer that stages too) writes straight into it: no nested
//    temporaries.
//  - Every run first cleans stale temporaries and backups of earlier runs (processes no
//    longer alive) next to --out, recovering a backup whose final name is missing.

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace mesoscan {

inline constexpr const char* kOutputMarker = ".mesoscan-output";

struct OutputSpec {
  std::string command;                        // "reconstruct", "export", ...
  std::string option = "out";                 // the caller's name for the output (messages)
  std::filesystem::path out;                  // as the user gave it
  std::vector<std::filesystem::path> inputs;  // files or folders read (empty entries ignored)
  bool force = false;                         // replace any existing folder (not an input)
  // Files whose presence marks an existing folder as a previous output of this command written
  // before the marker file existed (e.g. {"report.json", "height.exr"} for reconstruct).
  std::vector<std::string> legacy_signature;
};

// Validates `spec` (throws Error kUsage, exit 2, naming --out and the input) and cleans stale
// temporaries of earlier runs. Returns the absolute, normalised output path. Called by
// WriteOutputFolder; call it yourself before long work so a bad --out fails in milliseconds.
std::filesystem::path CheckOutputFolder(const OutputSpec& spec);

// CheckOutputFolder, then fill(tmp) writes into a fresh temporary sibling folder, which is
// swapped into place atomically. On an exception the temporary is removed and the existing
// output (if any) is left untouched.
void WriteOutputFolder(const OutputSpec& spec,
                       const std::function<void(const std::filesystem::path& tmp)>& fill);

// The temporary-folder-and-swap of WriteOutputFolder without the checks (core/fs.h's
// WriteFolderAtomically uses it); marker_command may be empty (no marker written).
void ReplaceFolderAtomically(const std::filesystem::path& final_dir,
                             const std::string& marker_command,
                             const std::function<void(const std::filesystem::path& tmp)>& fill);

// The same rules for a single output file (brdf plot/tabulate): --out must not be an input,
// nor an existing folder; an existing file is replaced only if accept_existing(path) says it
// is a previous output (or force). The write itself goes through core/fs.h's checked writer.
std::filesystem::path CheckOutputFile(
    const OutputSpec& spec,
    const std::function<bool(const std::filesystem::path&)>& accept_existing);

// Removes stale `.NAME.mesoscan-tmp.PID*` / `.NAME.mesoscan-old.PID*` siblings of `final_path`
// whose process is gone (nested ones `..NAME.mesoscan-tmp.P.0.mesoscan-tmp.P.1` too); a stale
// backup whose final name is missing is renamed back.
void CleanStaleOutputs(const std::filesystem::path& final_path);

// For readers: if `path` is missing because a replacement without RENAME_EXCHANGE was killed
// between its two renames (the old output then lies under its backup name), the backup is
// renamed back. Nothing else is touched.
void RestoreInterruptedReplacement(const std::filesystem::path& path);

// True if `inner` equals `outer` or lies below it (both absolute and canonical).
bool PathIsWithin(const std::filesystem::path& inner, const std::filesystem::path& outer);

}  // namespace mesoscan
