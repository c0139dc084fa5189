#pragma once
// The Gray-code codec (heightfield/codec.h; docs/formats.md "Patterns", graycode): B frames along
// the plan's axis, bit k (k = 0 the most significant) of the reflected binary Gray code of the
// block index floor(u / W). Each bit is read against its inverse frame where there is one (the
// pixel's own threshold: robust to albedo and defocus), else against the middle of the white and
// black frames, else against the mean of a sine set (half the phase-shift level). A bit whose two
// levels are too close for the pixel's noise (estimated from the frames themselves) is unknown,
// never guessed: any unknown bit leaves the pixel without a coordinate, except that a code which
// orders a sine period (OrderedCodec) keeps a pixel with one unknown bit whose two readings are
// neighbouring blocks at their common edge (the period's phase then decides the order, read away
// from the code's edges). A block beyond the projector is no coordinate either. An absolute
// codec: the block's centre (its columns' mean), sigma W / sqrt(12); its confidence the weakest
// bit's signal-to-noise (GrayCodeOptions), halved on an edge. With W = P or P / 2 and a sine set
// of period P along the axis, the Gray code fixes the sine's fringe order.

#include <memory>
#include <vector>

#include "heightfield/codec.h"
#include "session/session.h"

namespace mesoscan {

struct ReconstructPlan;

struct GrayCodeOptions {
  // A bit is read where its two levels (the frame and its inverse, or twice the frame's distance
  // from the threshold) differ by at least min_bit_snr times their noise (estimated per pixel
  // from the frames) and by at least min_bit_contrast of the pixel's white level; else it is
  // unknown. The confidence is the weakest read bit's signal-to-noise over full_bit_snr, capped
  // at 1.
  double min_bit_snr = 4.0;
  double full_bit_snr = 8.0;
  double min_bit_contrast = 0.02;
  // A pixel with one unknown bit whose two readings are neighbouring blocks sees their common
  // edge: true gives it the edge's coordinate (between the blocks, neither block guessed) at half
  // the confidence; false leaves it without a coordinate unless the code orders a sine period.
  bool edge_points = true;
  // Floor of the per-sample noise estimate, fraction of the white level.
  double min_noise = 1e-3;
  void Check() const;
};

// The planner (heightfield/codecs.h): the Gray-code frames along plan->axis (one set: the one with
// the most bits), nullptr if there are none.
std::shared_ptr<PlannedCodec> PlanGrayCode(const Session& session, const GrayCodeOptions& options,
                                           ReconstructPlan* plan);

}  // namespace mesoscan
