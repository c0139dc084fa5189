#include "heightfield/lens_shift_fit.h"

#include "core/error.h"

// Interim: the implementation lands in the next commit (headers first, so reconstruct can code
// against them).
namespace mesoscan {

const char* LensShiftFitterName(LensShiftFitter fitter) {
  switch (fitter) {
    case LensShiftFitter::kFast: return "fast";
    case LensShiftFitter::kLm: return "lm";
    case LensShiftFitter::kCeres: return "ceres";
  }
  return "?";
}
LensShiftFitter ParseLensShiftFitter(const std::string& name, const std::string& what) {
  if (name == "fast") return LensShiftFitter::kFast;
  if (name == "lm") return LensShiftFitter::kLm;
  if (name == "ceres") return LensShiftFitter::kCeres;
  MESOSCAN_BAD_INPUT(what << ": unknown fitter '" << name << "' (expected fast, lm or ceres)");
}
void LensShiftFitOptions::Check() const {}
struct LensShiftBatchFitter::Tables {};
LensShiftFit FitLensShiftProfile(const float*, const double*, int, double,
                                 const LensShiftFitOptions&, int) {
  MESOSCAN_THROW(ErrorKind::kInternal, "FitLensShiftProfile: not implemented yet");
}
LensShiftBatchFitter::LensShiftBatchFitter(std::vector<double> x, double f0,
                                           const LensShiftFitOptions& options)
    : x_(std::move(x)), f0_(f0), options_(options) {
  MESOSCAN_THROW(ErrorKind::kInternal, "LensShiftBatchFitter: not implemented yet");
}
LensShiftFit LensShiftBatchFitter::Fit(const float*, int) const { return {}; }
LensShiftFit LensShiftBatchFitter::Fit(const float*, int, double) const { return {}; }
int LensShiftBatchFitter::num_samples() const { return static_cast<int>(x_.size()); }
const std::vector<double>& LensShiftBatchFitter::positions() const { return x_; }
double LensShiftBatchFitter::nominal_frequency() const { return f0_; }
const LensShiftFitOptions& LensShiftBatchFitter::options() const { return options_; }
double LensShiftPhaseCrlbAt(double, double, const std::vector<double>&, double, double, bool) {
  return 0;
}
double LensShiftPhaseCrlb(double, double, const std::vector<double>&, double, bool) { return 0; }

}  // namespace mesoscan
