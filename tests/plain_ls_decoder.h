#pragma once
// The plain baseline of the robustness tests (a test helper, header-only): a fixed-frequency linear
// least-squares decoder of the lens-shift frames.
//  - frames normalised by their means over the lit pixels (white - black >= 0.02);
//  - per pixel, the 3-parameter linear fit d + A cos(pi x) + B sin(pi x) at the nominal frequency
//    0.5 cycles/px over the shift positions x (projector px, centred on the range);
//  - the fine phase phi = atan2(A, B) gives u mod 2 px (the pipeline's convention, reconstruct.cc:
//    u_fine = 2 * wrap(pi/2 - phi) / (2 pi)); the period is the one nearest to a reference u (the
//    pipeline's own projector_u, so only the fine phase is compared);
//  - triangulated like the pipeline (projector rows where the lens shifter moves along y).
// No weighting, no frequency map, no gain model, no rejection beyond "no reference u".

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "core/scan_folder.h"
#include "heightfield/frames.h"
#include "heightfield/triangulate.h"
#include "session/session.h"

namespace mesoscan::testing {

inline ScanPoints PlainLsDecode(const Session& s, const ImageF& u_ref) {
  constexpr double kPi = 3.14159265358979323846;
  const FramePlan plan = MakeFramePlan(s.frames);
  const char axis = s.rig.lens_shifter ? s.rig.lens_shifter->axis : 'x';
  std::vector<int> frames;
  std::vector<double> x;
  for (size_t f : plan.lens_shift) {
    const Pattern& p = s.frames[f].pattern;
    if (p.axis != axis || std::abs(p.period_px - 2.0) > 1e-9) continue;
    frames.push_back(static_cast<int>(f));
    x.push_back(s.frames[f].shift_steps / s.rig.lens_shifter->steps_per_px);
  }
  const int nk = static_cast<int>(frames.size());
  const double centre = std::accumulate(x.begin(), x.end(), 0.0) / nk;
  for (double& v : x) v -= centre;
  std::vector<int> all = frames;
  const int white_k = nk, black_k = nk + 1;
  all.push_back(static_cast<int>(plan.white.front()));
  all.push_back(static_cast<int>(plan.black.front()));
  const FrameStack st = LoadFrames(s, all, {});
  const size_t np = st.pixels();
  const int w = st.width();
  std::vector<uint8_t> lit(np);
  for (size_t i = 0; i < np; ++i)
    lit[i] = st.Value(white_k, i) - st.Value(black_k, i) >= 0.02 && !st.saturated()[i];
  std::vector<double> mean(nk, 0.0);
  size_t nlit = 0;
  for (size_t i = 0; i < np; ++i) {
    if (!lit[i]) continue;
    ++nlit;
    for (int k = 0; k < nk; ++k) mean[k] += st.Value(k, i);
  }
  const double mm = std::accumulate(mean.begin(), mean.end(), 0.0) / nk;
  // Normal matrix of (1, cos pi x, sin pi x), shared by every pixel.
  double A[3][3] = {};
  for (int k = 0; k < nk; ++k) {
    const double D[3] = {1, std::cos(kPi * x[k]), std::sin(kPi * x[k])};
    for (int p = 0; p < 3; ++p)
      for (int q = 0; q < 3; ++q) A[p][q] += D[p] * D[q];
  }
  auto det = [](const double M[3][3]) {
    return M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1]) -
           M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0]) +
           M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]);
  };
  const double d0 = det(A);
  const Triangulator tri(s.rig.camera, s.rig.projector, axis);
  const PixelRect roi = st.roi();
  ScanPoints out;
  const int cw = s.rig.camera.width, ch = s.rig.camera.height;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  out.xyz = ImageF(cw, ch, 3, nan);
  out.confidence = ImageF(cw, ch, 1, 0.0f);
  out.projector_u = ImageF(cw, ch, 1, nan);
  for (size_t i = 0; i < np; ++i) {
    const int cx = static_cast<int>(i % w) + roi.x, cy = static_cast<int>(i / w) + roi.y;
    if (!lit[i] || !nlit || !std::isfinite(u_ref(cx, cy))) continue;
    double b[3] = {};
    for (int k = 0; k < nk; ++k) {
      const double v = st.Value(k, i) * mm / mean[k];
      b[0] += v;
      b[1] += v * std::cos(kPi * x[k]);
      b[2] += v * std::sin(kPi * x[k]);
    }
    double c[3];
    for (int p = 0; p < 3; ++p) {
      double M[3][3];
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q) M[r][q] = q == p ? b[r] : A[r][q];
      c[p] = det(M) / d0;
    }
    const double phase = std::atan2(c[1], c[2]);  // at the centre of the range
    const double phase0 = phase - 2 * kPi * 0.5 * centre;
    double t = std::fmod(kPi / 2 - phase0, 2 * kPi);
    if (t < 0) t += 2 * kPi;
    const double phi = t / (2 * kPi);
    const double u = 2.0 * (std::round(u_ref(cx, cy) / 2.0 - phi) + phi);
    const auto p = tri.Triangulate(cx, cy, u);
    if (!p) continue;
    for (int q = 0; q < 3; ++q) out.xyz(cx, cy, q) = static_cast<float>((*p)[q]);
    out.confidence(cx, cy) = 1.0f;
    out.projector_u(cx, cy) = static_cast<float>(u);
  }
  return out;
}

// Keeps in `a` only the points that `b` has too (and vice versa): the comparison set.
inline void IntersectPoints(ScanPoints* a, ScanPoints* b) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < a->xyz.height(); ++y)
    for (int x = 0; x < a->xyz.width(); ++x) {
      const bool fa = std::isfinite(a->xyz(x, y, 2)), fb = std::isfinite(b->xyz(x, y, 2));
      if (fa == fb) continue;
      ScanPoints* drop = fa ? a : b;
      for (int q = 0; q < 3; ++q) drop->xyz(x, y, q) = nan;
      drop->confidence(x, y) = 0.0f;
    }
}

}  // namespace mesoscan::testing
