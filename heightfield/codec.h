#pragma once
// The codec seam. A codec decodes the projector coordinate along the plan's axis from the frames
// of one pattern family (heightfield/stage_plan.h lists the frames each codec reads). Its
// per-pixel record is the only thing the combine stage (heightfield/stage_combine.h) reads of
// it: an absolute codec (phase shifting whose periods unwrap, ...) gives the coordinate itself;
// a periodic codec (the lens-shift stripes, paper Eq. 2) gives a phase that repeats every
// PeriodPx() and refines the absolute coordinate, which fixes its order. Each record field comes
// with its predicted sigma, the codec's own confidence and a validity flag; the triangulation
// reads only what the combination made of them (heightfield/pixel_buffers.h CombinedPixels).
//
// The combine stage asks for blocks of a few thousand pixels: one virtual call per codec and
// block, planar buffers inside, no virtual call per pixel.

#include <cstddef>
#include <cstdint>
#include <vector>

#include "heightfield/pixel_buffers.h"

namespace mesoscan {

enum class CodecKind {
  kAbsolute,  // the projector coordinate over the whole projector, px
  kPeriodic,  // the coordinate modulo PeriodPx(): a phase, whose order an absolute codec fixes
};

// A block of a codec's per-pixel record: entry a belongs to the a-th pixel of the block the
// combine stage asked for. Sized by the codec; reused from block to block.
struct CodecRecord {
  // kAbsolute: the projector coordinate, px. kPeriodic: the phase in cycles of the period, in
  // [0, 1): the coordinate is PeriodPx() (order + value) with the order from an absolute codec.
  std::vector<double> value;
  std::vector<uint8_t> valid;  // 1 where value holds
  // kAbsolute: the consistency of the codec's own parts (the periods' unwrapping residual, sigma
  // units; 0 where there is a single part) and the factor in [0, 1] it puts on the confidence.
  std::vector<double> residual;
  std::vector<double> consistency;
  // Predicted sigma of the coordinate (px) and the codec's own confidence in [0, 1] (paper Eq. 4
  // for the lens shift); Describe() fills them for the entries asked.
  std::vector<double> sigma_px;
  std::vector<double> confidence;
  void Resize(size_t n) {
    value.resize(n);
    valid.resize(n);
    residual.resize(n);
    consistency.resize(n);
    sigma_px.resize(n);
    confidence.resize(n);
  }
};

class Codec {
 public:
  virtual ~Codec() = default;
  virtual const char* Name() const = 0;
  virtual CodecKind Kind() const = 0;
  // kPeriodic: the period of the phase, projector px.
  virtual double PeriodPx() const { return 0.0; }
  // The stack frames (heightfield/frames.h FrameStack) the codec reads.
  virtual std::vector<int> Frames() const = 0;
  // The per-sample noise (linear frame units) of pixels[0..n) that the codec's own fits
  // estimate, into sigma[a]; entries it has no estimate for are left as they are.
  virtual void SampleNoise(const size_t* pixels, size_t n, double* sigma) const = 0;
  // value and valid (kAbsolute: residual and consistency too) of pixels[0..n), whose per-sample
  // noise is noise[a]. out is resized to n.
  virtual void Decode(const size_t* pixels, size_t n, const double* noise,
                      CodecRecord* out) const = 0;
  // sigma_px and confidence of the entries which[0..m) of the block Decode() filled (other
  // entries are left as they are). `refined`: a periodic codec refines this absolute one where
  // it holds (its model errors then count in the sigma, as in the unwrapping's weights).
  virtual void Describe(const size_t* pixels, const double* noise, const uint32_t* which, size_t m,
                        bool refined, CodecRecord* out) const = 0;
  // kPeriodic: the phase is known up to a constant common to every pixel (the lens shifter's
  // positions estimated up to an offset): the combination references it to the absolute codec.
  virtual bool OffsetUnknown() const { return false; }
};

// What a planned codec's decoding reads besides its own frames.
struct CodecInputs {
  const FrameStack* stack = nullptr;      // holds the codec's frames (linear radiance)
  const PixelClasses* classes = nullptr;  // white level and black value (white/black frames)
  const PhaseShiftPixels* ps = nullptr;   // the phase-shift level (2 x a sine set's mean)
};

// A codec that planning finds in the session (heightfield/codecs.h): it names its frames (they
// are in ReconstructPlan::frames), decodes them once while they are in memory (the stream's sine
// branch) and then serves its records. Phase shifting and the lens shift are the pipeline's own
// stages; every other pattern family is a PlannedCodec.
class PlannedCodec : public Codec {
 public:
  // Decodes every kActive pixel into the codec's own per-pixel arrays; `state` is not changed (a
  // pixel without a coordinate is invalid in the records: the combine stage rejects it).
  virtual void DecodeFrames(const CodecInputs& in, const PixelStates& state) = 0;
  // Planning: this absolute codec fixes the fringe order of one sine period (OrderedCodec), so
  // coordinates it can only place near a code edge hold (the period's phase decides there).
  virtual void OrdersPeriod() {}
};

// A periodic codec whose order an absolute one fixes, as one absolute codec: u = P (round(u_a /
// P - phi) + phi), valid where both are, the absolute codec's consistency times 1 - (2 (u_a - u)
// / P)^2 (a coordinate half a period off says nothing of the order); sigma and confidence are the
// periodic codec's. Views both codecs, which must outlive it.
class OrderedCodec final : public Codec {
 public:
  OrderedCodec(const Codec& absolute, const Codec& periodic);
  const char* Name() const override { return periodic_.Name(); }
  CodecKind Kind() const override { return CodecKind::kAbsolute; }
  std::vector<int> Frames() const override;
  void SampleNoise(const size_t* pixels, size_t n, double* sigma) const override;
  void Decode(const size_t* pixels, size_t n, const double* noise, CodecRecord* out) const override;
  void Describe(const size_t* pixels, const double* noise, const uint32_t* which, size_t m,
                bool refined, CodecRecord* out) const override;

 private:
  const Codec& absolute_;
  const Codec& periodic_;
};

}  // namespace mesoscan
