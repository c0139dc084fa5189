#pragma once
// Frames of a session, decoded in parallel and kept compact (uint16 per sample, 2 bytes instead of
// 4: 59 frames of 3.1 Mpx are 370 MB), with the camera's black level and response applied through
// a 65536-entry table when samples are gathered. Per-frame luminance normalisation (Ritz et al.
// 2012, Sec. 5.1: the camera's brightness jitters from frame to frame) is estimated robustly on
// valid pixels by alternating a per-pixel linear model and per-frame gains.

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

#include "core/image.h"
#include "core/rect.h"
#include "session/session.h"

namespace mesoscan {

// An allocator whose resize() leaves new elements uninitialised (default-initialised): a frame's
// samples are all written by its decoder, and zero-filling 6.2 MB first cost a pass over memory
// per frame (61 frames of 3.1 Mpx: 381 MB of memset).
template <class T>
struct NoInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = NoInitAllocator<U>;
  };
  NoInitAllocator() = default;
  template <class U>
  NoInitAllocator(const NoInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
using FrameSamples = std::vector<uint16_t, NoInitAllocator<uint16_t>>;

struct FrameLoadOptions {
  // Region of the camera image to keep (clipped to the image); empty = everything.
  PixelRect roi;
  // A raw sample at or above this fraction of the format's full scale counts as saturated, in
  // (0, 1]. 16-bit: 65535 * 0.999; 8-bit frames are scaled to 16 bit first (255 -> 65535).
  double saturation_level = 0.999;
  // If set, called by the decoding task of stack frame k with its 16-bit samples (the ROI,
  // row-major) as soon as they are final; integer frames only. The samples stay where they are
  // (in the returned stack) until the frame is released.
  std::function<void(int k, const uint16_t* samples)> on_decoded;
  void Check() const;
};

// Some frames' 16-bit samples at a few pixels, gathered while the frames decode
// (FrameLoadOptions::on_decoded: scattered reads off the time after the last frame).
struct GatheredSamples {
  std::vector<uint32_t> pixels;                         // stack pixels
  std::vector<std::vector<uint16_t>> codes;             // codes[k][j]: stack frame k at pixels[j]
  void Gather(int k, const uint16_t* samples);          // frame k's (ROI, row-major) at `pixels`
  bool Complete(const std::vector<int>& frames) const;  // every one of `frames` gathered
};

// The decoded frames of one session (a chosen subset, in the order asked for), cropped to the ROI.
class FrameStack {
 public:
  int width() const { return width_; }
  int height() const { return height_; }
  size_t pixels() const { return static_cast<size_t>(width_) * height_; }
  int num_frames() const { return static_cast<int>(is_float_ ? raw_float_.size() : raw_.size()); }
  // The ROI in camera pixels (x, y of the stack's pixel (0, 0)).
  const PixelRect& roi() const { return roi_; }
  // Session frame index of stack frame k.
  int session_frame(int k) const { return session_frames_[k]; }

  // Linear radiance (black level subtracted, response linearised, NOT luminance-normalised) of
  // frame k at stack pixels [i0, i0 + n) into out[0..n).
  void Gather(int k, size_t i0, size_t n, float* out) const;
  float Value(int k, size_t i) const {
    return is_float_ ? raw_float_[k][i] - float_black_ : lut_[raw_[k][i]];
  }
  // Value of a 16-bit sample `code` of an integer stack (is_float() false).
  float Linear(uint16_t code) const { return lut_[code]; }
  // Frame k's 16-bit samples (ROI, row-major) of an integer stack.
  const uint16_t* Samples16(int k) const { return raw_[k].data(); }
  bool is_float() const { return is_float_; }
  // Frees the samples of frame k (the streaming driver releases each frame after the last stage
  // that reads it); Gather / Value must not be called for it afterwards.
  void Release(int k) {
    if (k < 0 || k >= num_frames()) return;
    if (is_float_)
      std::vector<float>().swap(raw_float_[k]);
    else
      FrameSamples().swap(raw_[k]);
  }
  // Moves in the frames that `other` (a stack of the same frame list, ROI and storage, loaded
  // with the complementary decode_only mask) holds and this one does not, and adds its saturated
  // pixels. Throws Error (internal) if the stacks do not match.
  void Merge(FrameStack&& other);
  // 1 where any frame of the stack is saturated at that pixel.
  const std::vector<uint8_t>& saturated() const { return saturated_; }
  // Number of frames that were stored with 8 bits per sample.
  int eight_bit_frames() const { return eight_bit_frames_; }

  // A stack held in memory (tests of the reconstruction stages): `frames` are linear radiance,
  // black level 0, each width x height row-major; `saturated` (empty: none) per pixel; the ROI
  // starts at camera pixel (origin_x, origin_y).
  static FrameStack FromLinear(int width, int height, std::vector<std::vector<float>> frames,
                               std::vector<uint8_t> saturated = {}, int origin_x = 0,
                               int origin_y = 0);

 private:
  friend FrameStack LoadFrames(const Session&, const std::vector<int>&, const FrameLoadOptions&,
                               const std::vector<uint8_t>*);
  int width_ = 0, height_ = 0;
  PixelRect roi_;
  bool is_float_ = false;  // every frame is float (EXR): raw_float_ is used instead of raw_
  float float_black_ = 0.0f;
  std::vector<int> session_frames_;
  std::vector<FrameSamples> raw_;
  std::vector<std::vector<float>> raw_float_;
  std::vector<float> lut_;  // raw code -> linear radiance (black subtracted), 65536 entries
  // Where every entry of lut_ equals float(code * lut_scale_ + lut_offset_) (double arithmetic;
  // a linear response, checked over all 65536 codes), Gather computes it instead of looking it
  // up: the same floats, in vector registers (the lens-shift stage gathers 150 M samples).
  bool lut_affine_ = false;
  double lut_scale_ = 0.0, lut_offset_ = 0.0;
  std::vector<uint8_t> saturated_;
  int eight_bit_frames_ = 0;
};

// Decodes frames `frame_indices` of `session` in parallel (TBB, a progress bar "decode frames"),
// grey (an RGB frame's BT.709 luminance, other channel counts averaged), cropped to the ROI. Throws
// Error naming the frame on an unreadable file or a size other than camera.width x camera.height.
// Float (EXR) frames are kept as float; a session mixing float and integer frames is converted to
// float throughout. decode_only (if given, one entry per frame_indices entry): only frames with a
// non-zero entry are decoded, the others are left empty (as Release does) and do not count for
// saturated(); Merge then joins two such stacks (the driver decodes the lens-shift frames while it
// works on the others).
FrameStack LoadFrames(const Session& session, const std::vector<int>& frame_indices,
                      const FrameLoadOptions& options,
                      const std::vector<uint8_t>* decode_only = nullptr);

// Per-frame luminance gains (Ritz et al. 2012, Sec. 5.1). A group of frames shares a per-pixel
// linear model I_k(i) = g_k * sum_p M(k, p) c_p(i) (e.g. DC + cos + sin of a sinusoid at known
// positions). Alternating least squares from g = 1 on `pixels` (indices into the stack): per-pixel
// coefficients c(i) with the current gains, then g_k = sum I m / sum m^2 over the pixels whose
// relative residual is not an outlier (> median + 4 MAD). Returns g normalised to mean 1.
// Gain patterns the per-pixel model can (nearly) absorb are left near 1 on purpose (see .cc).
struct GainModel {
  std::vector<int> frames;                  // stack frame indices of the group
  std::vector<std::vector<double>> design;  // design[k][p] for frame frames[k]
};
std::vector<double> EstimateFrameGains(const FrameStack& stack, const GainModel& model,
                                       const std::vector<uint32_t>& pixels, int iterations = 3);
// The same on samples gathered already: by_frame[k * n + j] the value of frame model.frames[k]
// at the j-th of n pixels.
std::vector<double> EstimateFrameGains(const std::vector<float>& by_frame, size_t n,
                                       const GainModel& model, int iterations = 3);

// The outlier limit of the gain fits' relative residuals: median + 4 robust sigmas (1.4826 MAD).
// `values` must not be empty.
double OutlierLimit(std::vector<double> values);

}  // namespace mesoscan
