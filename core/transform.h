#pragma once
// Eigen aliases and rigid transforms. Names follow COLMAP: `world_from_cam` takes camera
// coordinates to world coordinates; points are `point_in_world`, `point_in_cam`.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace mesoscan {

using Vec2d = Eigen::Vector2d;
using Vec3d = Eigen::Vector3d;
using Vec4d = Eigen::Vector4d;
using Vec2f = Eigen::Vector2f;
using Vec3f = Eigen::Vector3f;
using Mat3d = Eigen::Matrix3d;
using Mat4d = Eigen::Matrix4d;

// A rigid transform y = R x + t. Stored as rotation matrix + translation (no scale).
struct Rigid3d {
  Mat3d rotation = Mat3d::Identity();
  Vec3d translation = Vec3d::Zero();

  Vec3d operator*(const Vec3d& x) const { return rotation * x + translation; }
  Rigid3d operator*(const Rigid3d& o) const {
    return {rotation * o.rotation, rotation * o.translation + translation};
  }
  Rigid3d Inverse() const { return {rotation.transpose(), -(rotation.transpose() * translation)}; }
  Mat4d Matrix() const {
    Mat4d m = Mat4d::Identity();
    m.topLeftCorner<3, 3>() = rotation;
    m.topRightCorner<3, 1>() = translation;
    return m;
  }
  static Rigid3d FromMatrix(const Mat4d& m) {
    return {m.topLeftCorner<3, 3>(), m.topRightCorner<3, 1>()};
  }
  // A camera at `eye` looking at `target` with image-up roughly `up` (OpenCV axes: x right,
  // y down, z forward). Returns world_from_cam.
  static Rigid3d LookAt(const Vec3d& eye, const Vec3d& target, const Vec3d& up) {
    const Vec3d z = (target - eye).normalized();
    const Vec3d x = z.cross(up).normalized() * -1.0;  // right = forward x up, flipped for y-down
    const Vec3d y = z.cross(x);
    Rigid3d t;
    t.rotation.col(0) = x;
    t.rotation.col(1) = y;
    t.rotation.col(2) = z;
    t.translation = eye;
    return t;
  }
};

// True if m's top-left 3x3 is a rotation (orthonormal, det +1) within tol and the last row is
// [0 0 0 1].
bool IsRigid(const Mat4d& m, double tol = 1e-6);

}  // namespace mesoscan
