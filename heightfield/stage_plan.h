#pragma once
// Reconstruction stage 0, plan: which session frames are decoded and what each encodes. Only
// axis-x sine frames at shift 0 decode the coarse projector column (the calibrated model holds at
// shift 0); lens-shift frames are the period-2 axis-x stripes, sorted by shift; plus the first
// white and black frame. The stack order is the order of `frames` (heightfield/frames.h).

#include <string>
#include <vector>

#include "capture/session.h"

namespace mesoscan {

struct PlanOptions {
  // false: ignore lens-shift frames (phase shifting alone).
  bool use_lens_shift = true;
};

// One period of the phase-shift patterns (axis x, shift 0), >= 3 phases.
struct PhasePeriod {
  double period = 0;              // projector px
  std::vector<int> stack_frames;  // indices into the FrameStack
  std::vector<double> deltas;     // phase offsets, radians
};

struct ReconstructPlan {
  std::vector<int> frames;           // session frame index of each stack frame
  std::vector<PhasePeriod> periods;  // at least one
  std::vector<int> ls_stack;         // lens-shift stack frames, by increasing shift; empty: none
  std::vector<double> ls_shift_px;   // their shifts, projector px
  int white = -1, black = -1;        // stack frames; -1: none
  std::string unwrapping;            // "temporal", "hierarchical" or "single"
  double projector_width = 0;        // the unwrapping range, px
  std::string label;                 // the session (for messages)

  bool use_lens_shift() const { return !ls_stack.empty(); }
  bool has_white() const { return white >= 0; }
  std::vector<double> PeriodList() const;
  int PhaseShiftFrames() const;
  // Mean of ls_shift_px (the lens-shift fit references positions to it).
  double LensShiftCentre() const;
};

// Throws Error (bad input) if no axis-x sine set with >= 3 phases at shift 0 exists. Lens shift
// is used with >= 4 stripe frames and a lens shifter in the rig.
ReconstructPlan MakeReconstructPlan(const Session& session, const PlanOptions& options);

}  // namespace mesoscan
