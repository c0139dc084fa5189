#include "core/camera.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <random>

namespace mesoscan {
namespace {

PinholeCamera TestCamera() {
  PinholeCamera cam;
  cam.width = 640;
  cam.height = 480;
  cam.K << 800, 0, 319.5, 0, 810, 239.5, 0, 0, 1;
  cam.distortion = {-0.21, 0.08, 0.0012, -0.0007, -0.015};
  return cam;
}

TEST(PinholeCamera, ProjectMatchesOpenCV) {
  const PinholeCamera cam = TestCamera();
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::vector<cv::Point3d> pts;
  for (int i = 0; i < 200; ++i) pts.emplace_back(u(rng), u(rng), 1.0 + 0.5 * std::abs(u(rng)));
  cv::Mat K(3, 3, CV_64F), d(1, 5, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) K.at<double>(r, c) = cam.K(r, c);
  for (int k = 0; k < 5; ++k) d.at<double>(k) = cam.distortion[k];
  std::vector<cv::Point2d> ref;
  cv::projectPoints(pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, d, ref);
  for (size_t i = 0; i < pts.size(); ++i) {
    double p[3] = {pts[i].x, pts[i].y, pts[i].z}, uv[2];
    ASSERT_TRUE(cam.ProjectDevice(p, uv));
    EXPECT_NEAR(uv[0], ref[i].x, 1e-9);
    EXPECT_NEAR(uv[1], ref[i].y, 1e-9);
  }
}

TEST(PinholeCamera, UndistortInvertsProjectAndAgreesWithOpenCV) {
  const PinholeCamera cam = TestCamera();
  cv::Mat K(3, 3, CV_64F), d(1, 5, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) K.at<double>(r, c) = cam.K(r, c);
  for (int k = 0; k < 5; ++k) d.at<double>(k) = cam.distortion[k];
  std::vector<cv::Point2d> px, ref;
  for (int y = 0; y < 480; y += 37)
    for (int x = 0; x < 640; x += 41) px.emplace_back(x, y);
  cv::undistortPoints(
      px, ref, K, d, cv::noArray(), cv::noArray(),
      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-14));
  for (size_t i = 0; i < px.size(); ++i) {
    const Vec2d n = cam.UndistortNormalized({px[i].x, px[i].y});
    // Round trip: exact to 1e-9 px.
    double p[3] = {n.x(), n.y(), 1.0}, uv[2];
    cam.ProjectDevice(p, uv);
    EXPECT_NEAR(uv[0], px[i].x, 1e-9);
    EXPECT_NEAR(uv[1], px[i].y, 1e-9);
    // OpenCV's fixed-point iteration agrees to its own convergence (~1e-6 normalised).
    EXPECT_NEAR(n.x(), ref[i].x, 1e-6);
    EXPECT_NEAR(n.y(), ref[i].y, 1e-6);
  }
}

TEST(Rigid3d, InverseAndRigidity) {
  Rigid3d t;
  t.rotation = Eigen::AngleAxisd(0.3, Vec3d(1, 2, 3).normalized()).toRotationMatrix();
  t.translation = Vec3d(0.1, -0.2, 0.3);
  const Vec3d p(1, 2, 3);
  EXPECT_LT(((t.Inverse() * (t * p)) - p).norm(), 1e-12);
  EXPECT_TRUE(IsRigid(t.Matrix()));
  Mat4d bad = t.Matrix();
  bad(0, 0) *= 2;
  EXPECT_FALSE(IsRigid(bad));
}

}  // namespace
}  // namespace mesoscan
