// libmesoscan_ximgproc.so (interface: render/ximgproc_module.h): cv::ximgproc's filters.

#include "render/ximgproc_module.h"

#include <opencv2/ximgproc.hpp>

namespace mesoscan {
namespace {

class Module final : public XimgprocModule {
 public:
  void GuidedFilter(const cv::Mat& guide, const cv::Mat& src, cv::Mat& dst, int radius,
                    double eps) const override {
    cv::ximgproc::guidedFilter(guide, src, dst, radius, eps);
  }
  void JointBilateralFilter(const cv::Mat& joint, const cv::Mat& src, cv::Mat& dst, int d,
                            double sigma_color, double sigma_space) const override {
    cv::ximgproc::jointBilateralFilter(joint, src, dst, d, sigma_color, sigma_space);
  }
};

}  // namespace
}  // namespace mesoscan

extern "C" __attribute__((visibility("default"))) const void* mesoscan_module_ximgproc() {
  static const mesoscan::Module module;
  return static_cast<const mesoscan::XimgprocModule*>(&module);
}
