#pragma once
// Low-discrepancy samples for the preview renderer: Owen-scrambled Sobol points ordered along a
// Morton curve over the image (the "ZSobol" construction of Ahmed & Wonka 2020, as used by
// pbrt-v4's ZSobolSampler), written for this project.
//
//  * Each pixel owns 2^log2_spp consecutive indices of one global (0,2)-sequence: index =
//    morton(x, y) << log2_spp | sample. The base-4 digits of that index are shuffled per
//    dimension by hashed permutations (a random digit scrambling that keeps the net
//    structure), so neighbouring pixels receive complementary points (blue-noise error).
//  * Every 1D/2D request uses the first two Sobol dimensions (generated here from their
//    primitive polynomials, no table) with a hash-based nested uniform (Owen) scramble seeded by
//    (seed, dimension) (Burley 2020, "Practical hash-based Owen scrambling"). Different
//    dimensions therefore use independent randomisations of the same well-stratified 2D net
//    ("padding"), the standard way to reach the path's high dimensions with a 2D sequence.
//  * Any prefix of a pixel's samples whose length is a power of 4 is a stratified (0,m,2)-net
//    in every dimension pair; even and odd sample numbers are each a stratified half, which
//    the adaptive error estimate uses (two interleaved half-buffers).
//  * `seed` changes every permutation and scramble: different seeds are independent
//    randomisations; the same seed is bit-for-bit reproducible (no state across pixels).

#include <cstdint>

namespace mesoscan {

// Sobol dimension 0 or 1 of `index` as a 32-bit fraction (bits beyond 32 contribute below
// the float resolution). Exposed for tests.
uint32_t SobolBits(uint64_t index, int dimension);
// Nested uniform scramble of a 32-bit fraction by `seed` (Owen scrambling, hashed).
uint32_t OwenScramble(uint32_t v, uint32_t seed);
// 64-bit mixing hash (SplitMix64 finaliser).
uint64_t MixBits(uint64_t v);

class ZSobolSampler {
 public:
  // log2_spp: samples per pixel are < 2^log2_spp (<= 30). Image of width x height pixels.
  ZSobolSampler(int log2_spp, int width, int height, uint64_t seed);

  // Starts sample `sample` (< 2^log2_spp) of pixel (x, y); dimensions restart at 0.
  void StartPixelSample(int x, int y, uint32_t sample);
  double Get1D();
  void Get2D(double* u0, double* u1);
  int log2_spp() const { return log2_spp_; }

 private:
  uint64_t PermutedIndex(uint64_t dimension_hash);
  // The permuted pixel digits (above the sample digits) depend only on the pixel and the
  // dimension: cached per pixel for the first kCachedDims dimensions (3x fewer hashes per path).
  static constexpr int kCachedDims = 48;
  uint64_t pixel_part_[kCachedDims] = {};
  uint32_t cached_for_[kCachedDims] = {};  // generation stamp per entry
  uint32_t generation_ = 0;
  int log2_spp_;
  int base4_digits_;
  uint64_t seed_;
  uint64_t morton_index_ = 0;
  uint32_t dimension_ = 0;
};

}  // namespace mesoscan
