#pragma once
// OpenCV's ximgproc filters the denoiser uses, behind a module loaded on first use
// (core/module.h: libmesoscan_ximgproc.so, built from render/ximgproc_module.cc): ximgproc links
// OpenCV's imgcodecs and its ~140-library tree (GDAL, codecs), which every process would
// otherwise load at start. The functions are cv::ximgproc's, with its arguments.

#include <opencv2/core.hpp>

namespace mesoscan {

class XimgprocModule {
 public:
  virtual ~XimgprocModule() = default;
  virtual void GuidedFilter(const cv::Mat& guide, const cv::Mat& src, cv::Mat& dst, int radius,
                            double eps) const = 0;
  virtual void JointBilateralFilter(const cv::Mat& joint, const cv::Mat& src, cv::Mat& dst, int d,
                                    double sigma_color, double sigma_space) const = 0;
};

// The module, loaded on the first call. Throws Error(kInternal) if it cannot be loaded.
const XimgprocModule& Ximgproc();

}  // namespace mesoscan
