#include "calibration/calibrate_codecs.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <utility>

#include "core/error.h"
#include "core/parallel.h"
#include "heightfield/codec.h"
#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_classify.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

// One projector axis: its frames as a session of their own (the reconstruction plans one axis),
// the plan and the loaded frames.
struct CodedBoardFrames::Axis {
  char axis = 'x';
  Session session;            // the frames along `axis`, white and black
  std::vector<int> original;  // per frame of `session`: its index in the board session
  ReconstructPlan plan;
  FrameStack stack;
  std::string codec;
};

bool HasCodedFrames(const Session& session) {
  for (const Frame& f : session.frames)
    if (f.pattern.IsCoded() && f.shift_steps == 0) return true;
  return false;
}

namespace {

// The Gray-code sets along `axis` at shift 0: (bits, block_px) -> board session frame indices.
std::map<std::pair<int, double>, std::vector<int>> GrayCodeSets(const Session& session, char axis) {
  std::map<std::pair<int, double>, std::vector<int>> sets;
  for (size_t f = 0; f < session.frames.size(); ++f) {
    const Frame& frame = session.frames[f];
    if (frame.pattern.type == PatternType::kGrayCode && frame.pattern.axis == axis &&
        frame.shift_steps == 0)
      sets[{frame.pattern.bits, frame.pattern.block_px}].push_back(static_cast<int>(f));
  }
  return sets;
}

// The checks calibration adds to planning's (heightfield/codec_graycode.h): one Gray code per
// axis; alone (no sine set to read it against), every bit with its inverse.
void CheckGrayCode(const Session& session, char axis, bool with_sines) {
  const std::filesystem::path json = session.root / "session.json";
  const auto sets = GrayCodeSets(session, axis);
  if (sets.size() > 1) {
    std::ostringstream kinds;
    for (const auto& [key, frames] : sets)
      kinds << (kinds.tellp() > 0 ? ", " : "") << key.first << " bits of " << key.second << " px";
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(json, "frames"),
                          "Gray codes of " << sets.size() << " kinds along " << axis << " ("
                                           << kinds.str()
                                           << "), expected one code per projector axis");
  }
  if (sets.empty() || with_sines) return;
  const auto& [key, frames] = *sets.begin();
  std::vector<int> plain(key.first, -1), inverse(key.first, -1);
  for (int f : frames) {
    const Pattern& p = session.frames[f].pattern;
    if (p.bit < 0 || p.bit >= key.first) continue;  // the reader refuses these
    (p.inverted ? inverse : plain)[p.bit] = f;
  }
  for (int k = 0; k < key.first; ++k) {
    if (plain[k] >= 0 && inverse[k] >= 0) continue;
    const int have = std::max(plain[k], inverse[k]);
    if (have < 0) continue;  // a missing bit: planning names it
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::Key(json, "frames[" + std::to_string(have) + "]"),
        session.frames[have].file
            << ": bit " << k << " of the Gray code along " << axis << " has no "
            << (plain[k] < 0 ? "plain" : "inverted")
            << " frame; calibration reads each bit against its inverse (expected both frames of "
               "every bit, as OpenCV's GrayCodePattern writes them)");
  }
}

}  // namespace

CodedBoardFrames::CodedBoardFrames(const Session& session)
    : width_(session.rig.camera.width), height_(session.rig.camera.height) {
  const std::filesystem::path json = session.root / "session.json";
  for (int a = 0; a < 2; ++a) {
    auto ax = std::make_unique<Axis>();
    ax->axis = a ? 'y' : 'x';
    ax->session = session;
    ax->session.frames.clear();
    bool sines = false, coded = false;
    for (size_t f = 0; f < session.frames.size(); ++f) {
      const Frame& frame = session.frames[f];
      const Pattern& p = frame.pattern;
      const bool along = (p.type == PatternType::kSine || p.IsCoded()) && p.axis == ax->axis &&
                         frame.shift_steps == 0;
      if (!along && p.type != PatternType::kWhite && p.type != PatternType::kBlack) continue;
      sines = sines || (along && p.type == PatternType::kSine);
      coded = coded || (along && p.IsCoded());
      ax->session.frames.push_back(frame);
      ax->original.push_back(static_cast<int>(f));
    }
    CheckGrayCode(session, ax->axis, sines);
    if (!coded)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(json, "frames"),
                            "a Gray code along "
                                << (a ? 'x' : 'y') << " but none along " << ax->axis
                                << ": calibration expects the same codec along both projector "
                                   "axes (a Gray code alone, or one sine period with a Gray code)");
    PlanOptions po;
    po.use_lens_shift = false;
    // A pixel with one unknown bit is the edge between two neighbouring blocks only if the bit is
    // unknown because the pixel straddles it; blur makes a whole stripe of the finest bit unknown,
    // so calibration takes no edge coordinates (a sine period, where there is one, still decides
    // the order there: OrderedCodec).
    po.codecs.graycode.edge_points = false;
    ax->plan = MakeReconstructPlan(ax->session, po);
    MESOSCAN_CHECK(ax->plan.axis == ax->axis && !ax->plan.codecs.empty());
    ax->codec = ax->plan.periods.empty()  ? "graycode"
                : ax->plan.periods_unwrap ? "sine"
                                          : "sine+graycode";
    if (a == 1 && ax->codec != axis_[0]->codec)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(json, "frames"),
                            "the projector's x axis is coded by "
                                << axis_[0]->codec << " and its y axis by " << ax->codec
                                << ": calibration expects the same codec along both axes");
    try {
      ax->stack = LoadFrames(ax->session, ax->plan.frames, FrameLoadOptions());
    } catch (const Error& e) {
      if (e.frame() < 0 || e.frame() >= static_cast<int>(ax->original.size())) throw;
      ErrorSite site = e.site();
      site.frame = ax->original[e.frame()];
      throw e.At(site);
    }
    axis_[a] = std::move(ax);
  }
}

CodedBoardFrames::~CodedBoardFrames() = default;

int CodedBoardFrames::eight_bit_frames() const {
  return axis_[0]->stack.eight_bit_frames() + axis_[1]->stack.eight_bit_frames();
}

const std::string& CodedBoardFrames::codec() const { return axis_[0]->codec; }

std::vector<float> CodedBoardFrames::Texture() const {
  const Axis& ax = *axis_[0];
  const size_t np = static_cast<size_t>(width_) * height_;
  std::vector<float> t(np, 0.0f);
  std::vector<int> frames;
  if (ax.plan.has_white())
    frames.push_back(ax.plan.white);
  else if (!ax.plan.periods.empty())
    frames = ax.plan.periods[0].stack_frames;
  if (frames.empty()) return t;  // planning refuses a session without either
  ParallelForRows(height_, [&](int y0, int y1) {
    for (size_t i = static_cast<size_t>(y0) * width_; i < static_cast<size_t>(y1) * width_; ++i) {
      float s = 0;
      for (int k : frames) s += ax.stack.Value(k, i);
      t[i] = s / frames.size();
    }
  });
  return t;
}

void CodedBoardFrames::Decode(const std::vector<uint32_t>& pixels, double min_confidence,
                              std::vector<float>* u, std::vector<float>* v) const {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  u->assign(pixels.size(), kNaN);
  v->assign(pixels.size(), kNaN);
  const size_t np = static_cast<size_t>(width_) * height_;
  std::vector<uint8_t> wanted(np, 0);
  for (uint32_t i : pixels) wanted[i] = 1;
  for (int a = 0; a < 2; ++a) {
    const Axis& ax = *axis_[a];
    const ReconstructPlan& plan = ax.plan;
    // The reconstruction's stages on the requested pixels only.
    PixelClasses classes = ClassifyPixels(ax.stack, plan, width_, height_, ClassifyOptions());
    for (size_t i = 0; i < np; ++i) {
      if (!wanted[i]) {
        classes.state[i] = PixelState::kOutside;
      } else if (classes.state[i] == PixelState::kSaturated && plan.periods.empty() &&
                 plan.has_white()) {
        // A binary code read against its inverses survives clipping: the pixel is read, its
        // white level from the (clipped) white frame.
        const float black = plan.black >= 0 ? ax.stack.Value(plan.black, i) : 0.0f;
        classes.white_level[i] = ax.stack.Value(plan.white, i) - black;
        classes.black_value[i] = black;
        classes.state[i] =
            classes.white_level[i] >= classes.min_lit ? PixelState::kActive : PixelState::kUnlit;
      }
    }
    const PhaseShiftPixels ps =
        DecodePhaseShift(ax.stack, plan, UnitGains(plan, ax.session.frames.size()), classes,
                         PhaseShiftStageOptions(), &classes.state);
    for (const auto& codec : plan.codecs)
      codec->DecodeFrames({&ax.stack, &classes, &ps}, classes.state);
    // The absolute codec as the combine stage takes it (heightfield/stage_combine.cc
    // CombinePhases): the sine periods where they unwrap, else the planned absolute codec,
    // ordering the one sine period if there is one.
    std::optional<PhaseShiftCodec> sine;
    if (!plan.periods.empty()) sine.emplace(plan, ps, PhaseShiftStageOptions());
    const Codec* absolute = sine && sine->Kind() == CodecKind::kAbsolute ? &*sine : nullptr;
    for (const auto& c : plan.codecs)
      if (!absolute && c->Kind() == CodecKind::kAbsolute) absolute = c.get();
    if (!absolute) continue;  // planning refuses such a plan
    std::optional<OrderedCodec> ordered;
    if (sine && sine->Kind() == CodecKind::kPeriodic) absolute = &ordered.emplace(*absolute, *sine);
    std::vector<float>& out = a ? *v : *u;
    constexpr size_t kBlock = 4096;
    const int64_t blocks = static_cast<int64_t>((pixels.size() + kBlock - 1) / kBlock);
    ParallelFor(blocks, [&](int64_t b) {
      const size_t begin = static_cast<size_t>(b) * kBlock,
                   end = std::min(pixels.size(), begin + kBlock);
      std::vector<size_t> active, slot;
      for (size_t n = begin; n < end; ++n)
        if (classes.state[pixels[n]] == PixelState::kActive) {
          active.push_back(pixels[n]);
          slot.push_back(n);
        }
      const size_t m = active.size();
      if (m == 0) return;
      // Per-sample noise as the combine stage takes it: the codec's own fits, a floor of 1e-4
      // of the white level.
      std::vector<double> noise(m, -1.0);
      absolute->SampleNoise(active.data(), m, noise.data());
      for (size_t k = 0; k < m; ++k) noise[k] = std::max(noise[k], 1e-4 * ps.level[active[k]]);
      CodecRecord rec;
      absolute->Decode(active.data(), m, noise.data(), &rec);
      std::vector<uint32_t> which;
      for (size_t k = 0; k < m; ++k)
        if (rec.valid[k]) which.push_back(static_cast<uint32_t>(k));
      absolute->Describe(active.data(), noise.data(), which.data(), which.size(), false, &rec);
      for (uint32_t k : which) {
        const double c = rec.confidence[k] * rec.consistency[k];
        if (c >= min_confidence && std::isfinite(rec.value[k]))
          out[slot[k]] = static_cast<float>(rec.value[k]);
      }
    });
  }
}

}  // namespace mesoscan
