#include "compare/stitch.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <OpenEXR/ImfTiledOutputFile.h>
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

#include "compare/planar_alignment.h"
#include "compare/registration_module.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/stage_timer.h"
#include "maps/export.h"

namespace mesoscan {
namespace fs = std::filesystem;
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;
// A pair is kept when at least this fraction of B's points that the fit places over A fit A
// (within 3 robust sigmas): a changed area may take the rest, a wrong match leaves far fewer.
constexpr double kMinInlierFraction = 0.5;

struct Box {
  double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
  void Add(double x, double y) {
    x0 = std::min(x0, x), y0 = std::min(y0, y), x1 = std::max(x1, x), y1 = std::max(y1, y);
  }
  double Area() const { return x1 > x0 && y1 > y0 ? (x1 - x0) * (y1 - y0) : 0.0; }
  Box Intersect(const Box& o) const {
    Box b;
    b.x0 = std::max(x0, o.x0), b.y0 = std::max(y0, o.y0);
    b.x1 = std::min(x1, o.x1), b.y1 = std::min(y1, o.y1);
    return b;
  }
  bool Contains(double x, double y, double m) const {
    return x >= x0 - m && x <= x1 + m && y >= y0 - m && y <= y1 + m;
  }
};

// The footprint of a scan's grid moved by t (x, y of its corners).
Box Footprint(const HeightField& hf, const Mat4d& t) {
  Box b;
  for (int c = 0; c < 4; ++c) {
    const Vec4d p = t * Vec4d(hf.X((c & 1) ? hf.width() - 1 : 0),
                              hf.Y((c & 2) ? hf.height() - 1 : 0), 0.0, 1.0);
    b.Add(p.x(), p.y());
  }
  return b;
}

Mat4d Translation(const Vec2d& o) {
  Mat4d t = Mat4d::Identity();
  t(0, 3) = o.x();
  t(1, 3) = o.y();
  return t;
}

// Confident points of `scan` whose image under t lies in `box` (with margin), in t's frame.
void Cloud(const Scan& s, const ImageF& normals, const Mat4d& t, const Box& box, double margin,
           double min_conf, int max_points, std::vector<Vec3d>* pts, std::vector<Vec3d>* nrm) {
  const HeightField& hf = s.height;
  const Mat3d R = t.topLeftCorner<3, 3>();
  const Vec3d tr = t.topRightCorner<3, 1>();
  std::vector<Vec3d> p, n;
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      const float z = hf.z(i, j);
      if (!std::isfinite(z)) continue;
      if (!hf.confidence.empty() && !(hf.confidence(i, j) >= min_conf)) continue;
      const Vec3d nn(normals(i, j, 0), normals(i, j, 1), normals(i, j, 2));
      if (!nn.allFinite()) continue;
      const Vec3d q = R * Vec3d(hf.X(i), hf.Y(j), z) + tr;
      if (!box.Contains(q.x(), q.y(), margin)) continue;
      p.push_back(q);
      n.push_back((R * nn).normalized());
    }
  const size_t stride = std::max<size_t>(1, (p.size() + max_points - 1) / max_points);
  for (size_t k = 0; k < p.size(); k += stride) {
    pts->push_back(p[k]);
    nrm->push_back(n[k]);
  }
}

// One pose-graph edge: the measured b_to_a (B's world to A's) against the poses of A and B
// (mosaic_from_scan as angle-axis + translation); residual L^T delta with the fit's
// information L L^T, delta the correction (rotation vector, translation) applied in A's frame.
struct EdgeCost {
  Mat3d r_ab;
  Vec3d t_ab;
  Eigen::Matrix<double, 6, 6> lt;  // L^T
  template <typename T>
  bool operator()(const T* a, const T* b, T* res) const {
    using M3 = Eigen::Matrix<T, 3, 3>;
    using V3 = Eigen::Matrix<T, 3, 1>;
    M3 ra, rb;
    ceres::AngleAxisToRotationMatrix(a, ra.data());
    ceres::AngleAxisToRotationMatrix(b, rb.data());
    const V3 ta(a[3], a[4], a[5]), tb(b[3], b[4], b[5]);
    // M = X_a^-1 X_b T_ab^-1
    const M3 rab_t = r_ab.transpose().cast<T>();
    const V3 tab_inv = -(rab_t * t_ab.cast<T>());
    const M3 rm = ra.transpose() * rb * rab_t;
    const V3 tm = ra.transpose() * (rb * tab_inv + tb - ta);
    T aa[3];
    ceres::RotationMatrixToAngleAxis(rm.data(), aa);
    Eigen::Matrix<T, 6, 1> d;
    d << aa[0], aa[1], aa[2], tm(0), tm(1), tm(2);
    Eigen::Map<Eigen::Matrix<T, 6, 1>> out(res);
    out = lt.cast<T>() * d;
    return true;
  }
};

double SmoothStep01(double t) {
  t = std::clamp(t, 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

// One EXR tiled 64 x 64 with MIP levels (NaN-aware box filter: a coarser pixel is the mean of
// the finite ones below it) through OpenEXR.
void WriteTiledExr(const fs::path& path,
                   const std::vector<std::pair<std::string, const float*>>& ch, int w, int h,
                   const std::map<std::string, double>& attrs) {
  Imf::Header header(w, h);
  for (const auto& [name, ptr] : ch) header.channels().insert(name, Imf::Channel(Imf::FLOAT));
  header.setTileDescription(Imf::TileDescription(64, 64, Imf::MIPMAP_LEVELS, Imf::ROUND_DOWN));
  header.compression() = Imf::ZIP_COMPRESSION;
  for (const auto& [k, v] : attrs) header.insert(k, Imf::FloatAttribute(static_cast<float>(v)));
  const std::string tmp = path.string() + ".tmp";
  {
    Imf::TiledOutputFile out(tmp.c_str(), header, Imf::globalThreadCount());
    std::vector<std::vector<float>> level(ch.size());
    for (size_t c = 0; c < ch.size(); ++c)
      level[c].assign(ch[c].second, ch[c].second + size_t(w) * h);
    int lw = w, lh = h;
    for (int l = 0; l < out.numLevels(); ++l) {
      if (l > 0) {  // the next level from this one
        const int nw = std::max(1, lw / 2), nh = std::max(1, lh / 2);
        for (auto& v : level) {
          std::vector<float> nv(size_t(nw) * nh, kNaN);
          for (int y = 0; y < nh; ++y)
            for (int x = 0; x < nw; ++x) {
              double s = 0;
              int n = 0;
              for (int dy = 0; dy < 2; ++dy)
                for (int dx = 0; dx < 2; ++dx) {
                  const int xx = std::min(lw - 1, 2 * x + dx), yy = std::min(lh - 1, 2 * y + dy);
                  const float f = v[size_t(yy) * lw + xx];
                  if (std::isfinite(f)) s += f, ++n;
                }
              if (n) nv[size_t(y) * nw + x] = static_cast<float>(s / n);
            }
          v = std::move(nv);
        }
        lw = nw, lh = nh;
      }
      Imf::FrameBuffer fb;
      for (size_t c = 0; c < ch.size(); ++c)
        fb.insert(ch[c].first, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(level[c].data()),
                                          sizeof(float), sizeof(float) * lw));
      out.setFrameBuffer(fb);
      out.writeTiles(0, out.numXTiles(l) - 1, 0, out.numYTiles(l) - 1, l);
    }
  }
  fs::rename(tmp, path);
}

}  // namespace

void StitchOptions::Check() const {
  if (!(feather > 0 && feather <= 0.5))
    MESOSCAN_BAD_OPTION("StitchOptions.feather", "expected a fraction in (0, 0.5]");
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_OPTION("StitchOptions.min_confidence", "expected a value in [0, 1)");
  if (!(max_correction_deg > 0 && max_correction_deg <= 180))
    MESOSCAN_BAD_OPTION("StitchOptions.max_correction_deg", "expected (0, 180] degrees");
  if (!(max_correction_fraction > 0 && max_correction_fraction <= 1))
    MESOSCAN_BAD_OPTION("StitchOptions.max_correction_fraction", "expected (0, 1]");
  if (!(min_overlap > 0 && min_overlap < 1))
    MESOSCAN_BAD_OPTION("StitchOptions.min_overlap", "expected a fraction in (0, 1)");
  if (max_icp_points < 1000)
    MESOSCAN_BAD_OPTION("StitchOptions.max_icp_points", "expected >= 1000");
  for (const Vec2d& o : offsets_m)
    if (!(o.allFinite() && o.cwiseAbs().maxCoeff() < 10.0))
      MESOSCAN_BAD_OPTION("StitchOptions.offsets_m", "expected finite offsets under 10 m");
}

std::string StitchResult::BriefReport() const {
  std::ostringstream os;
  const Json& r = scan.report;
  int accepted = 0;
  for (const Json& p : r.at("stitch").at("pairs")) accepted += p.at("accepted").get<bool>();
  os << std::fixed << std::setprecision(2) << "stitched " << mosaic_from_scan.size()
     << " scans into " << scan.height.width() << "x" << scan.height.height() << " pixels ("
     << r.at("grid").at("width_mm").get<double>() << " x "
     << r.at("grid").at("height_mm").get<double>() << " mm), " << accepted << " of "
     << r.at("stitch").at("pairs").size() << " pairs registered";
  if (r.at("stitch").contains("edge_rms_um"))
    os << ", pose-graph edge RMS " << r.at("stitch").at("edge_rms_um").get<double>() << " um";
  os << " in " << r.at("timings_s").at("total").get<double>() << " s";
  return os.str();
}

StitchResult StitchScans(const std::vector<Scan>& scans, const std::vector<std::string>& names,
                         const StitchOptions& o) {
  o.Check();
  const Stopwatch total;
  const size_t n = scans.size();
  if (n < 2) MESOSCAN_THROW(ErrorKind::kUsage, "stitch: expected at least 2 scans, got " << n);
  if (!o.offsets_m.empty() && o.offsets_m.size() != n)
    MESOSCAN_BAD_OPTION("StitchOptions.offsets_m",
                        "expected one offset per scan (" << n << "), got " << o.offsets_m.size());
  std::vector<ImageF> normals(n);
  std::vector<Mat4d> nominal(n);
  for (size_t k = 0; k < n; ++k) {
    normals[k] = scans[k].normals.empty() ? scans[k].height.Normals() : scans[k].normals;
    nominal[k] = Translation(o.offsets_m.empty() ? Vec2d::Zero() : o.offsets_m[k]);
    int valid = 0;
    for (float z : scans[k].height.z.data()) valid += std::isfinite(z);
    if (valid < 500)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(fs::path(names[k]) / "height.exr"),
                            "only " << valid << " valid height samples, expected >= 500");
  }
  const double px = scans[0].height.pixel_size;
  Json timings, pairs = Json::array();

  // ---- pairwise registration on the nominal overlaps ----
  struct Edge {
    int a, b;
    Mat4d b_to_a;  // B's world to A's
    Eigen::Matrix<double, 6, 6> info;
  };
  std::vector<Edge> edges;
  std::vector<Mat4d> poses = nominal;
  std::vector<int> degree(n, 0);
  std::vector<double> edge_rms;
  std::vector<size_t> edge_pair;
  const Stopwatch t_pairs;
  if (o.register_scans) {
    std::vector<std::pair<int, int>> candidates;
    for (size_t a = 0; a < n; ++a)
      for (size_t b = a + 1; b < n; ++b) {
        const Box fa = Footprint(scans[a].height, nominal[a]);
        const Box fb = Footprint(scans[b].height, nominal[b]);
        if (fa.Intersect(fb).Area() >= o.min_overlap * std::min(fa.Area(), fb.Area()))
          candidates.emplace_back(static_cast<int>(a), static_cast<int>(b));
      }
    Progress progress("stitch: register pairs", static_cast<int64_t>(candidates.size()));
    for (const auto& [a, b] : candidates) {
      const Mat4d guess = nominal[a].inverse() * nominal[b];  // B's world -> A's, nominal
      // The nominal overlap in A's world. B's points there register against A's points within
      // the plausible re-placement around it (every point of B that truly lies over A finds its
      // partner); the plausible re-placement bounds the correction.
      const HeightField& ha = scans[a].height;
      const HeightField& hb = scans[b].height;
      const Box fa = Footprint(ha, Mat4d::Identity());
      const Box box = fa.Intersect(Footprint(hb, guess));
      const double side = o.max_correction_fraction * std::min(hb.width(), hb.height()) * px;
      const double margin = side + 2 * px;
      RegistrationInput in;
      Cloud(scans[a], normals[a], Mat4d::Identity(), box, margin, o.min_confidence,
            o.max_icp_points, &in.a_points, &in.a_normals);
      Cloud(scans[b], normals[b], guess, box, 0.0, o.min_confidence, o.max_icp_points, &in.b_points,
            &in.b_normals);
      Json pj = {
          {"a", a}, {"b", b}, {"points_a", in.a_points.size()}, {"points_b", in.b_points.size()}};
      progress.Advance();
      if (in.a_points.size() < 500 || in.b_points.size() < 500) {
        pj["accepted"] = false;
        pj["why"] = "fewer than 500 confident points in the overlap";
        pairs.push_back(pj);
        continue;
      }
      // Coarse starts: phase correlation of the two overlaps' relief over rotations about z
      // (compare/planar_alignment.h), the placements within the plausible rotation.
      const Stopwatch t_planar;
      {
        ImageU8 in_a(ha.width(), ha.height(), 1, 0), in_b(hb.width(), hb.height(), 1, 0);
        for (int j = 0; j < ha.height(); ++j)
          for (int i = 0; i < ha.width(); ++i)
            in_a(i, j) = box.Contains(ha.X(i), ha.Y(j), margin) ? 1 : 0;
        for (int j = 0; j < hb.height(); ++j)
          for (int i = 0; i < hb.width(); ++i) {
            const Vec4d q = guess * Vec4d(hb.X(i), hb.Y(j), 0, 1);
            in_b(i, j) = box.Contains(q.x(), q.y(), 0.0) ? 1 : 0;
          }
        PlanarAlignmentOptions po;
        po.size = 128;
        po.candidates = 5;
        for (const PlanarCandidate& c : PlanarAlignment(ha, in_a, hb, in_b, po)) {
          const Mat4d st = c.b_to_a * guess.inverse();
          if (Eigen::AngleAxisd(Mat3d(st.topLeftCorner<3, 3>())).angle() * 180.0 / kPi <=
              o.max_correction_deg)
            in.starts.push_back(st);
        }
        pj["planar_starts"] = in.starts.size();
        // And rotations about z within the plausible ones, about the centre of B's overlap
        // (a strip's relief may correlate poorly; each start costs one ICP refinement).
        Vec3d cb = Vec3d::Zero();
        for (const Vec3d& p : in.b_points) cb += p;
        cb /= static_cast<double>(in.b_points.size());
        const double step = std::max(1.0, o.max_correction_deg / 4);
        for (double deg = -o.max_correction_deg; deg <= o.max_correction_deg + 1e-9; deg += step) {
          Mat4d st = Mat4d::Identity();
          st.topLeftCorner<3, 3>() = Eigen::AngleAxisd(deg * kPi / 180, Vec3d::UnitZ()).matrix();
          st.topRightCorner<3, 1>() = cb - st.topLeftCorner<3, 3>() * cb;
          in.starts.push_back(st);
        }
      }
      const double planar_s = t_planar.Seconds();
      const double area = std::max(box.Area(), px * px);
      in.voxel_m = std::max(4 * px, std::sqrt(area / 8000.0));
      in.max_distance_m = 2 * px;
      in.seed = 1;
      in.max_rotation_deg = o.max_correction_deg;
      in.fine_iterations = 300;
      const RegistrationOutput reg = Registration().Register(in);
      const double sigma2 = reg.inliers > 6 ? reg.sum_squares / (reg.inliers - 6) : 0.0;
      const Mat4d t = reg.b_to_a * guess;
      const Mat4d corr = reg.b_to_a;
      // B's points that the fit places over A (or within the correspondence distance of its
      // border): the overlap the inlier fraction is taken of.
      int64_t over = 0;
      for (const Vec3d& p : in.b_points) {
        const Vec4d q = corr * Vec4d(p.x(), p.y(), p.z(), 1);
        over += fa.Contains(q.x(), q.y(), in.max_distance_m);
      }
      const double inlier_fraction =
          over > 0 ? std::min(1.0, static_cast<double>(reg.b_inliers) / static_cast<double>(over))
                   : 0.0;
      const bool ok =
          reg.inliers > 100 && sigma2 > 0 && over >= 200 && inlier_fraction >= kMinInlierFraction;
      const double corr_deg =
          Eigen::AngleAxisd(Mat3d(corr.topLeftCorner<3, 3>())).angle() * 180.0 / kPi;
      // The correction's largest displacement over the overlap.
      double corr_m = 0;
      for (int c = 0; c < 4; ++c) {
        const Vec4d p((c & 1) ? box.x1 : box.x0, (c & 2) ? box.y1 : box.y0, 0, 1);
        corr_m = std::max(corr_m, (corr * p - p).head<3>().norm());
      }
      const bool plausible = corr_deg <= o.max_correction_deg && corr_m <= side;
      pj["accepted"] = ok && plausible;
      if (!ok)
        pj["why"] = over < 200 ? "fewer than 200 of B's points registered over A"
                               : "too few of B's points over A fit it (inlier fraction below 0.5)";
      else if (!plausible)
        pj["why"] = "correction beyond the plausible re-placement";
      pj["coarse_hypotheses"] = reg.coarse_hypotheses;
      pj["coarse_refined_fitness"] = reg.coarse_icp_fitness;
      pj["points_over_a"] = over;
      pj["inliers"] = reg.b_inliers;
      pj["inlier_fraction"] = inlier_fraction;
      pj["inlier_rms_um"] = reg.inliers ? std::sqrt(reg.sum_squares / reg.inliers) * 1e6 : 0.0;
      pj["correction_rotation_deg"] = corr_deg;
      pj["correction_translation_mm"] = {corr(0, 3) * 1e3, corr(1, 3) * 1e3, corr(2, 3) * 1e3};
      pj["seconds"] = reg.seconds_coarse + reg.seconds_fine;
      pj["seconds_planar"] = planar_s;
      pairs.push_back(pj);
      if (!ok || !plausible) continue;
      edges.push_back({a, b, t, reg.jtj / sigma2});
      edge_rms.push_back(std::sqrt(sigma2));
      edge_pair.push_back(pairs.size() - 1);
    }
    progress.Finish();
    // Pairs fitting far worse than the others (a wrong match) leave.
    if (!edge_rms.empty()) {
      std::vector<double> sorted = edge_rms;
      std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
      const double med = sorted[sorted.size() / 2];
      std::vector<Edge> kept;
      for (size_t e = 0; e < edges.size(); ++e) {
        if (edge_rms[e] > 3 * med) {
          pairs[edge_pair[e]]["accepted"] = false;
          pairs[edge_pair[e]]["why"] = "inlier RMS beyond 3x the median of the pairs'";
          continue;
        }
        kept.push_back(edges[e]);
        ++degree[edges[e].a], ++degree[edges[e].b];
      }
      edges = std::move(kept);
    }
    for (size_t k = 0; k < n; ++k)
      if (degree[k] == 0)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(fs::path(names[k]) / "height.exr"),
                              "overlaps no other scan (no pair registered): check the offsets "
                              "and that the scans overlap");

    // ---- pose graph (Ceres): scan 0 fixed at its nominal placement ----
    std::vector<std::array<double, 6>> x(n);
    for (size_t k = 0; k < n; ++k) {
      // Initial: chained from the nominal placement, refined by any edge to scan 0's side.
      const Mat3d R = nominal[k].topLeftCorner<3, 3>();
      ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(R.data()), x[k].data());
      for (int c = 0; c < 3; ++c) x[k][3 + c] = nominal[k](c, 3);
    }
    // A better start: breadth-first from scan 0 along the accepted edges.
    {
      std::vector<bool> seen(n, false);
      std::vector<Mat4d> init = nominal;
      std::vector<int> queue{0};
      seen[0] = true;
      for (size_t q = 0; q < queue.size(); ++q)
        for (const Edge& e : edges) {
          int from = -1, to = -1;
          Mat4d rel;
          if (e.a == queue[q] && !seen[e.b]) from = e.a, to = e.b, rel = e.b_to_a;
          if (e.b == queue[q] && !seen[e.a]) from = e.b, to = e.a, rel = e.b_to_a.inverse();
          if (to < 0) continue;
          init[to] = init[from] * rel;
          seen[to] = true;
          queue.push_back(to);
        }
      for (size_t k = 0; k < n; ++k)
        if (!seen[k])
          MESOSCAN_BAD_INPUT_AT(ErrorSite::File(fs::path(names[k]) / "height.exr"),
                                "not connected to " << names[0]
                                                    << " by registered overlaps: check the "
                                                       "offsets and that the scans overlap");
      for (size_t k = 0; k < n; ++k) {
        const Mat3d R = init[k].topLeftCorner<3, 3>();
        ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(R.data()), x[k].data());
        for (int c = 0; c < 3; ++c) x[k][3 + c] = init[k](c, 3);
      }
    }
    ceres::Problem problem;
    for (const Edge& e : edges) {
      auto* cost = new EdgeCost;
      cost->r_ab = e.b_to_a.topLeftCorner<3, 3>();
      cost->t_ab = e.b_to_a.topRightCorner<3, 1>();
      const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(e.info);
      cost->lt = Eigen::Matrix<double, 6, 6>(llt.matrixL()).transpose();
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<EdgeCost, 6, 6, 6>(cost),
                               new ceres::HuberLoss(3.0), x[e.a].data(), x[e.b].data());
    }
    problem.SetParameterBlockConstant(x[0].data());
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_SCHUR;
    so.max_num_iterations = 50;
    so.num_threads = 2;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    for (size_t k = 0; k < n; ++k) {
      Mat3d R;
      ceres::AngleAxisToRotationMatrix(x[k].data(), ceres::ColumnMajorAdapter3x3(R.data()));
      poses[k] = Mat4d::Identity();
      poses[k].topLeftCorner<3, 3>() = R;
      for (int c = 0; c < 3; ++c) poses[k](c, 3) = x[k][3 + c];
    }
    // Each edge's disagreement with the solved poses: RMS displacement over its overlap (um).
    double ss = 0;
    for (const Edge& e : edges) {
      const Mat4d m = poses[e.a].inverse() * poses[e.b] * e.b_to_a.inverse();
      const Box fb = Footprint(scans[e.a].height, Mat4d::Identity());
      double acc = 0;
      for (int c = 0; c < 4; ++c) {
        const Vec4d p((c & 1) ? fb.x1 : fb.x0, (c & 2) ? fb.y1 : fb.y0, 0, 1);
        acc += (m * p - p).squaredNorm();
      }
      ss += acc / 4;
    }
    Json sj = {{"iterations", summary.iterations.size()},
               {"initial_cost", summary.initial_cost},
               {"final_cost", summary.final_cost},
               {"edges", edges.size()}};
    timings["pose_graph"] = summary.total_time_in_seconds;
    timings["pairs"] = t_pairs.Seconds();
    timings["edge_rms_um_at_corners"] = std::sqrt(ss / std::max<size_t>(1, edges.size())) * 1e6;
    timings["pose_graph_report"] = sj;
  }

  // ---- the common grid ----
  Box all;
  for (size_t k = 0; k < n; ++k) {
    const Box f = Footprint(scans[k].height, poses[k]);
    all.Add(f.x0, f.y0);
    all.Add(f.x1, f.y1);
  }
  StitchResult out;
  HeightField& g = out.scan.height;
  g.pixel_size = px;
  // On the first scan's pixel lattice as placed (its pixels are taken as they are, not
  // resampled, where it alone covers the mosaic).
  const Vec4d l0 = poses[0] * Vec4d(scans[0].height.X(0), scans[0].height.Y(0), 0, 1);
  g.x0 = l0.x() + std::floor((all.x0 - l0.x()) / px) * px;
  g.y0 = l0.y() + std::ceil((all.y1 - l0.y()) / px) * px;
  const int64_t w64 = static_cast<int64_t>(std::ceil((all.x1 - g.x0) / px)) + 1;
  const int64_t h64 = static_cast<int64_t>(std::ceil((g.y0 - all.y0) / px)) + 1;
  CheckMemoryBudget("stitched grid " + std::to_string(w64) + "x" + std::to_string(h64),
                    static_cast<double>(w64) * h64 * 7 * sizeof(float));
  const int w = static_cast<int>(w64), h = static_cast<int>(h64);
  g.z = ImageF(w, h, 1, kNaN);
  g.confidence = ImageF(w, h, 1, 0.0f);
  out.scan.normals = ImageF(w, h, 3, kNaN);

  // Albedo of each scan from its session (if it names one that can be read).
  std::vector<ImageF> albedo(n);
  bool any_albedo = false;
  for (size_t k = 0; k < n; ++k) {
    const std::string sp = SessionPathFromReport(scans[k].report);
    if (sp.empty()) continue;
    try {
      albedo[k] = ReadImageGrey(fs::path(names[k]) / "albedo.exr");
    } catch (const Error&) {
      try {
        ImageF a = AlbedoFromSession(scans[k].height, sp);
        if (a.channels() > 1) {
          ImageF grey(a.width(), a.height(), 1, 0.0f);
          for (int c = 0; c < a.channels(); ++c)
            for (size_t i = 0; i < a.pixels(); ++i)
              grey.data()[i] += a.channel(c)[i] / a.channels();
          a = std::move(grey);
        }
        albedo[k] = std::move(a);
      } catch (const Error&) {
      }
    }
    any_albedo = any_albedo || !albedo[k].empty();
  }
  if (any_albedo) out.albedo = ImageF(w, h, 1, kNaN);

  const Stopwatch t_blend;
  std::vector<Mat4d> inv(n);
  std::vector<Box> foot(n);
  for (size_t k = 0; k < n; ++k)
    inv[k] = poses[k].inverse(), foot[k] = Footprint(scans[k].height, poses[k]);
  constexpr int kBand = 64;
  Progress progress("stitch: blend", (h + kBand - 1) / kBand);
  ParallelFor((h + kBand - 1) / kBand, [&](int64_t band) {
    const int j0 = static_cast<int>(band) * kBand, j1 = std::min(h, j0 + kBand);
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < w; ++i) {
        const double x = g.X(i), y = g.Y(j);
        double sw = 0, sz = 0, sc = 0, sa = 0, swa = 0;
        Vec3d sn = Vec3d::Zero();
        for (size_t k = 0; k < n; ++k) {
          if (!foot[k].Contains(x, y, 2 * px)) continue;
          const HeightField& hf = scans[k].height;
          // The scan's point whose mosaic image lies above (x, y): a fixed point on its height.
          const Mat3d Ri = inv[k].topLeftCorner<3, 3>();
          const Vec3d ti = inv[k].topRightCorner<3, 1>();
          Vec3d q = Ri * Vec3d(x, y, 0) + ti;
          double zs = hf.Sample(q.x(), q.y()), zw = 0;
          for (int it = 0; it < 4 && std::isfinite(zs); ++it) {
            zw = (poses[k] * Vec4d(q.x(), q.y(), zs, 1)).z();
            q = Ri * Vec3d(x, y, zw) + ti;
            zs = hf.Sample(q.x(), q.y());
          }
          if (!std::isfinite(zs)) continue;
          const double fi = hf.I(q.x()), fj = hf.J(q.y());
          const double d = std::min({fi, hf.width() - 1 - fi, fj, hf.height() - 1 - fj});
          const double ramp = o.feather * std::min(hf.width(), hf.height());
          const int ni = std::clamp(static_cast<int>(std::lround(fi)), 0, hf.width() - 1);
          const int nj = std::clamp(static_cast<int>(std::lround(fj)), 0, hf.height() - 1);
          const double conf = hf.confidence.empty() ? 1.0 : hf.confidence(ni, nj);
          const double wt = SmoothStep01(d / ramp) * std::max(conf, 1e-3);
          if (!(wt > 0)) continue;
          sw += wt;
          sz += wt * zw;
          sc += wt * conf;
          const Vec3d nn(normals[k](ni, nj, 0), normals[k](ni, nj, 1), normals[k](ni, nj, 2));
          if (nn.allFinite()) sn += wt * (poses[k].topLeftCorner<3, 3>() * nn);
          if (!albedo[k].empty() && std::isfinite(albedo[k](ni, nj)))
            sa += wt * albedo[k](ni, nj), swa += wt;
        }
        if (!(sw > 0)) continue;
        g.z(i, j) = static_cast<float>(sz / sw);
        g.confidence(i, j) = static_cast<float>(sc / sw);
        if (sn.norm() > 0) {
          const Vec3d u = sn.normalized();
          for (int c = 0; c < 3; ++c) out.scan.normals(i, j, c) = static_cast<float>(u(c));
        }
        if (any_albedo && swa > 0) out.albedo(i, j) = static_cast<float>(sa / swa);
      }
    progress.Advance();
  });
  progress.Finish();
  timings["blend"] = t_blend.Seconds();
  timings["total"] = total.Seconds();
  out.mosaic_from_scan = poses;

  // ---- report ----
  Json& rep = out.scan.report;
  rep["format"] = "mesoscan-stitch/1";
  Json st;
  st["sources"] = names;
  Json pj = Json::array();
  for (size_t k = 0; k < n; ++k) {
    const Mat4d c = nominal[k].inverse() * poses[k];
    pj.push_back({{"source", names[k]},
                  {"mosaic_from_scan", MatrixToJson(poses[k])},
                  {"nominal_offset_mm", {nominal[k](0, 3) * 1e3, nominal[k](1, 3) * 1e3}},
                  {"correction_rotation_deg",
                   Eigen::AngleAxisd(Mat3d(c.topLeftCorner<3, 3>())).angle() * 180.0 / kPi},
                  {"correction_translation_mm", {c(0, 3) * 1e3, c(1, 3) * 1e3, c(2, 3) * 1e3}}});
  }
  st["poses"] = pj;
  st["pairs"] = pairs;
  st["registered"] = o.register_scans;
  if (timings.contains("edge_rms_um_at_corners")) {
    st["edge_rms_um"] = timings["edge_rms_um_at_corners"];
    st["pose_graph"] = timings["pose_graph_report"];
    timings.erase("edge_rms_um_at_corners");
    timings.erase("pose_graph_report");
  }
  st["method"] =
      o.register_scans
          ? "pairs registered on their nominal overlaps (FPFH + RANSAC, robust point-to-plane ICP, "
            "Open3D), poses solved together (Ceres, each edge weighted by its fit's information, "
            "Huber), scans blended with confidence x a smoothstep ramp to 0 at each border"
          : "scans placed at their nominal offsets (no registration), blended as above";
  st["feather"] = o.feather;
  rep["stitch"] = st;
  rep["grid"] = {{"width", w},
                 {"height", h},
                 {"x0", g.x0},
                 {"y0", g.y0},
                 {"pixel_size", px},
                 {"width_mm", w * px * 1e3},
                 {"height_mm", h * px * 1e3}};
  // The largest of the inputs' predicted depth noise stands for the mosaic's (compare's test).
  double pred = 0;
  for (const Scan& s : scans)
    if (s.report.contains("summary") && s.report["summary"].is_object() &&
        s.report["summary"].contains("predicted_depth_rms_m") &&
        s.report["summary"]["predicted_depth_rms_m"].is_number())
      pred = std::max(pred, s.report["summary"]["predicted_depth_rms_m"].get<double>());
  int64_t valid = 0;
  for (float z : g.z.data()) valid += std::isfinite(z);
  rep["summary"] = {{"valid_pixels", valid}};
  if (pred > 0) rep["summary"]["predicted_depth_rms_m"] = pred;
  rep["timings_s"] = timings;
  return out;
}

void WriteStitchedScan(const fs::path& dir, const StitchResult& r) {
  const HeightField& g = r.scan.height;
  const std::map<std::string, double> attrs = {
      {kAttrX0, g.x0}, {kAttrY0, g.y0}, {kAttrPixelSize, g.pixel_size}};
  const int w = g.width(), h = g.height();
  WriteTiledExr(dir / "height.exr",
                {{"Z", g.z.channel(0)}, {"confidence", g.confidence.channel(0)}}, w, h, attrs);
  WriteTiledExr(dir / "normal.exr",
                {{"X", r.scan.normals.channel(0)},
                 {"Y", r.scan.normals.channel(1)},
                 {"Z", r.scan.normals.channel(2)}},
                w, h, attrs);
  if (!r.albedo.empty())
    WriteTiledExr(dir / "albedo.exr", {{"Y", r.albedo.channel(0)}}, w, h, attrs);
  // points.exr: the grid's own points (an orthographic camera over the mosaic).
  {
    ImageF xyz(w, h, 3, kNaN), pu(w, h, 1, kNaN);
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i)
        if (std::isfinite(g.z(i, j))) {
          xyz(i, j, 0) = static_cast<float>(g.X(i));
          xyz(i, j, 1) = static_cast<float>(g.Y(j));
          xyz(i, j, 2) = g.z(i, j);
        }
    WriteTiledExr(dir / "points.exr",
                  {{"X", xyz.channel(0)},
                   {"Y", xyz.channel(1)},
                   {"Z", xyz.channel(2)},
                   {"confidence", g.confidence.channel(0)},
                   {"projector_u", pu.channel(0)}},
                  w, h, {});
  }
  WriteJsonFile(dir / "report.json", r.scan.report);
}

}  // namespace mesoscan
