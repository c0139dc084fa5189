#include "heightfield/stage_plan.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "core/error.h"
#include "core/log.h"

namespace mesoscan {

std::vector<double> ReconstructPlan::PeriodList() const {
  std::vector<double> v;
  for (const auto& p : periods) v.push_back(p.period);
  return v;
}

int ReconstructPlan::PhaseShiftFrames() const {
  int n = 0;
  for (const auto& p : periods) n += static_cast<int>(p.stack_frames.size());
  return n;
}

double ReconstructPlan::LensShiftCentre() const {
  if (ls_shift_px.empty()) return 0.0;
  return std::accumulate(ls_shift_px.begin(), ls_shift_px.end(), 0.0) / ls_shift_px.size();
}

namespace {

// The axis whose sines (and stripes) decode the projector coordinate: the lens shifter's axis
// when the rig has one and a sine set (>= 3 phases at shift 0) exists along it, else x when one
// exists along x, else y. A session with sets along both axes (calibration style) reconstructs
// from that one axis; the other set is ignored.
char DecodeAxis(const Session& session, const FramePlan& fp) {
  auto usable = [&](char axis) {
    for (const auto& set : fp.sine) {
      if (set.axis != axis) continue;
      int at_zero = 0;
      for (size_t f : set.frames) at_zero += session.frames[f].shift_steps == 0;
      if (at_zero >= 3) return true;
    }
    for (const Frame& f : session.frames)  // a planned codec's patterns
      if (f.pattern.IsCoded() && f.pattern.axis == axis && f.shift_steps == 0) return true;
    return false;
  };
  if (session.rig.lens_shifter && usable(session.rig.lens_shifter->axis))
    return session.rig.lens_shifter->axis;
  if (usable('x')) return 'x';
  if (usable('y')) return 'y';
  return session.rig.lens_shifter ? session.rig.lens_shifter->axis : 'x';
}

}  // namespace

ReconstructPlan MakeReconstructPlan(const Session& session, const PlanOptions& options) {
  const Rig& rig = session.rig;
  const FramePlan fp = MakeFramePlan(session.frames);
  ReconstructPlan plan;
  plan.label = session.root.string();
  plan.axis = DecodeAxis(session, fp);
  for (const auto& set : fp.sine) {
    if (set.axis != plan.axis) {
      MESOSCAN_LOG(kInfo) << "reconstruct: ignoring " << set.frames.size()
                          << " sine frames along the projector's " << set.axis
                          << " axis (decoding axis " << plan.axis << ")";
      continue;
    }
    PhasePeriod p;
    p.period = set.period_px;
    for (size_t f : set.frames) {
      if (session.frames[f].shift_steps != 0) continue;  // the calibrated model holds at 0
      p.stack_frames.push_back(static_cast<int>(plan.frames.size()));
      p.deltas.push_back(session.frames[f].pattern.phase);
      plan.frames.push_back(static_cast<int>(f));
    }
    if (p.stack_frames.size() >= 3) plan.periods.push_back(std::move(p));
  }
  const std::vector<double> period_list = plan.PeriodList();
  plan.projector_width = plan.axis == 'x' ? rig.projector.width : rig.projector.height;
  plan.projector_gamma =
      rig.projector_response.kind == Response::Kind::kGamma ? rig.projector_response.gamma : 1.0;
  if (!period_list.empty()) {
    const double longest = *std::max_element(period_list.begin(), period_list.end());
    plan.unwrapping = period_list.size() == 1           ? "single"
                      : longest >= plan.projector_width ? "hierarchical"
                                                        : "temporal";
  }

  // Lens-shift frames (stripes, period 2, along the decoded axis), sorted by shift.
  std::vector<std::pair<int, size_t>> by_shift;
  if (options.use_lens_shift && rig.lens_shifter) {
    for (size_t f : fp.lens_shift) {
      const Pattern& pat = session.frames[f].pattern;
      if (pat.axis != plan.axis || std::abs(pat.period_px - 2.0) > 1e-9) continue;
      by_shift.emplace_back(session.frames[f].shift_steps, f);
    }
    std::sort(by_shift.begin(), by_shift.end());
  }
  if (by_shift.size() >= 4) {
    for (const auto& [steps, f] : by_shift) {
      plan.ls_stack.push_back(static_cast<int>(plan.frames.size()));
      plan.ls_shift_px.push_back(steps / rig.lens_shifter->steps_per_px);
      plan.frames.push_back(static_cast<int>(f));
    }
  }
  if (!fp.white.empty()) {
    plan.white = static_cast<int>(plan.frames.size());
    plan.frames.push_back(static_cast<int>(fp.white.front()));
  }
  if (!fp.black.empty()) {
    plan.black = static_cast<int>(plan.frames.size());
    plan.frames.push_back(static_cast<int>(fp.black.front()));
  }
  // The planned codecs (Gray code, ...): one of them gives the absolute coordinate where the
  // periods do not.
  plan.codecs = PlanCodecs(session, options.codecs, &plan);
  PlannedCodec* absolute = nullptr;
  for (const auto& c : plan.codecs)
    if (c->Kind() == CodecKind::kAbsolute) absolute = absolute ? absolute : c.get();
  const ErrorSite frames_key = ErrorSite::Key(session.root / "session.json", "frames");
  // The periods unwrap on their own unless a planned absolute codec is there for periods that
  // repeat across the projector (without one, the unwrapper names the problem).
  plan.periods_unwrap =
      !plan.periods.empty() &&
      (!absolute || UnambiguousRangePx(period_list, plan.projector_width) >= plan.projector_width);
  if (plan.periods.empty() && !absolute)
    MESOSCAN_BAD_INPUT_AT(frames_key, "no sine pattern along "
                                          << plan.axis
                                          << " with >= 3 phases at shift_steps 0 and no Gray code "
                                             "along it; nothing gives the absolute projector "
                                          << (plan.axis == 'x' ? "column" : "row"));
  if (!plan.periods_unwrap) {
    if (plan.periods.size() > 1)
      MESOSCAN_BAD_INPUT_AT(frames_key,
                            plan.periods.size()
                                << " sine periods along " << plan.axis
                                << " that repeat across the projector, expected one period whose "
                                   "order the Gray code fixes");
    plan.unwrapping = absolute->Name();
    if (!plan.periods.empty()) absolute->OrdersPeriod();
  }
  if (!plan.has_white() && plan.periods.empty())
    MESOSCAN_BAD_INPUT_AT(frames_key,
                          "no white frame and no sine set: expected one of them for the "
                          "white level that the "
                              << (absolute ? absolute->Name() : "") << " frames are read against");
  return plan;
}

}  // namespace mesoscan
