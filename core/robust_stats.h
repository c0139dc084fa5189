#pragma once
// Robust statistics shared by the fits that reject outliers (gain fits, mount and shifter
// calibration, lens-shift refits, map flattening).

#include <algorithm>
#include <vector>

namespace mesoscan {

// Turns a median absolute deviation into the standard deviation of a normal distribution
// (1 / Phi^-1(3/4)): a "robust sigma" is kMadToSigma * MAD.
inline constexpr double kMadToSigma = 1.4826;

// The median of `v` (taken by value, partially sorted): the upper one, v[n/2], of an even count;
// 0 for an empty list.
inline double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace mesoscan
