#pragma once
// Reconstruction stage 0, plan: which session frames are decoded and what each encodes. One axis
// is decoded (`axis`: the lens shifter's, else x, else y; see MakeReconstructPlan): its sine
// frames at shift 0 decode the coarse projector coordinate (column for x, row for y; the
// calibrated model holds at shift 0); lens-shift frames are the period-2 stripes along it, sorted
// by shift; plus the first white and black frame. The stack order is the order of `frames`
// (heightfield/frames.h). Below, "column" and "width" mean row and height for axis y.

#include <string>
#include <vector>

#include "heightfield/codecs.h"
#include "session/session.h"

namespace mesoscan {

struct PlanOptions {
  // false: ignore lens-shift frames (phase shifting alone).
  bool use_lens_shift = true;
  // The planned codecs' options (heightfield/codecs.h).
  CodecOptions codecs;
};

// One period of the phase-shift patterns (along the plan's axis, shift 0), >= 3 phases.
struct PhasePeriod {
  double period = 0;              // projector px
  std::vector<int> stack_frames;  // indices into the FrameStack
  std::vector<double> deltas;     // phase offsets, radians
};

struct ReconstructPlan {
  std::vector<int> frames;           // session frame index of each stack frame
  std::vector<PhasePeriod> periods;  // may be empty (a planned codec alone)
  // The periods give the absolute coordinate on their own (their phases are unique over the
  // projector); false: one period whose order a planned absolute codec fixes (OrderedCodec).
  bool periods_unwrap = true;
  // The planned codecs (heightfield/codecs.h), their frames in `frames`; decoded by the stream.
  std::vector<std::shared_ptr<PlannedCodec>> codecs;
  std::vector<int> ls_stack;        // lens-shift stack frames, by increasing shift; empty: none
  std::vector<double> ls_shift_px;  // their shifts, projector px
  int white = -1, black = -1;       // stack frames; -1: none
  // "temporal", "hierarchical" or "single" (the periods unwrap), else the name of the planned
  // codec that gives the absolute coordinate ("graycode").
  std::string unwrapping;
  double projector_width = 0;  // the unwrapping range, px
  std::string label;           // the session (for messages)
  char axis = 'x';             // decoded projector axis: 'x' (columns) or 'y' (rows)
  // The rig's projector response as the sine decoders undo it: v^projector_gamma is the light of
  // a displayed value v (1: linear).
  double projector_gamma = 1.0;

  bool use_lens_shift() const { return !ls_stack.empty(); }
  bool has_white() const { return white >= 0; }
  std::vector<double> PeriodList() const;
  int PhaseShiftFrames() const;
  // Mean of ls_shift_px (the lens-shift fit references positions to it).
  double LensShiftCentre() const;
};

// The decoded axis: the lens shifter's when the rig has one and >= 3 sine phases at shift 0 (or a
// planned codec's frames) lie along it, else x if they do along x, else y (a session with sets
// along both axes, calibration style, reconstructs from that axis alone). Throws Error (bad
// input) if nothing along it gives the absolute coordinate: neither a sine set with >= 3 phases
// at shift 0 whose periods unwrap, nor a planned absolute codec (which then orders one period).
// Lens shift is used with >= 4 stripe frames along the axis and a lens shifter in the rig.
ReconstructPlan MakeReconstructPlan(const Session& session, const PlanOptions& options);

}  // namespace mesoscan
