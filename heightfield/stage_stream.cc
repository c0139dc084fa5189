#include "heightfield/stage_stream.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <chrono>
#include <mutex>
#include <utility>
#include <vector>

namespace mesoscan {
namespace {

// Gathers frames' samples (GatheredSamples) at pixels that are chosen while the frames decode.
// A frame decoded after SetPixels is gathered by its decoding task (OnDecoded: its samples are
// in place while that task runs); the frames decoded before are gathered by Finish, from the
// stack once it is complete (not by SetPixels: if another frame's decode fails meanwhile, the
// loader's frames are freed under it).
class LateGatherer {
 public:
  LateGatherer(GatheredSamples* out, size_t frames) : out_(out) { out->codes.resize(frames); }
  void OnDecoded(int k, const uint16_t* samples) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!ready_) {
        pending_.push_back(k);
        return;
      }
    }
    out_->Gather(k, samples);
  }
  void SetPixels(std::vector<uint32_t> pixels) {
    out_->pixels = std::move(pixels);
    std::lock_guard<std::mutex> lock(mutex_);
    ready_ = true;
  }
  // The frames decoded before SetPixels, from `stack` (integer frames; nothing if SetPixels
  // was not called).
  void Finish(const FrameStack& stack) {
    if (!ready_ || stack.is_float()) return;
    tbb::parallel_for<int64_t>(0, static_cast<int64_t>(pending_.size()), [&](int64_t q) {
      out_->Gather(pending_[q], stack.Samples16(pending_[q]));
    });
    pending_.clear();
  }

 private:
  GatheredSamples* out_;
  std::mutex mutex_;
  bool ready_ = false;
  std::vector<int> pending_;
};

int64_t CountActive(const PixelStates& state) {
  int64_t n = 0;
  for (const PixelState s : state) n += s == PixelState::kActive;
  return n;
}

}  // namespace

StreamedFrames DecodeAndPhaseShift(const Session& session, const ReconstructPlan& plan,
                                   const StreamStageOptions& options) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto since = [&] { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  const Rig& rig = session.rig;
  std::vector<uint8_t> is_ls(plan.frames.size(), 0), not_ls(plan.frames.size(), 1);
  for (int k : plan.ls_stack) is_ls[k] = 1, not_ls[k] = 0;
  const bool overlap = plan.use_lens_shift() && plan.ls_stack.size() < plan.frames.size();
  StreamedFrames out;
  out.gains = UnitGains(plan, session.frames.size());
  FrameStack ls_frames;
  PixelStates classified;  // the classify stage's states: the gains' pixel sample
  PhaseReference early_reference;
  size_t newly_saturated = 0;  // pixels saturated in a lens-shift frame only
  // The lens-shift frames' samples that the gains (~20000 pixels) and the frame corrections'
  // phase reference (~12000) read, gathered as each frame decodes (~15 ms of scattered reads off
  // the time after the last frame); the sine branch picks both sets of pixels. Used if no pixel
  // turns out saturated in a lens-shift frame only (the pixels are then the same).
  GatheredSamples gain_samples, reference_samples;
  LateGatherer gain_gatherer(&gain_samples, plan.frames.size()),
      reference_gatherer(&reference_samples, plan.frames.size());
  FrameLoadOptions ls_load = options.load;
  if (overlap)
    ls_load.on_decoded = [&](int k, const uint16_t* samples) {
      gain_gatherer.OnDecoded(k, samples);
      reference_gatherer.OnDecoded(k, samples);
    };
  double decoded_s = 0.0, ls_decoded_s = 0.0;
  auto sine_frames = [&] {
    out.stack = LoadFrames(session, plan.frames, options.load, overlap ? &not_ls : nullptr);
    decoded_s = since();
    out.classes =
        ClassifyPixels(out.stack, plan, rig.camera.width, rig.camera.height, options.classify);
    classified = out.classes.state;
    if (overlap && options.gains.normalize_luminance)
      gain_gatherer.SetPixels(GainSample(classified));
    EstimateLuminanceGains(out.stack, plan, classified, GainGroup::kPhaseShift, options.gains,
                           &out.gains);
    out.ps = DecodePhaseShift(out.stack, plan, out.gains, out.classes, options.phase_shift,
                              &out.classes.state);
    // The planned codecs (Gray code, ...) while their frames are in memory.
    for (const auto& codec : plan.codecs)
      codec->DecodeFrames({&out.stack, &out.classes, &out.ps}, out.classes.state);
    // The lens-shift frames' phase reference (phase shifting alone) while they still decode; it
    // is kept below if no pixel turns out saturated in a lens-shift frame only (the pixels it
    // samples are then the same: ps.level is the white level at every classified-kActive pixel).
    if (overlap) {
      early_reference = MakePhaseReference(plan, out.ps, classified);
      reference_gatherer.SetPixels(early_reference.pixels);
    }
    // The fringe orders too (the combine stage's search, ~0.25 CPU-s at full resolution, off
    // the time after the last frame); the lens-shift noise sets their weights there.
    if (overlap && plan.periods_unwrap)
      out.ps.u_unwrapped = UnwrapPhaseShift(plan, out.ps, out.classes.state, options.phase_shift);
    if (overlap)  // only the lens-shift frames are read from here on
      for (int k = 0; k < out.stack.num_frames(); ++k)
        if (!is_ls[k]) out.stack.Release(k);
  };
  if (overlap) {
    tbb::parallel_invoke(
        [&] {
          ls_frames = LoadFrames(session, plan.frames, ls_load, &is_ls);
          ls_decoded_s = since();
        },
        sine_frames);
  } else {
    sine_frames();
  }
  out.decode_s = std::max(decoded_s, ls_decoded_s);
  out.phase_shift_s = since();
  if (overlap) {
    out.stack.Merge(std::move(ls_frames));
    // Classify's verdict on the lens-shift frames' saturation, then what is still lit.
    newly_saturated =
        static_cast<size_t>(ClassifyLateSaturation(out.stack, &classified, &out.classes));
    if (newly_saturated > 0) out.ps.pixels_lit = CountActive(out.classes.state);
  }
  if (plan.has_white()) {  // the same values where read (kActive pixels): one array, not two
    out.ps.level = std::move(out.classes.white_level);
    out.classes.white_level = {};
  }
  // The lens-shift frames' gains after the last frame; their phase reference too unless the
  // early one holds (~45 ms serial, at full resolution, off the time after the last frame).
  const bool early = overlap && newly_saturated == 0;
  if (early) {
    gain_gatherer.Finish(out.stack);
    reference_gatherer.Finish(out.stack);
  }
  EstimateLuminanceGains(out.stack, plan, classified, GainGroup::kLensShift, options.gains,
                         &out.gains, early ? nullptr : &out.ps, early ? &gain_samples : nullptr);
  if (early) {
    out.gains.phase_reference = std::move(early_reference);
    out.gains.phase_reference.samples = std::move(reference_samples);
  }
  return out;
}

}  // namespace mesoscan
