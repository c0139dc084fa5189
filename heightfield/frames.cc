#include "heightfield/frames.h"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstring>
#include <string_view>

#include "core/error.h"
#include "core/image_input.h"
#include "core/log.h"
#include "core/png_gray16.h"
#include "core/progress.h"
#include "core/robust_stats.h"
#include "core/simd_clones.h"
#include "session/raw_frame.h"

namespace mesoscan {
namespace {

PixelRect ClipRoi(const PixelRect& r, int width, int height) {
  if (r.w <= 0 || r.h <= 0) return {0, 0, width, height};
  PixelRect c;
  c.x = std::clamp(r.x, 0, width);
  c.y = std::clamp(r.y, 0, height);
  c.w = std::clamp(r.x + r.w, 0, width) - c.x;
  c.h = std::clamp(r.y + r.h, 0, height) - c.y;
  return c;
}

struct DecodedFrame {
  int width = 0, height = 0, channels = 0;
  bool is_float = false;
  bool eight_bit = false;
  bool direct = false;     // decoded into the caller's buffer (u16 left empty)
  FrameSamples u16;        // interleaved
  std::vector<float> f32;  // interleaved
};

// Decodes a frame. `direct` (optional): where a single-channel integer frame is stored as it is
// (resized to width x height); d.direct tells whether it was used.
DecodedFrame Decode(const std::filesystem::path& path, const std::string& label,
                    FrameSamples* direct = nullptr) {
  if (IsCameraRawPath(path)) {  // 2x2 Bayer cells averaged, black subtracted (session/raw_frame.h)
    CheckRegularFile(path, label);
    ImageU16 grey = ReadRawGrey(path, label);
    DecodedFrame d;
    d.width = grey.width();
    d.height = grey.height();
    d.channels = 1;
    d.u16.assign(grey.data().begin(), grey.data().end());  // (camera raw files: a copy)
    return d;
  }
  DecodedFrame d;
  // A grey 8- or 16-bit PNG (every frame the rig writes): the fast path (core/png_gray16.h),
  // without opening the file through OpenImageIO (whose module then never loads); anything it
  // does not take is decoded (or refused) by OIIO below.
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".png") {
    const bool fast = ReadPngGray16(path, [&](int w, int h, int bits) -> uint16_t* {
      CheckImageBudget(label, w, h, 1);  // as OpenImageInput checks before decoding
      d.width = w;
      d.height = h;
      d.channels = 1;
      d.eight_bit = bits == 8;
      d.direct = direct != nullptr;
      FrameSamples& dst = d.direct ? *direct : d.u16;
      dst.resize(static_cast<size_t>(w) * h);
      return dst.data();
    });
    if (fast) return d;
    d = DecodedFrame();
  }
  auto in = OpenImageInput(path, label);  // regular file, extension's reader, size vs header
  const ImageHeader& spec = in->header();
  d.width = spec.width;
  d.height = spec.height;
  d.channels = spec.channels;
  d.is_float = spec.is_float;
  d.eight_bit = spec.format_bytes == 1;
  const size_t n = static_cast<size_t>(d.width) * d.height * d.channels;
  d.direct = direct && !d.is_float && d.channels == 1;
  bool ok;
  if (d.is_float) {
    d.f32.resize(n);
    ok = in->Read(PixelType::kFloat, d.f32.data());
  } else {
    FrameSamples& dst = d.direct ? *direct : d.u16;
    dst.resize(n);
    ok = in->Read(PixelType::kUInt16, dst.data());
  }
  if (!ok)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "cannot decode image (" << in->error() << ")");
  return d;
}

// out[i] = float(src[i] * scale + offset), the product and sum in double (core/simd_clones.h).
MESOSCAN_SIMD_CLONES
void AffineToFloat(const uint16_t* src, size_t n, double scale, double offset, float* out) {
  for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(src[i] * scale + offset);
}

// Marks (mark(i)) the samples src[i] >= code of src[0..n): blocks of 256 are screened first by
// a branch-free OR (vectorised; every block of a well exposed frame passes at once).
MESOSCAN_SIMD_CLONES
bool AnyAtLeast(const uint16_t* src, size_t n, uint16_t code) {
  unsigned any = 0;
  for (size_t i = 0; i < n; ++i) any |= src[i] >= code;
  return any != 0;
}
template <class Mark>
void MarkAtLeast(const uint16_t* src, size_t n, uint16_t code, Mark&& mark) {
  constexpr size_t kBlock = 256;
  for (size_t b = 0; b < n; b += kBlock) {
    const size_t m = std::min(kBlock, n - b);
    if (!AnyAtLeast(src + b, m, code)) continue;
    for (size_t i = b; i < b + m; ++i)
      if (src[i] >= code) mark(i);
  }
}

// Colour channels (an alpha channel, 2nd of 2 or 4th of 4, ignored).
int ColourChannels(int channels) {
  return (channels == 2 || channels == 4) ? channels - 1 : channels;
}

// Weights of the colour channels in the grey value decoded: an RGB frame's luminance (ITU-R
// BT.709 / sRGB primaries: 0.2126 R + 0.7152 G + 0.0722 B), the mean of any other channel count.
// kLumaQ16: the same weights in 1/65536 (summing to 65536) for integer frames.
constexpr float kLuma[3] = {0.2126f, 0.7152f, 0.0722f};
constexpr uint32_t kLumaQ16[3] = {13933, 46872, 4731};
static_assert(kLumaQ16[0] + kLumaQ16[1] + kLumaQ16[2] == 65536);

}  // namespace

void FrameLoadOptions::Check() const {
  if (!(saturation_level > 0.0 && saturation_level <= 1.0))
    MESOSCAN_BAD_INPUT("saturation_level: expected a value in (0, 1], got " << saturation_level);
  if (roi.w < 0 || roi.h < 0 || roi.x < 0 || roi.y < 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("FrameLoadOptions.roi"),
                          "expected non-negative x, y, w, h");
}

void FrameStack::Gather(int k, size_t i0, size_t n, float* out) const {
  if (is_float_) {
    const float* src = raw_float_[k].data() + i0;
    for (size_t i = 0; i < n; ++i) out[i] = src[i] - float_black_;
  } else {
    const uint16_t* src = raw_[k].data() + i0;
    if (lut_affine_) {
      AffineToFloat(src, n, lut_scale_, lut_offset_, out);
      return;
    }
    const float* lut = lut_.data();
    for (size_t i = 0; i < n; ++i) out[i] = lut[src[i]];
  }
}

void FrameStack::Merge(FrameStack&& o) {
  if (o.width_ != width_ || o.height_ != height_ || o.is_float_ != is_float_ ||
      o.session_frames_ != session_frames_)
    MESOSCAN_THROW(::mesoscan::ErrorKind::kInternal,
                   "FrameStack::Merge: stacks of different frames, sizes or storage");
  for (int k = 0; k < num_frames(); ++k) {
    if (is_float_) {
      if (raw_float_[k].empty()) raw_float_[k] = std::move(o.raw_float_[k]);
    } else if (raw_[k].empty()) {
      raw_[k] = std::move(o.raw_[k]);
    }
  }
  for (size_t i = 0; i < saturated_.size() && i < o.saturated_.size(); ++i)
    saturated_[i] |= o.saturated_[i];
  eight_bit_frames_ += o.eight_bit_frames_;
  o = FrameStack();
}

void GatheredSamples::Gather(int k, const uint16_t* samples) {
  std::vector<uint16_t>& c = codes[k];
  c.resize(pixels.size());
  for (size_t j = 0; j < pixels.size(); ++j) c[j] = samples[pixels[j]];
}

bool GatheredSamples::Complete(const std::vector<int>& frames) const {
  if (pixels.empty()) return false;
  for (int k : frames)
    if (k < 0 || static_cast<size_t>(k) >= codes.size() || codes[k].size() != pixels.size())
      return false;
  return true;
}

FrameStack LoadFrames(const Session& session, const std::vector<int>& frame_indices,
                      const FrameLoadOptions& options, const std::vector<uint8_t>* decode_only) {
  options.Check();
  if (decode_only && decode_only->size() != frame_indices.size())
    MESOSCAN_THROW(::mesoscan::ErrorKind::kInternal, "LoadFrames: decode_only has "
                                                         << decode_only->size() << " entries for "
                                                         << frame_indices.size() << " frames");
  auto decoded = [&](size_t k) { return !decode_only || (*decode_only)[k]; };
  const PinholeCamera& cam = session.rig.camera;
  FrameStack s;
  s.roi_ = ClipRoi(options.roi, cam.width, cam.height);
  if (s.roi_.w <= 0 || s.roi_.h <= 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("FrameLoadOptions.roi"),
                          options.roi.x << "," << options.roi.y << "," << options.roi.w << ","
                                        << options.roi.h << " does not overlap the " << cam.width
                                        << "x" << cam.height << " camera image");
  s.width_ = s.roi_.w;
  s.height_ = s.roi_.h;
  s.session_frames_ = frame_indices;
  const int nf = static_cast<int>(frame_indices.size());
  const size_t np = s.pixels();

  // Which storage: float only if some frame is float (EXR); decided from the headers. PNG holds
  // integers only: those frames are not opened twice (a serial open per frame costs ~1 ms).
  bool any_float = false;
  for (int f : frame_indices) {  // every frame of the list: merged stacks share the storage
    const auto path = session.FramePath(f);
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".png") continue;
    auto in = OpenImageInput(path, path.string() + ": frames[" + std::to_string(f) + "]");
    any_float |= in->header().is_float;
  }
  s.is_float_ = any_float;
  // Allocated by the decoding tasks (in parallel; a direct decode fills its frame itself).
  if (any_float)
    s.raw_float_.assign(nf, {});
  else
    s.raw_.assign(nf, {});

  const uint16_t sat_code =
      static_cast<uint16_t>(std::min(65535.0, std::floor(options.saturation_level * 65535.0)));
  std::atomic<int> eight_bit{0};
  // 1 where any frame saturates; frames decoded in parallel mark it through relaxed atomic
  // stores (only saturated samples write, so this costs nothing on well exposed frames).
  std::vector<uint8_t> saturated(np, 0);
  auto mark_saturated = [&](size_t i) {
    std::atomic_ref<uint8_t>(saturated[i]).store(1, std::memory_order_relaxed);
  };
  {
    int n_decoded = 0;
    for (int k = 0; k < nf; ++k) n_decoded += decoded(k);
    Progress progress("decode frames", n_decoded);
    tbb::parallel_for<int64_t>(0, nf, [&](int64_t k) {
      if (!decoded(k)) return;
      const int f = frame_indices[k];
      const auto path = session.FramePath(f);
      const std::string label = path.string() + ": frames[" + std::to_string(f) + "]";
      // A grey integer frame covering the whole ROI decodes straight into the stack (no copy).
      FrameSamples* direct = (!any_float && s.roi_.x == 0 && s.roi_.y == 0 &&
                              s.roi_.w == cam.width && s.roi_.h == cam.height)
                                 ? &s.raw_[k]
                                 : nullptr;
      DecodedFrame d = Decode(path, label, direct);
      if (d.width != cam.width || d.height != cam.height)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                              "size " << d.width << "x" << d.height
                                      << ", expected camera.width x camera.height = " << cam.width
                                      << "x" << cam.height);
      if (d.is_float && !any_float)  // not a PNG after all
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                              "a floating-point image in a file named .png");
      if (d.eight_bit) eight_bit.fetch_add(1);
      if (d.direct) {
        MarkAtLeast(s.raw_[k].data(), np, sat_code, mark_saturated);
        if (options.on_decoded) options.on_decoded(static_cast<int>(k), s.raw_[k].data());
        progress.Advance();
        return;
      }
      if (any_float)
        s.raw_float_[k].resize(np);
      else
        s.raw_[k].resize(np);
      const int nc = d.channels, ncc = ColourChannels(nc);
      for (int y = 0; y < s.height_; ++y) {
        const size_t src_row = (static_cast<size_t>(y + s.roi_.y) * d.width + s.roi_.x) * nc;
        const size_t dst_row = static_cast<size_t>(y) * s.width_;
        for (int x = 0; x < s.width_; ++x) {
          const size_t src = src_row + static_cast<size_t>(x) * nc;
          bool saturated_sample = false;
          if (d.is_float || any_float) {
            float v = 0.0f;
            for (int c = 0; c < ncc; ++c) {
              const float sample = d.is_float ? d.f32[src + c] : d.u16[src + c] / 65535.0f;
              if (!d.is_float && d.u16[src + c] >= sat_code) saturated_sample = true;
              v += ncc == 3 ? kLuma[c] * sample : sample;
            }
            s.raw_float_[k][dst_row + x] = ncc == 3 ? v : v / ncc;
          } else {
            uint32_t v = 0;
            for (int c = 0; c < ncc; ++c) {
              v += ncc == 3 ? kLumaQ16[c] * d.u16[src + c] : d.u16[src + c];
              if (d.u16[src + c] >= sat_code) saturated_sample = true;
            }
            s.raw_[k][dst_row + x] =
                static_cast<uint16_t>(ncc == 3 ? (v + 32768u) >> 16 : (v + ncc / 2) / ncc);
          }
          if (saturated_sample) mark_saturated(dst_row + x);
        }
      }
      if (!any_float && options.on_decoded)
        options.on_decoded(static_cast<int>(k), s.raw_[k].data());
      progress.Advance();
    });
  }
  s.saturated_ = std::move(saturated);
  s.eight_bit_frames_ = eight_bit.load();
  if (s.eight_bit_frames_ > 0)
    MESOSCAN_LOG(kWarning) << session.root.string() << ": " << s.eight_bit_frames_
                           << " frame(s) have 8 bits per sample; precision is limited";

  // Black level and response: linear = ToLinear(v) - ToLinear(black_level), v in [0, 1]
  // (black_level is a level in the frame's own units, so it is linearised like the frames).
  const Response& resp = session.rig.camera_response;
  const double black_lin = resp.ToLinear(session.rig.black_level);
  if (s.is_float_) {
    // Float frames are linear radiance as stored; a non-linear response is applied in place.
    if (resp.kind != Response::Kind::kLinear) {
      tbb::parallel_for<int64_t>(0, nf, [&](int64_t k) {
        for (float& v : s.raw_float_[k]) v = static_cast<float>(resp.ToLinear(v));
      });
    }
    s.float_black_ = static_cast<float>(black_lin);
  } else {
    s.lut_.resize(65536);
    for (int c = 0; c < 65536; ++c)
      s.lut_[c] = static_cast<float>(resp.ToLinear(c / 65535.0) - black_lin);
    // A linear response: the table is (usually) float(c / 65535 - black) = float(c * (1 /
    // 65535) - black) to the bit (the double product is off by an ulp at most, which moves the
    // float only within 2^-29 of a rounding boundary). Checked code by code, with the arithmetic
    // Gather uses.
    if (resp.kind == Response::Kind::kLinear) {
      const double scale = 1.0 / 65535.0, offset = -black_lin;
      std::vector<uint16_t> codes(65536);
      std::vector<float> affine(65536);
      for (int c = 0; c < 65536; ++c) codes[c] = static_cast<uint16_t>(c);
      AffineToFloat(codes.data(), codes.size(), scale, offset, affine.data());
      s.lut_affine_ = std::isfinite(offset) &&
                      std::memcmp(affine.data(), s.lut_.data(), affine.size() * sizeof(float)) == 0;
      s.lut_scale_ = scale;
      s.lut_offset_ = offset;
    }
  }
  return s;
}

double OutlierLimit(std::vector<double> values) {
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  const double med = values[mid];
  for (double& v : values) v = std::abs(v - med);
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  return med + 4 * kMadToSigma * values[mid];
}

std::vector<double> EstimateFrameGains(const FrameStack& stack, const GainModel& model,
                                       const std::vector<uint32_t>& pixels, int iterations) {
  // Alternating least squares from g = 1: per-pixel coefficients with the current gains (one
  // shared pseudo-inverse), then g_k = sum I m / sum m^2 over the inlier pixels. A few steps
  // recover the gain patterns the per-pixel model cannot absorb; patterns it can nearly absorb
  // (e.g. a cosine in the frame index for a sinusoid model) are identifiable only through the
  // noise and are deliberately left near 1: iterating to the joint minimum lets the noise
  // (errors in variables) bias them, which costs more phase accuracy than it gains.
  const int nk = static_cast<int>(model.frames.size());
  std::vector<double> gains(nk, 1.0);
  if (nk == 0 || pixels.empty()) return gains;
  const int np = static_cast<int>(model.design[0].size());
  if (nk <= np) return gains;  // every gain pattern is absorbed by the per-pixel model
  // Gathered frame by frame in parallel (a frame's samples at increasing pixels).
  const size_t n = pixels.size();
  std::vector<float> by_frame(static_cast<size_t>(nk) * n);
  tbb::parallel_for<int64_t>(0, nk, [&](int64_t k) {
    float* dst = by_frame.data() + static_cast<size_t>(k) * n;
    for (size_t j = 0; j < n; ++j) dst[j] = stack.Value(model.frames[k], pixels[j]);
  });
  return EstimateFrameGains(by_frame, n, model, iterations);
}

std::vector<double> EstimateFrameGains(const std::vector<float>& by_frame, size_t n,
                                       const GainModel& model, int iterations) {
  const int nk = static_cast<int>(model.frames.size());
  std::vector<double> gains(nk, 1.0);
  if (nk == 0 || n == 0 || by_frame.size() != static_cast<size_t>(nk) * n) return gains;
  const int np = static_cast<int>(model.design[0].size());
  if (nk <= np) return gains;  // every gain pattern is absorbed by the per-pixel model
  Eigen::MatrixXd M(nk, np);
  for (int k = 0; k < nk; ++k)
    for (int p = 0; p < np; ++p) M(k, p) = model.design[k][p];
  Eigen::MatrixXd I(nk, n);  // samples, frame-major
  {
    // Transposed in blocks of pixels (a frame's row of the block stays in cache).
    constexpr size_t kT = 64;
    for (size_t j0 = 0; j0 < n; j0 += kT)
      for (int k = 0; k < nk; ++k)
        for (size_t j = j0; j < std::min(n, j0 + kT); ++j)
          I(k, static_cast<Eigen::Index>(j)) = by_frame[static_cast<size_t>(k) * n + j];
  }
  std::vector<uint8_t> use(n, 1);
  for (int it = 0; it < iterations; ++it) {
    Eigen::MatrixXd Mg = M;
    for (int k = 0; k < nk; ++k) Mg.row(k) *= gains[k];
    const Eigen::MatrixXd pinv = (Mg.transpose() * Mg).ldlt().solve(Mg.transpose());
    // The ungained model (nk x n) and each pixel's relative residual, by blocks of pixels on the
    // pool (each column's products and sums as in one product over all of them: ~80 ms serial
    // right after the last lens-shift frame at full resolution).
    Eigen::MatrixXd model_val(nk, static_cast<Eigen::Index>(n));
    std::vector<double> rel(n);
    constexpr size_t kBlock = 2048;
    tbb::parallel_for<int64_t>(0, static_cast<int64_t>((n + kBlock - 1) / kBlock), [&](int64_t b) {
      const size_t j0 = static_cast<size_t>(b) * kBlock, m = std::min(kBlock, n - j0);
      const auto cols = [&](auto& a) {
        return a.middleCols(static_cast<Eigen::Index>(j0), static_cast<Eigen::Index>(m));
      };
      cols(model_val).noalias() = M * (pinv * cols(I));
      // Robust: drop pixels whose relative residual is an outlier (> median + 4 MAD).
      for (size_t j = j0; j < j0 + m; ++j) {
        double r2 = 0.0, m2 = 0.0;
        for (int k = 0; k < nk; ++k) {
          const double r = I(k, j) - gains[k] * model_val(k, j);
          r2 += r * r;
          m2 += model_val(k, j) * model_val(k, j);
        }
        rel[j] = m2 > 0 ? std::sqrt(r2 / m2) : std::numeric_limits<double>::infinity();
      }
    });
    const double limit = OutlierLimit(rel);
    for (size_t j = 0; j < n; ++j) use[j] = std::isfinite(rel[j]) && rel[j] <= limit;
    // Each frame's sums in pixel order, all frames in one pass down the (frame-major) columns:
    // the frames in parallel strode across both matrices, a cache miss per sample (~10 ms an
    // iteration right after the last lens-shift frame at full resolution).
    std::vector<double> num(nk, 0.0), den(nk, 0.0);
    for (size_t j = 0; j < n; ++j) {
      if (!use[j]) continue;
      const double* ij = &I(0, static_cast<Eigen::Index>(j));
      const double* mj = &model_val(0, static_cast<Eigen::Index>(j));
      for (int k = 0; k < nk; ++k) {
        num[k] += ij[k] * mj[k];
        den[k] += mj[k] * mj[k];
      }
    }
    std::vector<double> next(gains);
    for (int k = 0; k < nk; ++k)
      if (den[k] > 0) next[k] = num[k] / den[k];
    gains = std::move(next);
    double mean = 0.0;
    for (double g : gains) mean += g;
    mean /= nk;
    for (double& g : gains) g /= mean;
  }
  return gains;
}

FrameStack FrameStack::FromLinear(int width, int height, std::vector<std::vector<float>> frames,
                                  std::vector<uint8_t> saturated, int origin_x, int origin_y) {
  FrameStack s;
  s.width_ = width;
  s.height_ = height;
  s.roi_ = {origin_x, origin_y, width, height};
  s.is_float_ = true;
  for (const auto& f : frames)
    if (f.size() != s.pixels()) MESOSCAN_THROW(ErrorKind::kInternal, "FromLinear: frame size");
  for (size_t k = 0; k < frames.size(); ++k) s.session_frames_.push_back(static_cast<int>(k));
  s.raw_float_ = std::move(frames);
  s.saturated_ = saturated.empty() ? std::vector<uint8_t>(s.pixels(), 0) : std::move(saturated);
  return s;
}

}  // namespace mesoscan
