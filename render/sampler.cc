#include "render/sampler.h"

#include <algorithm>
#include <array>

#include "core/error.h"

namespace mesoscan {

namespace {

// Direction numbers of Sobol dimension 1 (primitive polynomial x + 1, m_1 = 1): the recurrence
// m_k = 2 m_{k-1} xor m_{k-1}; v_k = m_k / 2^k, kept as its top 32 bits. Dimension 0 is the van
// der Corput sequence (v_k = 2^-k). Computed once, 64 columns (indices up to 2^64).
struct SobolMatrices {
  std::array<uint32_t, 64> v0{}, v1{};
  // Dimension 1 as byte tables: bytes[b][x] = XOR of the columns 8b..8b+7 selected by x.
  std::array<std::array<uint32_t, 256>, 8> bytes1{};
  SobolMatrices() {
    uint64_t m = 1;  // m_k < 2^k: fits for k <= 64
    for (int k = 1; k <= 64; ++k) {
      if (k > 1) m = (m << 1) ^ m;
      // v_k = m_k * 2^-k; top 32 bits of the fraction = m_k * 2^(32 - k).
      v1[k - 1] =
          k <= 32 ? static_cast<uint32_t>(m << (32 - k)) : static_cast<uint32_t>(m >> (k - 32));
      v0[k - 1] = k <= 32 ? (1u << (32 - k)) : 0u;
    }
    for (int b = 0; b < 8; ++b)
      for (int x = 0; x < 256; ++x) {
        uint32_t r = 0;
        for (int k = 0; k < 8; ++k)
          if (x & (1 << k)) r ^= v1[8 * b + k];
        bytes1[b][x] = r;
      }
  }
};
const SobolMatrices& Matrices() {
  static const SobolMatrices m;
  return m;
}

uint32_t ReverseBits32(uint32_t v) {
  v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
  v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
  v = ((v >> 4) & 0x0F0F0F0Fu) | ((v & 0x0F0F0F0Fu) << 4);
  v = ((v >> 8) & 0x00FF00FFu) | ((v & 0x00FF00FFu) << 8);
  return (v >> 16) | (v << 16);
}

// Interleaves the bits of x and y (x in the even bits).
uint64_t Morton2(uint32_t x, uint32_t y) {
  auto spread = [](uint64_t v) {
    v &= 0xFFFFFFFFull;
    v = (v | (v << 16)) & 0x0000FFFF0000FFFFull;
    v = (v | (v << 8)) & 0x00FF00FF00FF00FFull;
    v = (v | (v << 4)) & 0x0F0F0F0F0F0F0F0Full;
    v = (v | (v << 2)) & 0x3333333333333333ull;
    v = (v | (v << 1)) & 0x5555555555555555ull;
    return v;
  };
  return spread(x) | (spread(y) << 1);
}

// The 24 permutations of {0, 1, 2, 3}, generated in lexicographic order.
struct Permutations4 {
  std::array<std::array<uint8_t, 4>, 24> p{};
  Permutations4() {
    std::array<uint8_t, 4> a{0, 1, 2, 3};
    for (int i = 0; i < 24; ++i) {
      p[i] = a;
      std::next_permutation(a.begin(), a.end());
    }
  }
};
const Permutations4& Perms() {
  static const Permutations4 p;
  return p;
}

}  // namespace

uint64_t MixBits(uint64_t v) {
  v ^= v >> 31;
  v *= 0x7fb5d329728ea185ull;
  v ^= v >> 27;
  v *= 0x81dadef4bc2dd44dull;
  v ^= v >> 33;
  return v;
}

uint32_t SobolBits(uint64_t index, int dimension) {
  // Dimension 0 is the bit reversal of the index's low 32 bits (higher bits fall below 2^-32).
  if (dimension == 0) return ReverseBits32(static_cast<uint32_t>(index));
  const auto& t = Matrices().bytes1;
  uint32_t r = 0;
  for (int b = 0; index; index >>= 8, ++b) r ^= t[b][index & 0xFF];
  return r;
}

uint32_t OwenScramble(uint32_t v, uint32_t seed) {
  // Burley (2020): a Laine-Karras style hash applied to the bit-reversed value scrambles each
  // bit by a hash of the bits above it (nested uniform scrambling).
  v = ReverseBits32(v);
  v ^= v * 0x3d20adeau;
  v += seed;
  v *= (seed >> 16) | 1u;
  v ^= v * 0x05526c56u;
  v ^= v * 0x53a22864u;
  return ReverseBits32(v);
}

ZSobolSampler::ZSobolSampler(int log2_spp, int width, int height, uint64_t seed)
    : log2_spp_(log2_spp), seed_(seed) {
  MESOSCAN_CHECK(log2_spp >= 0 && log2_spp <= 30);
  int res_bits = 0;
  while ((1 << res_bits) < std::max(width, height)) ++res_bits;
  base4_digits_ = res_bits + (log2_spp + 1) / 2;
  MESOSCAN_CHECK(2 * base4_digits_ <= 62);
}

void ZSobolSampler::StartPixelSample(int x, int y, uint32_t sample) {
  const uint64_t m =
      (Morton2(static_cast<uint32_t>(x), static_cast<uint32_t>(y)) << log2_spp_) | sample;
  if ((m >> log2_spp_) != (morton_index_ >> log2_spp_) || generation_ == 0) {
    if (++generation_ == 0) {  // wrapped: clear the stamps
      std::fill(std::begin(cached_for_), std::end(cached_for_), 0u);
      generation_ = 1;
    }
  }
  morton_index_ = m;
  dimension_ = 0;
}

uint64_t ZSobolSampler::PermutedIndex(uint64_t dimension_hash) {
  // Shuffles each base-4 digit of the Morton-ordered index by one of the 24 permutations,
  // chosen by a hash of the digits above it and the dimension (a nested random digit
  // permutation: every elementary interval of the (0,2)-sequence keeps one point). With an odd
  // log2_spp the lowest digit is binary and is flipped by a hashed bit.
  const auto& perms = Perms();
  const bool odd = log2_spp_ & 1;
  uint64_t index = 0;
  const int last = odd ? 1 : 0;
  int top = base4_digits_ - 1;
  if (!odd && dimension_ < kCachedDims) {
    // Digits at and above log2_spp / 2 hold the pixel: the same for all its samples.
    const int first_pixel_digit = log2_spp_ / 2;
    if (cached_for_[dimension_] != generation_) {
      uint64_t part = 0;
      for (int i = base4_digits_ - 1; i >= first_pixel_digit; --i) {
        const int shift = 2 * i;
        const int digit = static_cast<int>((morton_index_ >> shift) & 3);
        const int p =
            static_cast<int>((MixBits((morton_index_ >> (shift + 2)) ^ dimension_hash) >> 24) % 24);
        part |= static_cast<uint64_t>(perms.p[p][digit]) << shift;
      }
      pixel_part_[dimension_] = part;
      cached_for_[dimension_] = generation_;
    }
    index = pixel_part_[dimension_];
    top = first_pixel_digit - 1;
  }
  for (int i = top; i >= last; --i) {
    const int shift = 2 * i - (odd ? 1 : 0);
    const int digit = static_cast<int>((morton_index_ >> shift) & 3);
    const uint64_t higher = morton_index_ >> (shift + 2);
    const int p = static_cast<int>((MixBits(higher ^ dimension_hash) >> 24) % 24);
    index |= static_cast<uint64_t>(perms.p[p][digit]) << shift;
  }
  if (odd) {
    const uint64_t bit = morton_index_ & 1;
    index |= bit ^ (MixBits((morton_index_ >> 1) ^ dimension_hash) & 1);
  }
  return index;
}

double ZSobolSampler::Get1D() {
  const uint64_t h = MixBits(seed_ * 0x9E3779B97F4A7C15ull ^ (dimension_ + 1));
  const uint64_t index = PermutedIndex(h);
  ++dimension_;
  const uint32_t v = OwenScramble(SobolBits(index, 0), static_cast<uint32_t>(h >> 32));
  return std::min(v * 0x1p-32, 0x1.fffffffffffffp-1);
}

void ZSobolSampler::Get2D(double* u0, double* u1) {
  const uint64_t h = MixBits(seed_ * 0x9E3779B97F4A7C15ull ^ (dimension_ + 1));
  const uint64_t index = PermutedIndex(h);
  dimension_ += 2;
  const uint64_t h2 = MixBits(h);
  const uint32_t a = OwenScramble(SobolBits(index, 0), static_cast<uint32_t>(h2));
  const uint32_t b = OwenScramble(SobolBits(index, 1), static_cast<uint32_t>(h2 >> 32));
  *u0 = std::min(a * 0x1p-32, 0x1.fffffffffffffp-1);
  *u1 = std::min(b * 0x1p-32, 0x1.fffffffffffffp-1);
}

}  // namespace mesoscan
