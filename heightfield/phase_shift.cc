#include "heightfield/phase_shift.h"

#include "core/error.h"

// Interim: the implementation lands in the next commit (headers first, so reconstruct can code
// against them).
namespace mesoscan {

WrappedPhaseSolver::WrappedPhaseSolver(std::vector<double> deltas) : deltas_(std::move(deltas)) {
  MESOSCAN_THROW(ErrorKind::kInternal, "WrappedPhaseSolver: not implemented yet");
}
WrappedPhaseSolver::Result WrappedPhaseSolver::Solve(const float*, int) const { return {}; }
double WrappedPhaseSolver::ThetaVarianceAt(double, double, double) const { return 0; }
double WrappedPhaseSolver::ThetaVariance(double, double) const { return 0; }

TemporalUnwrapper::TemporalUnwrapper(std::vector<double> periods, double range_px,
                                     double max_residual)
    : periods_(std::move(periods)), range_px_(range_px), max_residual_(max_residual) {
  MESOSCAN_THROW(ErrorKind::kInternal, "TemporalUnwrapper: not implemented yet");
}
UnwrapResult TemporalUnwrapper::Unwrap(const double*, const double*) const { return {}; }

}  // namespace mesoscan
