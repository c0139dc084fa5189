#pragma once
// libpng's default error handler prints "libpng error: ..." to stderr before OpenImageIO turns
// the failure into an error that mesoscan reports in its own one line. The
// CLI replaces the C `stderr` stream with one that drops such lines and passes everything else
// through unchanged and unbuffered.

namespace mesoscan {

// Installs the filter once per process (no-op on a second call).
void FilterLibraryNoiseOnStderr();

}  // namespace mesoscan
