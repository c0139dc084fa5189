#include "sim/board_sim.h"

#include <atomic>
#include <cmath>
#include <memory>
#include <numbers>
#include <optional>
#include <sstream>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/stage_timer.h"
#include "session/patterns.h"

namespace fs = std::filesystem;

namespace mesoscan {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

#define BOARD_USAGE(expr) MESOSCAN_THROW(ErrorKind::kUsage, expr)
// A bad value of the options field `field` ("BoardSimOptions.pose").
#define BOARD_OPTION(field, expr) MESOSCAN_BAD_OPTION(field, expr)

// splitmix64, deterministic per (seed, frame, pixel).
inline uint64_t SplitMix(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
inline double UniformOf(uint64_t x) {
  return (static_cast<double>(x >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}
// A standard normal from a 64-bit key (Box-Muller, one of the pair).
inline double NormalOf(uint64_t key) {
  const double u1 = UniformOf(SplitMix(key)), u2 = UniformOf(SplitMix(key ^ 0xA5A5A5A5u));
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(kTwoPi * u2);
}

// Integral of the square wave (-1)^floor(f) from 0 to f (a triangle wave of period 2).
inline double SquareWaveIntegral(double f) {
  const double t = f - 2.0 * std::floor(0.5 * f);
  return t < 1.0 ? t : 2.0 - t;
}
// The square wave (-1)^floor(f) averaged over [f - h, f + h] (h in the wave's units).
inline double BoxedSquareWave(double f, double h) {
  if (h < 1e-9) return (static_cast<long>(std::floor(f)) % 2 == 0) ? 1.0 : -1.0;
  return (SquareWaveIntegral(f + h) - SquareWaveIntegral(f - h)) / (2.0 * h);
}

// A ChArUco board's printed image as a summed-area table: the box average of the image over any
// axis-aligned rectangle, exact for the piecewise-constant pixels (the table is bilinear within a
// pixel), the same box filter BoxedSquareWave applies to the plain checker.
class BoardTexture {
 public:
  BoardTexture(const CalibrationBoard& board, int px_per_square) : ppm_(px_per_square) {
    const std::vector<uint8_t> img = board.CharucoImage(px_per_square, &w_, &h_);
    sat_.assign(static_cast<size_t>(w_ + 1) * (h_ + 1), 0.0);
    for (int y = 0; y < h_; ++y) {
      double row = 0;
      for (int x = 0; x < w_; ++x) {
        row += img[static_cast<size_t>(y) * w_ + x] / 255.0;
        sat_[static_cast<size_t>(y + 1) * (w_ + 1) + x + 1] =
            sat_[static_cast<size_t>(y) * (w_ + 1) + x + 1] + row;
      }
    }
  }
  // Mean paper fraction (1 white, 0 ink) over [fx - hx, fx + hx] x [fy - hy, fy + hy], in
  // squares from the board's corner at (-half width, -half height); fy up the print.
  double Mean(double fx, double fy, double hx, double hy) const {
    const double u = fx * ppm_, v = h_ - fy * ppm_;
    const double hu = std::max(0.5, hx * ppm_), hv = std::max(0.5, hy * ppm_);
    const double area = 4 * hu * hv;
    return (At(u + hu, v + hv) - At(u - hu, v + hv) - At(u + hu, v - hv) + At(u - hu, v - hv)) /
           area;
  }

 private:
  double At(double x, double y) const {
    x = std::clamp(x, 0.0, static_cast<double>(w_));
    y = std::clamp(y, 0.0, static_cast<double>(h_));
    const int ix = std::min(static_cast<int>(x), w_ - 1),
              iy = std::min(static_cast<int>(y), h_ - 1);
    const double ax = x - ix, ay = y - iy;
    auto s = [&](int xx, int yy) { return sat_[static_cast<size_t>(yy) * (w_ + 1) + xx]; };
    return (1 - ay) * ((1 - ax) * s(ix, iy) + ax * s(ix + 1, iy)) +
           ay * ((1 - ax) * s(ix, iy + 1) + ax * s(ix + 1, iy + 1));
  }
  int ppm_, w_ = 0, h_ = 0;
  std::vector<double> sat_;
};

}  // namespace

void BoardSimOptions::Check() const {
  if (board.cols < 2 || board.rows < 2 || !(board.square_m > 0))
    BOARD_OPTION("BoardSimOptions.board",
                 "expected board:checker:COLSxROWS:SQUARE_MM or "
                 "board:charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT");
  for (double v : pose)
    if (!std::isfinite(v)) BOARD_OPTION("BoardSimOptions.pose", "expected six finite numbers");
  if (!(dark_albedo >= 0 && dark_albedo <= 1 && light_albedo >= 0 && light_albedo <= 1))
    BOARD_USAGE("board albedo: expected values in [0, 1]");
  if (!(margin_squares >= 0 && margin_squares < 100))
    BOARD_USAGE("board margin: expected [0, 100)");
  for (double p : ps_periods_y_px)
    if (!(p > 2.0) || !std::isfinite(p))
      BOARD_OPTION("BoardSimOptions.ps_periods_y_px", "expected periods > 2 px, got " << p);
  if (graycode_y_bits < 0 || graycode_y_bits > 30)
    BOARD_OPTION("BoardSimOptions.graycode_y_bits", "expected 0..30, got " << graycode_y_bits);
  if (!(graycode_y_block_px >= 1))
    BOARD_OPTION("BoardSimOptions.graycode_y_block_px",
                 "expected >= 1, got " << graycode_y_block_px);
  if (frame_format != "png16" && frame_format != "png8" && frame_format != "bmp" &&
      frame_format != "tif8")
    BOARD_OPTION("BoardSimOptions.frame_format",
                 "'" << frame_format << "', expected png16, png8, bmp or tif8");
}

bool IsBoardObject(const std::string& object) { return object.rfind("board:", 0) == 0; }

std::array<double, 6> ParseBoardPose(const std::string& text, const std::string& option) {
  std::array<double, 6> pose{};
  std::stringstream ss(text);
  std::string item;
  int n = 0;
  while (std::getline(ss, item, ',')) {
    if (n >= 6) BOARD_OPTION(option, "'" << text << "': expected six numbers rx,ry,rz,tx,ty,tz");
    try {
      size_t used = 0;
      pose[n] = std::stod(item, &used);
      if (used != item.size() || !std::isfinite(pose[n])) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      BOARD_OPTION(option,
                   "'" << text << "': expected six numbers rx,ry,rz,tx,ty,tz (degrees, mm)");
    }
    ++n;
  }
  if (n != 6) BOARD_OPTION(option, "'" << text << "': expected six numbers rx,ry,rz,tx,ty,tz");
  return pose;
}

Rigid3d BoardPoseToRigid(const std::array<double, 6>& pose) {
  const Vec3d r(pose[0], pose[1], pose[2]);
  const double angle = r.norm() * std::numbers::pi / 180.0;
  Rigid3d t;
  t.rotation =
      angle > 0 ? Eigen::AngleAxisd(angle, r.normalized()).toRotationMatrix() : Mat3d::Identity();
  t.translation = Vec3d(pose[3], pose[4], pose[5]) * 1e-3;
  return t;
}

void WriteRigFile(const fs::path& path, const Rig& rig) {
  Session s;
  s.rig = rig;
  const Json j = SessionToJson(s);
  WriteJsonFile(path, Json{{"rig", j["rig"]}});
}

namespace {

// The camera's undistorted normalised coordinates on a grid every kGrid px, bilinear in between
// (the distortion is smooth: < 1e-4 px error for |k1| ~ 0.1 at 4 px spacing).
class RayGrid {
 public:
  explicit RayGrid(const PinholeCamera& cam)
      : gw_(cam.width / kGrid + 3), gh_(cam.height / kGrid + 3) {
    grid_.resize(static_cast<size_t>(gw_) * gh_);
    ParallelFor(gh_, [&](int64_t gy) {
      for (int gx = 0; gx < gw_; ++gx)
        grid_[gy * gw_ + gx] = cam.UndistortNormalized(Vec2d(-1.0 + gx * kGrid, -1.0 + gy * kGrid));
    });
  }
  Vec2d Normalised(double x, double y) const {
    const double fx = (x + 1.0) / kGrid, fy = (y + 1.0) / kGrid;
    const int ix = std::clamp(static_cast<int>(fx), 0, gw_ - 2);
    const int iy = std::clamp(static_cast<int>(fy), 0, gh_ - 2);
    const double ax = fx - ix, ay = fy - iy;
    const Vec2d& a = grid_[iy * gw_ + ix];
    const Vec2d& b = grid_[iy * gw_ + ix + 1];
    const Vec2d& c = grid_[(iy + 1) * gw_ + ix];
    const Vec2d& d = grid_[(iy + 1) * gw_ + ix + 1];
    return Vec2d((1 - ay) * ((1 - ax) * a + ax * b) + ay * ((1 - ax) * c + ax * d));
  }

 private:
  static constexpr int kGrid = 4;
  int gw_, gh_;
  std::vector<Vec2d> grid_;
};

// The checked options of a board simulation (the board replaces the object; no lens shift).
SimulateOptions BoardSimulateOptions(const SimulateOptions& options, const BoardSimOptions& bo) {
  bo.Check();
  SimulateOptions o = options;
  o.ls_frames = 0;
  o.object = "plane";  // Check() wants a known object; the board replaces it
  o.Check();
  if ((o.ps_periods_px.empty() && o.graycode_bits == 0) ||
      (bo.ps_periods_y_px.empty() && bo.graycode_y_bits == 0))
    BOARD_USAGE("board: expected sine periods or a Gray code along both axes ("
                << OptionRef{"SimulateOptions.ps_periods_px"} << ", "
                << OptionRef{"BoardSimOptions.ps_periods_y_px"} << ")");
  if (o.axis != 'x') BOARD_OPTION("SimulateOptions.axis", "a board session's first axis is x");
  return o;
}

// The frame plan (session/patterns.h, as `capture --plan calibration`): sines along x then y
// (every period, phases 2 pi k / N), Gray code along x then y, white, black; per frame its sine
// set and phase.
struct BoardFrames {
  struct SineSet {
    char axis;
    double period;
  };
  std::vector<Frame> frames;
  std::vector<SineSet> sets;
  // Per frame: set index (-1 white, -2 black, -3 a Gray-code bit: frames[f].pattern).
  std::vector<int> frame_set;
  std::vector<double> cos_phase, sin_phase;
  std::vector<double> rate;  // per set: 2 pi / period
  bool coded = false;        // some frame is a Gray-code bit
  // Per frame: a Gray-code bit's value at each projector column (row for axis y); else empty.
  std::vector<std::vector<uint8_t>> coded_line;
};

BoardFrames PlanBoardFrames(const SimulateOptions& o, const BoardSimOptions& bo, const Rig& rig) {
  const int sc_width = rig.projector.width, sc_height = rig.projector.height;
  BoardFrames bf;
  FramePlanOptions plan;
  plan.periods_px = o.ps_periods_px;
  plan.cross_periods_px = bo.ps_periods_y_px;
  plan.phases = o.ps_phases;
  plan.graycode_bits = o.graycode_bits;
  plan.graycode_block_px = o.graycode_block_px;
  plan.cross_graycode_bits = bo.graycode_y_bits;
  plan.cross_graycode_block_px = bo.graycode_y_block_px;
  plan.graycode_inverse = o.graycode_inverse;
  plan.lens_shift_frames = 0;
  plan.white = o.white;
  plan.black = o.black;
  plan.extension = bo.frame_format == "bmp" ? ".bmp" : bo.frame_format == "tif8" ? ".tif" : ".png";
  bf.frames = MakeStandardFrames(plan);
  for (double p : o.ps_periods_px) bf.sets.push_back({'x', p});
  for (double p : bo.ps_periods_y_px) bf.sets.push_back({'y', p});
  for (const Frame& f : bf.frames) {
    int si = f.pattern.type == PatternType::kWhite      ? -1
             : f.pattern.type == PatternType::kGrayCode ? -3
                                                        : -2;
    for (size_t k = 0; k < bf.sets.size() && f.pattern.type == PatternType::kSine; ++k)
      if (bf.sets[k].axis == f.pattern.axis && bf.sets[k].period == f.pattern.period_px) {
        si = static_cast<int>(k);
        break;
      }
    bf.frame_set.push_back(si);
    bf.coded = bf.coded || si == -3;
    std::vector<uint8_t> line;
    if (si == -3) {
      const int extent = f.pattern.axis == 'y' ? sc_height : sc_width;
      line.resize(extent);
      for (int c = 0; c < extent; ++c) line[c] = f.pattern.Value(c, c) > 0.5 ? 1 : 0;
    }
    bf.coded_line.push_back(std::move(line));
  }
  const int nf = static_cast<int>(bf.frames.size());
  bf.cos_phase.resize(nf);
  bf.sin_phase.resize(nf);
  for (int f = 0; f < nf; ++f) {
    bf.cos_phase[f] = std::cos(bf.frames[f].pattern.phase);
    bf.sin_phase[f] = std::sin(bf.frames[f].pattern.phase);
  }
  const int nsets = static_cast<int>(bf.sets.size());
  bf.rate.resize(nsets);
  for (int si = 0; si < nsets; ++si) bf.rate[si] = kTwoPi / bf.sets[si].period;
  return bf;
}

// The rig and the board at its pose: what the ray caster reads.
struct BoardScene {
  BoardScene(const SimulateOptions& o_in, const BoardSimOptions& bo_in, const Rig& rig_in)
      : o(o_in),
        bo(bo_in),
        rig(rig_in),
        cam(rig.camera),
        prj(rig.projector),
        board(bo.board),
        // NaN focus (the object's mid height for objects): a calibration plan keeps the focus of
        // the scans it calibrates for, on the mount plane.
        focus_z(std::isnan(o.focus_height_m) ? 0.0 : o.focus_height_m),
        world_from_board(BoardPoseToRigid(bo.pose)),
        board_from_world(world_from_board.Inverse()),
        prj_from_world(prj.world_from_device.Inverse()),
        n_world(world_from_board.rotation.col(2)),
        b0(world_from_board.translation),
        cam_centre(cam.CentreInWorld()),
        prj_centre(prj.CentreInWorld()),
        r0(prj_centre.norm()),
        half_w(board.HalfWidth() + bo.margin_squares * board.square_m),
        half_h(board.HalfHeight() + bo.margin_squares * board.square_m),
        rays(cam) {
    if (board.charuco()) texture = std::make_unique<const BoardTexture>(board, 64);
  }
  const SimulateOptions& o;
  const BoardSimOptions& bo;
  const Rig& rig;
  const PinholeCamera& cam;
  const PinholeCamera& prj;
  const CalibrationBoard& board;
  const double focus_z;
  const Rigid3d world_from_board, board_from_world, prj_from_world;
  const Vec3d n_world, b0, cam_centre, prj_centre;
  const double r0;
  const double half_w, half_h;  // the board with its margin
  const RayGrid rays;
  std::unique_ptr<const BoardTexture> texture;  // ChArUco boards only
};

// The board point of an image point (false if the ray misses the front).
bool BoardPoint(const BoardScene& sc, double x, double y, Vec3d* world) {
  const Vec2d n = sc.rays.Normalised(x, y);
  const Vec3d d = sc.cam.world_from_device.rotation * Vec3d(n.x(), n.y(), 1.0);
  const double nd = sc.n_world.dot(d);
  if (!(nd < 0)) return false;  // parallel to, or the back of, the board
  const double t = sc.n_world.dot(sc.b0 - sc.cam_centre) / nd;
  if (!(t > 0)) return false;
  *world = sc.cam_centre + t * d;
  return true;
}

// The albedo at world point p of image subsample (qx, qy): background, margin, or the print
// box-filtered over the subsample's footprint.
double SubsampleAlbedo(const BoardScene& sc, double qx, double qy, const Vec3d& p) {
  const BoardSimOptions& bo = sc.bo;
  const CalibrationBoard& board = sc.board;
  const int S = sc.o.supersample;
  const Vec3d pb = sc.board_from_world * p;
  double albedo = bo.background_albedo;
  if (std::abs(pb.x()) <= sc.half_w && std::abs(pb.y()) <= sc.half_h) {
    albedo = bo.light_albedo;
    if (std::abs(pb.x()) < board.HalfWidth() && std::abs(pb.y()) < board.HalfHeight()) {
      // The checker box-filtered over the subsample's footprint (its extent along the board's
      // axes, from the neighbouring subsamples' board points): dark fraction
      // = (1 + <sx> <sy>) / 2, the box filter being separable.
      Vec3d px_next, py_next;
      double hx = 0, hy = 0;
      if (BoardPoint(sc, qx + 0.5 / S, qy, &px_next) &&
          BoardPoint(sc, qx, qy + 0.5 / S, &py_next)) {
        const Vec3d ex = sc.board_from_world.rotation * (px_next - p);
        const Vec3d ey = sc.board_from_world.rotation * (py_next - p);
        hx = (std::abs(ex.x()) + std::abs(ey.x())) / board.square_m;
        hy = (std::abs(ex.y()) + std::abs(ey.y())) / board.square_m;
      }
      const double fx = pb.x() / board.square_m + 0.5 * (board.cols - 1) + 1.0;
      const double fy = pb.y() / board.square_m + 0.5 * (board.rows - 1) + 1.0;
      const double dark = sc.texture
                              ? 1.0 - sc.texture->Mean(fx, fy, hx, hy)
                              : 0.5 * (1.0 + BoxedSquareWave(fx, hx) * BoxedSquareWave(fy, hy));
      albedo = bo.light_albedo + (bo.dark_albedo - bo.light_albedo) * dark;
    }
  }
  return albedo;
}

// The projector's light on one subsample: per frame, acc[f] += its irradiance times the albedo
// (the sines blurred by the projector's Gaussian and pixel box). set_cos / set_sin: scratch of
// one entry per sine set. False where the projector does not light the point.
bool AddProjectedLight(const BoardScene& sc, const BoardFrames& bf, const Vec3d& p, double albedo,
                       std::vector<double>* set_cos, std::vector<double>* set_sin,
                       std::vector<double>* acc) {
  const SimulateOptions& o = sc.o;
  const Vec3d p_dev = sc.prj_from_world * p;
  double uv[2];
  if (!sc.prj.ProjectDevice(p_dev.data(), uv)) return false;
  if (uv[0] < -0.5 || uv[0] > sc.prj.width - 0.5 || uv[1] < -0.5 || uv[1] > sc.prj.height - 0.5)
    return false;
  Vec3d l = sc.prj_centre - p;
  const double r = l.norm();
  const double cos_i = sc.n_world.dot(l) / r;
  if (!(cos_i > 0)) return false;
  const double sh = albedo * cos_i * (sc.r0 / r) * (sc.r0 / r);
  const double sigma = o.blur_sigma_px + o.defocus_px_per_m * std::abs(p.z() - sc.focus_z);
  const int nsets = static_cast<int>(bf.sets.size());
  for (int si = 0; si < nsets; ++si) {
    const double x = bf.sets[si].axis == 'x' ? uv[0] : uv[1];
    // The projected sine blurred by a Gaussian (sigma) and a pixel box of the fill factor: its
    // amplitude times exp(-2 pi^2 s^2 / p^2) sinc(fill / p).
    const double pf = bf.sets[si].period;
    const double arg = std::numbers::pi * o.fill_factor / pf;
    const double att =
        std::exp(-2.0 * std::numbers::pi * std::numbers::pi * sigma * sigma / (pf * pf)) *
        std::sin(arg) / arg;
    (*set_cos)[si] = sh * 0.5 * att * std::cos(bf.rate[si] * x);
    (*set_sin)[si] = sh * 0.5 * att * std::sin(bf.rate[si] * x);
  }
  // Binary (Gray-code) patterns: each projector pixel's value spread over its pitch, blurred by
  // the Gaussian and the fill factor's box (taken as a Gaussian of the same variance): the
  // weight of pixel c at x is Phi((x - c + 1/2) / s) - Phi((x - c - 1/2) / s), the same weights
  // for every frame along an axis.
  const double s_box = std::sqrt(sigma * sigma + o.fill_factor * o.fill_factor / 12.0);
  // +-6 sigma, at most +-31 px (a blur beyond ~5 px leaves no bit of a fine code readable).
  const int reach = std::min(31, static_cast<int>(std::ceil(6.0 * s_box)) + 1);
  double weights[2][64];
  int first[2] = {0, 0}, count[2] = {0, 0};
  if (bf.coded)
    for (int a = 0; a < 2; ++a) {
      const double x = uv[a];
      const int c0 = static_cast<int>(std::floor(x)) - reach, n = 2 * reach + 2;
      first[a] = c0;
      count[a] = n;
      double lo = 0.5 * std::erfc(-(x - (c0 - 0.5)) / (s_box * std::numbers::sqrt2));
      for (int j = 0; j < n; ++j) {
        const double hi = 0.5 * std::erfc(-(x - (c0 + j + 0.5)) / (s_box * std::numbers::sqrt2));
        weights[a][j] = lo - hi;
        lo = hi;
      }
    }
  const int nf = static_cast<int>(bf.frames.size());
  for (int f = 0; f < nf; ++f) {
    const int si = bf.frame_set[f];
    if (si >= 0) {
      (*acc)[f] += 0.5 * sh + (*set_cos)[si] * bf.cos_phase[f] - (*set_sin)[si] * bf.sin_phase[f];
    } else if (si == -1) {
      (*acc)[f] += sh;
    } else if (si == -3) {
      const std::vector<uint8_t>& line = bf.coded_line[f];
      const int a = bf.frames[f].pattern.axis == 'y' ? 1 : 0;
      const int extent = static_cast<int>(line.size());
      double light = 0.0;
      for (int j = 0; j < count[a]; ++j) {
        const int c = first[a] + j;
        if (c >= 0 && c < extent && line[c]) light += weights[a][j];  // beyond: dark
      }
      (*acc)[f] += sh * light;
    }
  }
  return true;
}

// The frames' pixels: camera values per frame (gains, noise, quantisation), in DN of the frame
// format.
struct BoardImages {
  std::vector<std::vector<uint16_t>> images;
  int64_t lit_pixels = 0;
  bool eight_bit = true;
};

BoardImages RayCastBoard(const BoardScene& sc, const BoardFrames& bf) {
  const SimulateOptions& o = sc.o;
  const int W = sc.cam.width, H = sc.cam.height, S = o.supersample;
  const int nf = static_cast<int>(bf.frames.size()), nsets = static_cast<int>(bf.sets.size());
  const NoiseModel noise = MakeNoiseModel(o);
  BoardImages out;
  out.eight_bit = sc.bo.frame_format != "png16";
  const bool eight_bit = out.eight_bit;
  const int dn_max = eight_bit ? 255 : (1 << o.adc_bits) - 1;
  std::vector<double> gains(nf, 1.0);
  for (int f = 0; f < nf; ++f)
    gains[f] = 1.0 + noise.GainJitterSigma() * NormalOf(SplitMix(o.seed * 7919 + f));
  const double inv_ss = 1.0 / (S * S);
  out.images.assign(nf, std::vector<uint16_t>(static_cast<size_t>(W) * H));
  std::atomic<int64_t> lit_pixels{0};
  Progress progress("simulate board", H);
  ParallelForRows(
      H,
      [&](int y0, int y1) {
        std::vector<double> acc(nf);
        std::vector<double> set_cos(nsets), set_sin(nsets);
        for (int py = y0; py < y1; ++py) {
          for (int px = 0; px < W; ++px) {
            std::fill(acc.begin(), acc.end(), 0.0);
            double amb = 0.0;
            bool any_lit = false;
            for (int sy = 0; sy < S; ++sy)
              for (int sx = 0; sx < S; ++sx) {
                const double qx = px - 0.5 + (sx + 0.5) / S, qy = py - 0.5 + (sy + 0.5) / S;
                Vec3d p;
                if (!BoardPoint(sc, qx, qy, &p)) continue;
                const double albedo = SubsampleAlbedo(sc, qx, qy, p);
                amb += albedo;
                if (AddProjectedLight(sc, bf, p, albedo, &set_cos, &set_sin, &acc)) any_lit = true;
              }
            if (any_lit) lit_pixels.fetch_add(1, std::memory_order_relaxed);
            const size_t pix = static_cast<size_t>(py) * W + px;
            for (int f = 0; f < nf; ++f) {
              const double light = bf.frame_set[f] == -2 ? 0.0 : acc[f] * inv_ss;
              const double mean = o.exposure * (light + o.ambient * amb * inv_ss);
              double value = mean;  // the board is simulated with a linear projector
              value *= gains[f];
              if (o.noise > 0)
                value +=
                    noise.Sigma(mean) *
                    NormalOf(SplitMix((o.seed << 40) ^ (static_cast<uint64_t>(f) << 32) ^ pix));
              const int dn = static_cast<int>(std::lround(std::clamp(value, 0.0, 1.0) * dn_max));
              out.images[f][pix] =
                  eight_bit ? static_cast<uint16_t>(dn)
                            : static_cast<uint16_t>(std::lround(dn * (65535.0 / dn_max)));
            }
          }
          progress.Advance();
        }
      },
      8);
  progress.Finish();
  out.lit_pixels = lit_pixels.load();
  return out;
}

// The session folder: the frames and session.json with the uncalibrated rig, and the true rig
// and board pose under "simulation". Written atomically.
void WriteBoardSession(const fs::path& out_dir, const BoardScene& sc, const BoardFrames& bf,
                       const BoardImages& im) {
  const SimulateOptions& o = sc.o;
  const BoardSimOptions& bo = sc.bo;
  const int W = sc.cam.width, H = sc.cam.height, nf = static_cast<int>(bf.frames.size());
  auto fill = [&](const fs::path& dir) {
    fs::create_directories(dir / "frames");
    ParallelFor(nf, [&](int64_t f) {
      const fs::path path = dir / bf.frames[f].file;
      if (!im.eight_bit) {
        ImageU16 image(W, H, 1);
        std::copy(im.images[f].begin(), im.images[f].end(), image.channel(0));
        WritePng16(path, image, 1);
        return;
      }
      ImageU8 image(W, H, 1);
      std::copy(im.images[f].begin(), im.images[f].end(), image.channel(0));
      WritePng8(path, image);
    });
    Session s;
    s.root = dir;
    s.created = SessionTimeNow();
    s.object = "calibration board " + sc.board.ToString();
    s.rig = sc.rig;
    s.rig.uncalibrated = true;
    s.rig.lens_shifter.reset();
    s.frames = bf.frames;
    Session truth;
    truth.rig = sc.rig;
    truth.rig.uncalibrated = false;
    const Json truth_json = SessionToJson(truth);
    s.extra["simulation"] = {
        {"board", sc.board.ToString()},
        {"pose_deg_mm", Json(std::vector<double>(bo.pose.begin(), bo.pose.end()))},
        {"world_from_board", Json::array()},
        {"true_rig", truth_json["rig"]},
        {"dark_albedo", bo.dark_albedo},
        {"light_albedo", bo.light_albedo},
        {"noise", o.noise},
        {"full_well_e", o.full_well_e},
        {"read_noise_e", o.read_noise_e},
        {"supersample", o.supersample},
        {"frame_format", bo.frame_format},
        {"seed", o.seed}};
    const Mat4d m = sc.world_from_board.Matrix();
    for (int r = 0; r < 4; ++r)
      s.extra["simulation"]["world_from_board"].push_back({m(r, 0), m(r, 1), m(r, 2), m(r, 3)});
    WriteSessionJson(s);
  };
  WriteFolderAtomically(out_dir, fill);
}

}  // namespace

SimulateSummary SimulateBoard(const SimulateOptions& options, const BoardSimOptions& bo,
                              const fs::path& out_dir) {
  const Stopwatch t_start;
  const SimulateOptions o = BoardSimulateOptions(options, bo);
  const Rig rig = ResolveRig(o);
  const BoardScene scene(o, bo, rig);
  if (scene.n_world.dot(scene.cam_centre - scene.b0) <= 0)
    BOARD_OPTION("BoardSimOptions.pose", "the camera sees the back of the board at this pose");
  const BoardFrames frames = PlanBoardFrames(o, bo, rig);

  SimulateSummary summary;
  summary.width = rig.camera.width;
  summary.height = rig.camera.height;
  summary.frames = static_cast<int>(frames.frames.size());
  const Stopwatch t_ray;
  const BoardImages images = RayCastBoard(scene, frames);
  summary.seconds_raycast = t_ray.Seconds();
  summary.lit_pixels = images.lit_pixels;
  summary.rays =
      static_cast<int64_t>(summary.width) * summary.height * o.supersample * o.supersample;

  const Stopwatch t_frames;
  WriteBoardSession(out_dir, scene, frames, images);
  summary.seconds_frames = t_frames.Seconds();
  summary.seconds_total = t_start.Seconds();
  return summary;
}

Rig RealShapeRig() {
  Rig rig;
  rig.camera.width = 1688;
  rig.camera.height = 1352;
  rig.camera.K << 3400, 0, 843.5, 0, 3400, 675.5, 0, 0, 1;
  rig.camera.distortion = {-0.05, 0.08, 0, 0, 0};
  Mat4d m;
  m << 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0.4, 0, 0, 0, 1;
  rig.camera.world_from_device = Rigid3d::FromMatrix(m);
  rig.projector.width = 1824;
  rig.projector.height = 1140;
  rig.projector.K << 3000, 0, 911.5, 0, 3000, 569.5, 0, 0, 1;
  rig.projector.distortion = {0.03, 0, 0, 0, 0};
  const double a = 15.0 * std::numbers::pi / 180.0, dist = 0.42;
  rig.projector.world_from_device.rotation.col(0) = Vec3d(std::cos(a), 0, -std::sin(a));
  rig.projector.world_from_device.rotation.col(1) = Vec3d(0, -1, 0);
  rig.projector.world_from_device.rotation.col(2) = Vec3d(-std::sin(a), 0, -std::cos(a));
  rig.projector.world_from_device.translation = Vec3d(dist * std::sin(a), 0, dist * std::cos(a));
  return rig;
}

}  // namespace mesoscan
