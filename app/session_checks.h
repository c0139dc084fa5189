#pragma once
// What `reconstruct` would refuse, for `check` too, and errors of the pipeline that carry no
// location given the session's session.json.

#include "core/scan_folder.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"

namespace mesoscan {

// Reconstruct(session, options), with a bad-input error that carries no location located at
// "<session>/session.json" (the refusals of the decoders are about its periods and phases),
// and an empty result (no pixel decoded: identical, unlit or all-NaN frames) refused naming
// the session instead of written as an empty scan.
Scan ReconstructOrExplain(const Session& session, const ReconstructOptions& options,
                          ReconstructSummary* summary);

// The full check of `mesoscan check SESSION` (without --quick): decodes every frame whole
// (a truncated file fails here, not in the header check) and runs the reconstruction's own
// validation on a small window at the image centre, discarding the result.
void CheckSessionLikeReconstruct(const Session& session);

// A scan folder's height field as render/export need it: at least 2x2 and some finite sample.
void CheckScanUsable(const Scan& scan, const std::filesystem::path& dir);

}  // namespace mesoscan
