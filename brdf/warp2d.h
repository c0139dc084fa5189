#pragma once
// Sample warping for a tabulated 2-D density on [0,1]^2 that is bilinear between grid nodes and may
// depend on up to three extra parameters (interpolated linearly between tabulated values).
//
// This is the "marginal then conditional, continuous" scheme of Dupuy & Jakob 2018 (sec. 5):
// sampling inverts the exact CDF of the bilinear interpolant (a quadratic per patch), so Sample()
// and Invert() are exact inverses and the density returned by both equals Eval(). Each parameter
// slice is normalised on its own, so any linear blend of slices is a density too.

#include <Eigen/Core>
#include <string>
#include <utility>
#include <vector>

namespace mesoscan {

class Warp2D {
 public:
  static constexpr int kMaxParams = 3;

  Warp2D() = default;

  // data: values >= 0, laid out [param 0][param 1]...[height][width] (width
  // contiguous), i.e.
  //   x (first coordinate of a position) runs along width, y along height.
  //   width, height >= 2.
  // param_values: for each parameter, its tabulated values in ascending order
  // (>= 1 each). sampling: true normalises every slice to integrate to 1 over
  // [0,1]^2 and builds the CDFs
  //   (Eval then returns a density); false keeps raw values (Eval is a plain
  //   interpolant).
  // name: used in error messages ("vndf", "luminance"...). A slice with no mass
  // throws
  //   Error(kBadInput) when sampling is requested.
  Warp2D(int width, int height, std::vector<double> data,
         std::vector<std::vector<double>> param_values, bool sampling, std::string name);

  int width() const { return width_; }
  int height() const { return height_; }

  // Interpolated value (sampling: the normalised density on [0,1]^2) at pos in [0,1]^2 for the
  // given parameters (param_values.size() of them; values outside the table are clamped).
  double Eval(const Eigen::Vector2d& pos, const double* params = nullptr) const;
  // Maps a uniform u in [0,1]^2 to a position distributed by the density; returns it and its
  // density. Requires sampling = true.
  std::pair<Eigen::Vector2d, double> Sample(const Eigen::Vector2d& u,
                                            const double* params = nullptr) const;
  // The inverse of Sample: position -> uniform variate, and the density at the position.
  std::pair<Eigen::Vector2d, double> Invert(const Eigen::Vector2d& pos,
                                            const double* params = nullptr) const;

 private:
  // Up to 2^kMaxParams slices blended with weights, for one set of parameter values.
  struct Blend {
    int n = 1;
    int slice[1 << kMaxParams] = {0};
    double weight[1 << kMaxParams] = {1.0};
  };
  Blend Interpolate(const double* params) const;
  // Blended value of buf[slice * stride + index].
  static double Lookup(const std::vector<double>& buf, const Blend& b, size_t stride,
                       size_t index) {
    double v = 0;
    for (int i = 0; i < b.n; ++i) v += b.weight[i] * buf[b.slice[i] * stride + index];
    return v;
  }

  int width_ = 0, height_ = 0;
  size_t slice_size_ = 0;
  std::vector<std::vector<double>> param_values_;
  std::vector<size_t> param_strides_;    // in slices
  std::vector<double> data_;             // normalised when sampling
  std::vector<double> marginal_cdf_;     // [slice][height]
  std::vector<double> conditional_cdf_;  // [slice][height][width]
  bool sampling_ = false;
};

}  // namespace mesoscan
