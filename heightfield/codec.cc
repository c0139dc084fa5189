#include "heightfield/codec.h"

#include <cmath>

namespace mesoscan {

OrderedCodec::OrderedCodec(const Codec& absolute, const Codec& periodic)
    : absolute_(absolute), periodic_(periodic) {}

std::vector<int> OrderedCodec::Frames() const {
  std::vector<int> frames = absolute_.Frames();
  for (int f : periodic_.Frames()) frames.push_back(f);
  return frames;
}

void OrderedCodec::SampleNoise(const size_t* pixels, size_t n, double* sigma) const {
  periodic_.SampleNoise(pixels, n, sigma);
  absolute_.SampleNoise(pixels, n, sigma);
}

void OrderedCodec::Decode(const size_t* pixels, size_t n, const double* noise,
                          CodecRecord* out) const {
  thread_local CodecRecord coarse;  // reused by each thread
  absolute_.Decode(pixels, n, noise, &coarse);
  periodic_.Decode(pixels, n, noise, out);
  const double period = periodic_.PeriodPx();
  for (size_t a = 0; a < n; ++a) {
    if (!coarse.valid[a] || !out->valid[a]) {
      out->valid[a] = 0;
      continue;
    }
    const double u_abs = coarse.value[a], phi = out->value[a];
    const double u = period * (std::round(u_abs / period - phi) + phi);
    const double off = 2.0 * (u_abs - u) / period;  // in (-1, 1]
    out->value[a] = u;
    out->residual[a] = coarse.residual[a];
    out->consistency[a] = coarse.consistency[a] * (1.0 - off * off);
  }
}

void OrderedCodec::Describe(const size_t* pixels, const double* noise, const uint32_t* which,
                            size_t m, bool refined, CodecRecord* out) const {
  periodic_.Describe(pixels, noise, which, m, refined, out);
}

}  // namespace mesoscan
