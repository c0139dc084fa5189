#pragma once
// Planar image: channel c is a contiguous width*height block (structure of arrays, so per-channel
// loops vectorise). Row-major within a channel; pixel (x, y) has x = column, y = row.

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/error.h"

namespace mesoscan {

template <typename T>
class Image {
 public:
  Image() = default;
  Image(int width, int height, int channels = 1, T fill = T())
      : width_(width), height_(height), channels_(channels) {
    MESOSCAN_CHECK(width >= 0 && height >= 0 && channels >= 1);
    data_.assign(static_cast<size_t>(width) * height * channels, fill);
  }

  int width() const { return width_; }
  int height() const { return height_; }
  int channels() const { return channels_; }
  size_t pixels() const { return static_cast<size_t>(width_) * height_; }
  bool empty() const { return data_.empty(); }

  T& operator()(int x, int y, int c = 0) { return data_[Index(x, y, c)]; }
  const T& operator()(int x, int y, int c = 0) const { return data_[Index(x, y, c)]; }

  // Start of channel c (width*height contiguous values).
  T* channel(int c) { return data_.data() + static_cast<size_t>(c) * pixels(); }
  const T* channel(int c) const { return data_.data() + static_cast<size_t>(c) * pixels(); }
  T* row(int y, int c = 0) { return channel(c) + static_cast<size_t>(y) * width_; }
  const T* row(int y, int c = 0) const { return channel(c) + static_cast<size_t>(y) * width_; }

  std::vector<T>& data() { return data_; }
  const std::vector<T>& data() const { return data_; }
  void Fill(T v) { std::fill(data_.begin(), data_.end(), v); }

 private:
  size_t Index(int x, int y, int c) const {
    MESOSCAN_DCHECK(x >= 0 && x < width_ && y >= 0 && y < height_ && c >= 0 && c < channels_);
    return static_cast<size_t>(c) * pixels() + static_cast<size_t>(y) * width_ + x;
  }
  int width_ = 0, height_ = 0, channels_ = 0;
  std::vector<T> data_;
};

using ImageF = Image<float>;
using ImageD = Image<double>;
using ImageU8 = Image<uint8_t>;
using ImageU16 = Image<uint16_t>;

}  // namespace mesoscan
