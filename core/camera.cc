#include "core/camera.h"

namespace mesoscan {

bool IsRigid(const Mat4d& m, double tol) {
  if (!m.allFinite()) return false;
  const Mat3d r = m.topLeftCorner<3, 3>();
  if ((r * r.transpose() - Mat3d::Identity()).cwiseAbs().maxCoeff() > tol) return false;
  if (std::abs(r.determinant() - 1.0) > tol) return false;
  return std::abs(m(3, 0)) <= tol && std::abs(m(3, 1)) <= tol && std::abs(m(3, 2)) <= tol &&
         std::abs(m(3, 3) - 1.0) <= tol;
}

Vec2d PinholeCamera::UndistortNormalized(const Vec2d& uv) const {
  // Distorted normalised coordinates from the pixel (inverse of the affine K part).
  const double yd = (uv.y() - K(1, 2)) / K(1, 1);
  const double xd = (uv.x() - K(0, 2) - K(0, 1) * yd) / K(0, 0);
  if (!HasDistortion()) return {xd, yd};
  Vec2d x(xd, yd);
  for (int it = 0; it < 20; ++it) {
    double fx, fy;
    Distort(distortion.data(), x.x(), x.y(), &fx, &fy);
    const Vec2d r(fx - xd, fy - yd);
    if (r.squaredNorm() < 1e-30) break;
    // Jacobian by central differences: the model is smooth and cheap.
    constexpr double h = 1e-7;
    double ax, ay, bx, by;
    Distort(distortion.data(), x.x() + h, x.y(), &ax, &ay);
    Distort(distortion.data(), x.x() - h, x.y(), &bx, &by);
    Eigen::Matrix2d J;
    J(0, 0) = (ax - bx) / (2 * h);
    J(1, 0) = (ay - by) / (2 * h);
    Distort(distortion.data(), x.x(), x.y() + h, &ax, &ay);
    Distort(distortion.data(), x.x(), x.y() - h, &bx, &by);
    J(0, 1) = (ax - bx) / (2 * h);
    J(1, 1) = (ay - by) / (2 * h);
    const Vec2d step = J.partialPivLu().solve(r);
    if (!step.allFinite()) break;
    x -= step;
  }
  return x;
}

}  // namespace mesoscan
