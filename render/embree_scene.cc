#include "render/embree_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>

#include "core/error.h"
#include "core/log.h"

namespace mesoscan {

std::string EmbreeVersion() { return RTC_VERSION_STRING; }

// The Embree device: created once per process (while any scene lives), with its error callback
// registered once. Embree errors inside a query are bugs; at build time they are reported as
// internal errors by the callers' checks.
class EmbreeDevice {
 public:
  EmbreeDevice() {
    device_ = rtcNewDevice(nullptr);
    if (!device_)
      MESOSCAN_THROW(ErrorKind::kInternal,
                     "embree: cannot create device (error " << rtcGetDeviceError(nullptr) << ")");
    rtcSetDeviceErrorFunction(device_, &EmbreeDevice::OnError, nullptr);
  }
  ~EmbreeDevice() { rtcReleaseDevice(device_); }
  RTCDevice get() const { return device_; }

  static std::shared_ptr<EmbreeDevice> Shared() {
    static std::mutex mutex;
    static std::weak_ptr<EmbreeDevice> weak;
    std::lock_guard<std::mutex> lock(mutex);
    std::shared_ptr<EmbreeDevice> device = weak.lock();
    if (!device) {
      device = std::make_shared<EmbreeDevice>();
      weak = device;
    }
    return device;
  }

 private:
  static void OnError(void*, RTCError code, const char* message) {
    MESOSCAN_LOG(kError) << "embree error " << static_cast<int>(code) << ": "
                         << (message ? message : "");
  }
  RTCDevice device_ = nullptr;
};

namespace {

constexpr int kTileCells = 64;  // grid primitives cover at most 64 x 64 cells

struct Geometry {
  enum class Kind { kHeightField, kPlane } kind = Kind::kPlane;
  HeightField hf;      // kHeightField
  double plane_z = 0;  // kPlane
};

// Bilinear patch of cell (i, j): z = c0 + c1 a + c2 b + c3 a b with a along +i, b along +j.
struct Patch {
  double c0 = 0, c1 = 0, c2 = 0, c3 = 0;
};

bool CellPatch(const HeightField& hf, int i, int j, Patch* p) {
  if (i < 0 || j < 0 || i + 1 >= hf.width() || j + 1 >= hf.height()) return false;
  const double z00 = hf.z(i, j), z10 = hf.z(i + 1, j), z01 = hf.z(i, j + 1),
               z11 = hf.z(i + 1, j + 1);
  if (!std::isfinite(z00) || !std::isfinite(z10) || !std::isfinite(z01) || !std::isfinite(z11))
    return false;
  *p = {z00, z10 - z00, z01 - z00, z00 - z10 - z01 + z11};
  return true;
}

// Largest |c3| / 4 over the 3 x 3 cells around (i, j): the most the two-triangle surface
// Embree traverses can deviate vertically from the bilinear surface there.
double LocalTriangleDeviation(const HeightField& hf, int i, int j) {
  double m = 0.0;
  for (int dj = -1; dj <= 1; ++dj)
    for (int di = -1; di <= 1; ++di) {
      Patch p;
      if (CellPatch(hf, i + di, j + dj, &p)) m = std::max(m, std::abs(p.c3) * 0.25);
    }
  return m;
}

// Smallest root t of the ray/bilinear-patch equation in cell (i, j) within [t_lo, t_hi],
// parameterised around t_ref for precision. Returns NaN if none.
double IntersectCell(const HeightField& hf, int i, int j, const Vec3d& o, const Vec3d& d,
                     double t_ref, double t_lo, double t_hi) {
  Patch p;
  if (!CellPatch(hf, i, j, &p)) return std::numeric_limits<double>::quiet_NaN();
  const Vec3d c = o + t_ref * d;
  const double h = hf.pixel_size;
  const double ac = hf.I(c.x()) - i, bc = hf.J(c.y()) - j;
  const double ka = d.x() / h, kb = -d.y() / h;
  const double A = p.c3 * ka * kb;
  const double B = p.c1 * ka + p.c2 * kb + p.c3 * (ac * kb + bc * ka) - d.z();
  const double C = p.c0 + p.c1 * ac + p.c2 * bc + p.c3 * ac * bc - c.z();
  double roots[2];
  int n = 0;
  if (std::abs(A) <= 1e-14 * std::abs(B)) {
    if (B != 0.0) roots[n++] = -C / B;
  } else {
    const double disc = B * B - 4 * A * C;
    if (disc >= 0) {
      const double q = -0.5 * (B + std::copysign(std::sqrt(disc), B));
      roots[n++] = q / A;
      if (q != 0.0) roots[n++] = C / q;
    }
  }
  double best = std::numeric_limits<double>::quiet_NaN();
  constexpr double kEps = 1e-9;  // cells: a root on the shared edge belongs to both cells
  for (int k = 0; k < n; ++k) {
    const double s = roots[k];
    const double t = t_ref + s;
    if (!(t >= t_lo && t <= t_hi)) continue;
    const double a = ac + s * ka, b = bc + s * kb;
    if (a < -kEps || a > 1 + kEps || b < -kEps || b > 1 + kEps) continue;
    if (!(t >= best)) best = t;  // also takes the first finite root
  }
  return best;
}

Vec3d PatchNormal(const HeightField& hf, int i, int j, double a, double b) {
  Patch p{0, 0, 0, 0};
  CellPatch(hf, i, j, &p);
  a = std::clamp(a, 0.0, 1.0);
  b = std::clamp(b, 0.0, 1.0);
  const double dz_da = p.c1 + p.c3 * b, dz_db = p.c2 + p.c3 * a;
  // x = x0 + (i + a) h, y = y0 - (j + b) h.
  const double dz_dx = dz_da / hf.pixel_size, dz_dy = -dz_db / hf.pixel_size;
  return Vec3d(-dz_dx, -dz_dy, 1.0).normalized();
}

}  // namespace

struct EmbreeScene::Impl {
  std::shared_ptr<EmbreeDevice> device;
  RTCScene scene = nullptr;
  std::vector<Geometry> geometries;  // index = Embree geometry id
  bool committed = false;
  mutable std::atomic<int64_t> unrefined{0};

  // Refines a float hit on height field `g` in double. Returns false if no bilinear root lies
  // near the float hit.
  bool RefineHeightField(const HeightField& hf, const Vec3d& o, const Vec3d& d, double t_float,
                         double t_near, double t_far, RayHit* hit) const {
    const Vec3d pf = o + t_float * d;
    const int ic = static_cast<int>(std::floor(hf.I(pf.x())));
    const int jc = static_cast<int>(std::floor(hf.J(pf.y())));
    // Window in t: the float error plus the triangle/bilinear deviation, along z.
    const double dev = LocalTriangleDeviation(hf, ic, jc);
    const double window = (2e-6 + 1e-6 * std::abs(t_float) + dev) / std::max(std::abs(d.z()), 0.05);
    const double t_lo = std::max(t_near, t_float - window),
                 t_hi = std::min(t_far, t_float + window);
    const Vec3d p0 = o + t_lo * d, p1 = o + t_hi * d;
    const int i0 = static_cast<int>(std::floor(std::min(hf.I(p0.x()), hf.I(p1.x())))) - 1;
    const int i1 = static_cast<int>(std::floor(std::max(hf.I(p0.x()), hf.I(p1.x())))) + 1;
    const int j0 = static_cast<int>(std::floor(std::min(hf.J(p0.y()), hf.J(p1.y())))) - 1;
    const int j1 = static_cast<int>(std::floor(std::max(hf.J(p0.y()), hf.J(p1.y())))) + 1;
    if (static_cast<int64_t>(i1 - i0 + 1) * (j1 - j0 + 1) > 1024) return false;
    double best_t = std::numeric_limits<double>::quiet_NaN();
    int best_i = 0, best_j = 0;
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const double t = IntersectCell(hf, i, j, o, d, t_float, t_lo, t_hi);
        if (std::isfinite(t) && !(t >= best_t)) {
          best_t = t;
          best_i = i;
          best_j = j;
        }
      }
    if (!std::isfinite(best_t)) return false;
    hit->t = best_t;
    hit->point = o + best_t * d;
    hit->normal = PatchNormal(hf, best_i, best_j, hf.I(hit->point.x()) - best_i,
                              hf.J(hit->point.y()) - best_j);
    hit->shadow_lift = LocalTriangleDeviation(hf, best_i, best_j);
    hit->refined = true;
    return true;
  }
};

EmbreeScene::EmbreeScene() : impl_(std::make_unique<Impl>()) {
  impl_->device = EmbreeDevice::Shared();
  impl_->scene = rtcNewScene(impl_->device->get());
  MESOSCAN_CHECK(impl_->scene != nullptr);
  // Robust traversal: no rays slip through the shared edges of neighbouring cells.
  rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_HIGH);
}

EmbreeScene::~EmbreeScene() {
  if (impl_->scene) rtcReleaseScene(impl_->scene);
}

int EmbreeScene::AddHeightField(const HeightField& hf) {
  MESOSCAN_CHECK(!impl_->committed);
  MESOSCAN_CHECK(hf.width() >= 2 && hf.height() >= 2 && hf.pixel_size > 0);
  const int w = hf.width(), h = hf.height();
  auto valid_cell = [&](int i, int j) {
    return std::isfinite(hf.z(i, j)) && std::isfinite(hf.z(i + 1, j)) &&
           std::isfinite(hf.z(i, j + 1)) && std::isfinite(hf.z(i + 1, j + 1));
  };
  // Grid primitives: a full 64 x 64 cell tile where every cell is valid, else one primitive per
  // run of valid cells in each row of the tile (holes are left out).
  std::vector<RTCGrid> grids;
  for (int tj = 0; tj < h - 1; tj += kTileCells)
    for (int ti = 0; ti < w - 1; ti += kTileCells) {
      const int ni = std::min(kTileCells, w - 1 - ti), nj = std::min(kTileCells, h - 1 - tj);
      bool all = true;
      for (int j = tj; j < tj + nj && all; ++j)
        for (int i = ti; i < ti + ni && all; ++i) all = valid_cell(i, j);
      if (all) {
        grids.push_back({static_cast<unsigned>(tj * w + ti), static_cast<unsigned>(w),
                         static_cast<unsigned short>(ni + 1), static_cast<unsigned short>(nj + 1)});
        continue;
      }
      for (int j = tj; j < tj + nj; ++j) {
        int i = ti;
        while (i < ti + ni) {
          if (!valid_cell(i, j)) {
            ++i;
            continue;
          }
          int e = i;
          while (e < ti + ni && valid_cell(e, j)) ++e;
          grids.push_back({static_cast<unsigned>(j * w + i), static_cast<unsigned>(w),
                           static_cast<unsigned short>(e - i + 1), 2});
          i = e;
        }
      }
    }
  Geometry geo;
  geo.kind = Geometry::Kind::kHeightField;
  geo.hf = hf;
  if (grids.empty()) MESOSCAN_BAD_INPUT("height field: no cell with four finite corners");
  RTCGeometry g = rtcNewGeometry(impl_->device->get(), RTC_GEOMETRY_TYPE_GRID);
  float* v =
      static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                  3 * sizeof(float), static_cast<size_t>(w) * h));
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      float* p = v + 3 * (static_cast<size_t>(j) * w + i);
      const float z = hf.z(i, j);
      p[0] = static_cast<float>(hf.X(i));
      p[1] = static_cast<float>(hf.Y(j));
      p[2] = std::isfinite(z) ? z : 0.0f;  // never referenced by a grid primitive
    }
  RTCGrid* gb = static_cast<RTCGrid*>(rtcSetNewGeometryBuffer(
      g, RTC_BUFFER_TYPE_GRID, 0, RTC_FORMAT_GRID, sizeof(RTCGrid), grids.size()));
  std::copy(grids.begin(), grids.end(), gb);
  rtcSetGeometryMask(g, kMaskHeightFields);
  rtcCommitGeometry(g);
  const unsigned id = rtcAttachGeometry(impl_->scene, g);
  rtcReleaseGeometry(g);
  MESOSCAN_CHECK_EQ(static_cast<size_t>(id), impl_->geometries.size());
  impl_->geometries.push_back(std::move(geo));
  return static_cast<int>(id);
}

int EmbreeScene::AddPlane(double z_m, double half_size_m) {
  MESOSCAN_CHECK(!impl_->committed);
  RTCGeometry g = rtcNewGeometry(impl_->device->get(), RTC_GEOMETRY_TYPE_QUAD);
  float* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0,
                                                         RTC_FORMAT_FLOAT3, 3 * sizeof(float), 4));
  const float s = static_cast<float>(half_size_m), z = static_cast<float>(z_m);
  const float corners[4][3] = {{-s, -s, z}, {s, -s, z}, {s, s, z}, {-s, s, z}};
  for (int k = 0; k < 4; ++k) std::copy(corners[k], corners[k] + 3, v + 3 * k);
  unsigned* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
      g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4, 4 * sizeof(unsigned), 1));
  for (unsigned k = 0; k < 4; ++k) idx[k] = k;
  rtcSetGeometryMask(g, kMaskPlanes);
  rtcCommitGeometry(g);
  const unsigned id = rtcAttachGeometry(impl_->scene, g);
  rtcReleaseGeometry(g);
  MESOSCAN_CHECK_EQ(static_cast<size_t>(id), impl_->geometries.size());
  Geometry geo;
  geo.kind = Geometry::Kind::kPlane;
  geo.plane_z = z_m;
  impl_->geometries.push_back(std::move(geo));
  return static_cast<int>(id);
}

void EmbreeScene::Commit() {
  rtcCommitScene(impl_->scene);
  const RTCError err = rtcGetDeviceError(impl_->device->get());
  if (err != RTC_ERROR_NONE)
    MESOSCAN_THROW(ErrorKind::kInternal, "embree: scene build failed (error " << err << ")");
  impl_->committed = true;
}

std::optional<RayHit> EmbreeScene::Intersect(const Vec3d& origin, const Vec3d& direction,
                                             double t_near, double t_far, unsigned mask) const {
  MESOSCAN_DCHECK(impl_->committed);
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  RTCRayHit rh;
  rh.ray.org_x = static_cast<float>(origin.x());
  rh.ray.org_y = static_cast<float>(origin.y());
  rh.ray.org_z = static_cast<float>(origin.z());
  rh.ray.dir_x = static_cast<float>(direction.x());
  rh.ray.dir_y = static_cast<float>(direction.y());
  rh.ray.dir_z = static_cast<float>(direction.z());
  // Widen the float interval slightly; the double refinement enforces [t_near, t_far].
  rh.ray.tnear = static_cast<float>(std::max(0.0, t_near - 1e-6));
  rh.ray.tfar = static_cast<float>(std::min(t_far + 1e-6, 1e30));
  rh.ray.time = 0.0f;
  rh.ray.mask = mask;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &context, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  const Geometry& geo = impl_->geometries[rh.hit.geomID];
  RayHit hit;
  hit.geometry = static_cast<int>(rh.hit.geomID);
  if (geo.kind == Geometry::Kind::kPlane) {
    if (direction.z() == 0.0) return std::nullopt;
    hit.t = (geo.plane_z - origin.z()) / direction.z();
    if (!(hit.t >= t_near && hit.t <= t_far)) return std::nullopt;
    hit.point = origin + hit.t * direction;
    hit.point.z() = geo.plane_z;
    hit.normal = Vec3d(0, 0, 1);
    return hit;
  }
  if (impl_->RefineHeightField(geo.hf, origin, direction, rh.ray.tfar, t_near, t_far, &hit))
    return hit;
  // Refinement failed (grazing ray at a steep cell edge): keep Embree's triangle hit.
  ++impl_->unrefined;
  hit.t = rh.ray.tfar;
  if (!(hit.t >= t_near && hit.t <= t_far)) return std::nullopt;
  hit.point = origin + hit.t * direction;
  hit.normal = Vec3d(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z).normalized();
  if (hit.normal.z() < 0) hit.normal = -hit.normal;
  const HeightField& hf = geo.hf;
  hit.shadow_lift = LocalTriangleDeviation(hf, static_cast<int>(std::floor(hf.I(hit.point.x()))),
                                           static_cast<int>(std::floor(hf.J(hit.point.y()))));
  hit.refined = false;
  return hit;
}

bool EmbreeScene::Occluded(const Vec3d& origin, const Vec3d& direction, double t_near,
                           double t_far) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray;
  ray.org_x = static_cast<float>(origin.x());
  ray.org_y = static_cast<float>(origin.y());
  ray.org_z = static_cast<float>(origin.z());
  ray.dir_x = static_cast<float>(direction.x());
  ray.dir_y = static_cast<float>(direction.y());
  ray.dir_z = static_cast<float>(direction.z());
  ray.tnear = static_cast<float>(t_near);
  ray.tfar = static_cast<float>(std::min(t_far, 1e30));
  ray.time = 0.0f;
  ray.mask = 0xFFFFFFFFu;
  ray.id = 0;
  ray.flags = 0;
  rtcOccluded1(impl_->scene, &context, &ray);
  return ray.tfar < 0.0f;  // Embree sets tfar = -inf on a hit
}

int64_t EmbreeScene::unrefined_hits() const { return impl_->unrefined.load(); }

}  // namespace mesoscan
