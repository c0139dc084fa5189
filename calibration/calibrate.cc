#include "calibration/calibrate.h"

#include <ceres/ceres.h>
#include <ceres/covariance.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <numeric>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "calibration/calibrate_codecs.h"
#include "core/camera.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/parallel.h"
#include "heightfield/frame_corrections.h"
#include "heightfield/frames.h"
#include "heightfield/phase_shift.h"

namespace fs = std::filesystem;

namespace mesoscan {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The sine frames of one (axis, period) and their phase offsets, as stack frame indices.
struct PeriodFrames {
  double period = 0;
  std::vector<int> stack;
  std::vector<double> deltas;
};

struct AxisDecoder {
  std::vector<PeriodFrames> periods;
  std::vector<WrappedPhaseSolver> solvers;
  std::optional<TemporalUnwrapper> unwrapper;
};

// The frames a view needs: every sine frame, plus the first white frame (texture).
struct ViewFrames {
  std::vector<int> session_frames;
  AxisDecoder axis[2];           // x, y
  int white = -1;                // stack index, -1 if none
  std::vector<int> texture_set;  // stack indices of the phase set averaged for the texture
};

ViewFrames PlanView(const Session& session) {
  const FramePlan plan = MakeFramePlan(session.frames);
  ViewFrames v;
  for (const auto& set : plan.sine) {
    PeriodFrames pf;
    pf.period = set.period_px;
    for (size_t f : set.frames) {
      if (session.frames[f].shift_steps != 0) continue;
      pf.stack.push_back(static_cast<int>(v.session_frames.size()));
      pf.deltas.push_back(session.frames[f].pattern.phase);
      v.session_frames.push_back(static_cast<int>(f));
    }
    if (pf.stack.size() < 3) continue;
    v.axis[set.axis == 'x' ? 0 : 1].periods.push_back(std::move(pf));
  }
  const std::string where = session.root.string() + "/session.json";
  for (int a = 0; a < 2; ++a) {
    if (v.axis[a].periods.empty())
      MESOSCAN_BAD_INPUT(where << ": frames: no sine pattern along " << (a ? "y" : "x")
                               << " with >= 3 phases at shift_steps 0, expected sines along both "
                                  "axes for calibration");
    std::vector<double> list;
    for (const auto& p : v.axis[a].periods) {
      list.push_back(p.period);
      v.axis[a].solvers.emplace_back(p.deltas);
    }
    const double range = a == 0 ? session.rig.projector.width : session.rig.projector.height;
    try {
      v.axis[a].unwrapper.emplace(list, range, 4.0);
    } catch (const Error& e) {
      MESOSCAN_BAD_INPUT(where << ": frames (axis " << (a ? "y" : "x") << "): " << e.what());
    }
  }
  if (!plan.white.empty()) {
    v.white = static_cast<int>(v.session_frames.size());
    v.session_frames.push_back(static_cast<int>(plan.white.front()));
  }
  // Texture without a white frame: the mean of the phase set with the most equal-step phases
  // (the mean of N >= 3 equally spaced phases is the offset A exactly). Prefer the finest period.
  const PeriodFrames* best = nullptr;
  for (int a = 0; a < 2; ++a)
    for (const auto& p : v.axis[a].periods)
      if (!best || p.stack.size() > best->stack.size() ||
          (p.stack.size() == best->stack.size() && p.period < best->period))
        best = &p;
  v.texture_set = best->stack;
  return v;
}

// The sine frames' design for a per-frame gain estimate: one per-pixel model over every sine
// frame of both axes, the offset A shared (the same surface point under the same mean light) and
// (B cos, B sin) per period set.
GainModel SineGainModel(const ViewFrames& vf) {
  GainModel model;
  int sets = 0;
  for (int a = 0; a < 2; ++a) sets += static_cast<int>(vf.axis[a].periods.size());
  int s = 0;
  for (int a = 0; a < 2; ++a)
    for (const auto& p : vf.axis[a].periods) {
      for (size_t k = 0; k < p.stack.size(); ++k) {
        std::vector<double> row(1 + 2 * sets, 0.0);
        row[0] = 1.0;
        row[1 + 2 * s] = std::cos(p.deltas[k]);
        row[2 + 2 * s] = -std::sin(p.deltas[k]);
        model.frames.push_back(p.stack[k]);
        model.design.push_back(row);
      }
      ++s;
    }
  return model;
}

// Joint least squares of the frame gains g and every pixel's coefficients c_j of
//   I_kj = g_k (M c_j)_k + noise
// (variable projection: Gauss-Newton on g with the c_j eliminated exactly). A gain pattern that
// lies in the band of one period set (a cosine / sine over its phases) moves each pixel's
// decoded phase by ~ (A / B) g and is absorbed by that set's (B cos, B sin): it is identifiable
// only through the shared offset A, whose per-set estimates it shifts by ~ (B / 2) g with the
// pixel's own phase. Over thousands of pixels at different phases that is plenty, but alternating
// least squares moves along such weak directions by a factor ~ B^2 / 4 A^2 per step and leaves
// them at their start (frames.h EstimateFrameGains); Gauss-Newton takes them in one step.
// Since G and M are shared by all pixels, so is the projection P = I - G M (M' G^2 M)^-1 M' G,
// and the Gauss-Newton normal matrix is P .* sum_j m_j m_j' (m_j = M c_j). Gauge: the mean gain
// is 1. Pixels with a saturated sample or a relative residual beyond median + 4 MAD are dropped.
std::vector<double> JointFrameGains(const FrameStack& stack, const GainModel& model,
                                    const std::vector<uint32_t>& pixels, int iterations) {
  const int nk = static_cast<int>(model.frames.size());
  std::vector<double> gains(nk, 1.0);
  if (nk == 0 || pixels.size() < 16) return gains;
  const int np = static_cast<int>(model.design[0].size());
  if (nk <= np) return gains;
  Eigen::MatrixXd M(nk, np);
  for (int k = 0; k < nk; ++k)
    for (int p = 0; p < np; ++p) M(k, p) = model.design[k][p];
  std::vector<uint32_t> px;
  const auto& sat = stack.saturated();
  for (uint32_t i : pixels)
    if (sat.empty() || !sat[i]) px.push_back(i);
  const size_t n = px.size();
  if (n < 16) return gains;
  Eigen::MatrixXd I(nk, n);
  for (int k = 0; k < nk; ++k)
    for (size_t j = 0; j < n; ++j) I(k, j) = stack.Value(model.frames[k], px[j]);
  Eigen::VectorXd g = Eigen::VectorXd::Ones(nk);
  std::vector<uint8_t> use(n, 1);
  for (int it = 0; it < iterations; ++it) {
    const Eigen::MatrixXd GM = g.asDiagonal() * M;
    const Eigen::MatrixXd pinv = (GM.transpose() * GM).ldlt().solve(GM.transpose());
    const Eigen::MatrixXd C = pinv * I;                 // np x n
    const Eigen::MatrixXd Mc = M * C;                   // ungained model, nk x n
    const Eigen::MatrixXd R = I - g.asDiagonal() * Mc;  // residuals
    const Eigen::MatrixXd P = Eigen::MatrixXd::Identity(nk, nk) - GM * pinv;
    std::vector<double> rel(n);
    for (size_t j = 0; j < n; ++j) {
      const double m2 = Mc.col(j).squaredNorm();
      rel[j] =
          m2 > 0 ? std::sqrt(R.col(j).squaredNorm() / m2) : std::numeric_limits<double>::infinity();
    }
    const double limit = OutlierLimit(rel);
    Eigen::MatrixXd S = Eigen::MatrixXd::Zero(nk, nk);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(nk);
    for (size_t j = 0; j < n; ++j) {
      use[j] = std::isfinite(rel[j]) && rel[j] <= limit;
      if (!use[j]) continue;
      S.noalias() += Mc.col(j) * Mc.col(j).transpose();
      b += Mc.col(j).cwiseProduct(R.col(j));
    }
    // H dg = b (J = -P diag(m_j), J' r = -m .* r since P r = r); the gauge (g itself is a null
    // direction: scaling g scales every c_j inversely) fixed by a penalty on the mean.
    Eigen::MatrixXd H = P.cwiseProduct(S);
    const double scale = H.diagonal().mean();
    if (!(scale > 0) || !std::isfinite(scale)) break;
    H += scale * Eigen::MatrixXd::Constant(nk, nk, 1.0 / nk);
    const Eigen::VectorXd dg = H.ldlt().solve(b);
    if (!dg.allFinite()) break;
    g += dg;
    g /= g.mean();
    if ((g.array() <= 0.5).any() || (g.array() >= 1.5).any()) {  // not a gain jitter: give up
      g.setOnes();
      break;
    }
    if (dg.lpNorm<Eigen::Infinity>() < 1e-7) break;
  }
  for (int k = 0; k < nk; ++k) gains[k] = g[k];
  return gains;
}

// Per-frame gains of the sine frames (stack indices; 1 where not estimated), by `method`.
std::vector<double> SineGains(const FrameStack& stack, const ViewFrames& vf,
                              const std::vector<uint32_t>& pixels, CalibrationGainMethod method) {
  std::vector<double> gains(stack.num_frames(), 1.0);
  if (method == CalibrationGainMethod::kNone) return gains;
  if (method == CalibrationGainMethod::kFrameMeans) {
    // Every set's frame means over the whole view (FrameMeanGains), mean 1 per set.
    std::vector<uint32_t> all;
    for (size_t i = 0; i < stack.pixels(); i += 3) all.push_back(static_cast<uint32_t>(i));
    for (int a = 0; a < 2; ++a)
      for (const auto& p : vf.axis[a].periods) {
        const std::vector<double> g = FrameMeanGains(stack, p.stack, all);
        for (size_t k = 0; k < g.size(); ++k) gains[p.stack[k]] = g[k];
      }
    return gains;
  }
  const GainModel model = SineGainModel(vf);
  if (model.frames.size() <= model.design[0].size() || pixels.size() < 100)
    return gains;  // no redundancy
  std::vector<double> g;
  if (method == CalibrationGainMethod::kAlternating) {
    // Every 4th pixel is plenty for a dozen gains.
    std::vector<uint32_t> sample;
    for (size_t i = 0; i < pixels.size(); i += 4) sample.push_back(pixels[i]);
    g = EstimateFrameGains(stack, model, sample);
  } else {
    std::vector<uint32_t> sample;
    for (size_t i = 0; i < pixels.size(); i += 2) sample.push_back(pixels[i]);
    g = JointFrameGains(stack, model, sample, 8);
  }
  for (size_t k = 0; k < model.frames.size(); ++k) gains[model.frames[k]] = g[k];
  return gains;
}

void DecodeAt(const FrameStack& stack, const ViewFrames& vf, const std::vector<uint32_t>& pixels,
              const CalibrateOptions& options, std::vector<float>* out_u,
              std::vector<float>* out_v) {
  const std::vector<double> gains = SineGains(stack, vf, pixels, options.gain_method);
  std::vector<float> inv_gain(gains.size());
  for (size_t k = 0; k < gains.size(); ++k) inv_gain[k] = static_cast<float>(1.0 / gains[k]);
  out_u->assign(pixels.size(), std::numeric_limits<float>::quiet_NaN());
  out_v->assign(pixels.size(), std::numeric_limits<float>::quiet_NaN());
  const double sigma = options.frame_sigma;
  ParallelFor(static_cast<int64_t>(pixels.size()), [&](int64_t n) {
    const size_t i = pixels[n];
    for (int a = 0; a < 2; ++a) {
      const AxisDecoder& ax = vf.axis[a];
      const int m = static_cast<int>(ax.periods.size());
      double theta[16], weight[16];
      bool ok = m <= 16;
      for (int p = 0; p < m && ok; ++p) {
        float samples[64];
        const int k = static_cast<int>(ax.periods[p].stack.size());
        if (k > 64) {
          ok = false;
          break;
        }
        for (int j = 0; j < k; ++j) {
          const int f = ax.periods[p].stack[j];
          samples[j] = stack.Value(f, i) * inv_gain[f];
        }
        const auto r = ax.solvers[p].Solve(samples);
        if (!r.valid || !(r.modulation > options.min_modulation)) {
          ok = false;
          break;
        }
        theta[p] = r.theta;
        weight[p] = 1.0 / ax.solvers[p].ThetaVariance(sigma, r.modulation);
      }
      if (!ok) return;
      const UnwrapResult ur = ax.unwrapper->Unwrap(theta, weight);
      if (!ur.valid) return;
      (a == 0 ? *out_u : *out_v)[n] = static_cast<float>(ur.u);
    }
  });
}

// Distance-ordered labelling: corners as OpenCV returns them, re-ordered so that k = j*cols+i
// follows the board frame (x along the columns, y along the rows, +z out of the printed face,
// seen by the camera): the image of x cross y is clockwise (y down); for boards whose colours are
// not symmetric under a half turn, the square beyond corner 0 is dark.
void NormaliseOrder(const CalibrationBoard& board, const cv::Mat& texture,
                    std::vector<cv::Point2f>* corners) {
  const int c = board.cols, r = board.rows;
  auto at = [&](int i, int j) { return (*corners)[j * c + i]; };
  const cv::Point2f a = at(1, 0) - at(0, 0), b = at(0, 1) - at(0, 0);
  if (a.x * b.y - a.y * b.x > 0) {  // counter-clockwise: reverse the rows
    std::vector<cv::Point2f> flipped(corners->size());
    for (int j = 0; j < r; ++j)
      for (int i = 0; i < c; ++i) flipped[j * c + i] = at(i, r - 1 - j);
    *corners = flipped;
  }
  if ((c + r) % 2 == 1) {
    auto sample = [&](cv::Point2f p) {
      const int x = std::clamp(static_cast<int>(std::lround(p.x)), 0, texture.cols - 1);
      const int y = std::clamp(static_cast<int>(std::lround(p.y)), 0, texture.rows - 1);
      return texture.at<float>(y, x);
    };
    const cv::Point2f c0 = at(0, 0), dx = at(1, 0) - c0, dy = at(0, 1) - c0;
    const float dark = sample(c0 - 0.5f * dx - 0.5f * dy);             // square beyond corner 0
    const float light = sample(c0 + 0.5f * dx - 0.5f * dy);            // its neighbour along x
    if (dark > light) std::reverse(corners->begin(), corners->end());  // a half turn
  }
}

// ChArUco: the markers (cv::aruco::detectMarkers, then refineDetectedMarkers against the board)
// and the chessboard corners between them (interpolateCornersCharuco: local homographies of the
// neighbouring markers, cornerSubPix). Corners come with their board index; a partial board gives
// the corners of its visible part.
bool DetectCharuco(const CalibrationBoard& board, const cv::Mat& grey8,
                   std::vector<cv::Point2f>* corners, std::vector<int>* ids, std::string* why) {
  const auto dict = cv::aruco::getPredefinedDictionary(
      static_cast<cv::aruco::PREDEFINED_DICTIONARY_NAME>(board.dictionary));
  const auto cb = cv::aruco::CharucoBoard::create(board.squares_x(), board.squares_y(),
                                                  static_cast<float>(board.square_m),
                                                  static_cast<float>(board.marker_m), dict);
  std::vector<std::vector<cv::Point2f>> marker_corners, rejected;
  std::vector<int> marker_ids;
  try {
    auto params = cv::aruco::DetectorParameters::create();
    params->cornerRefinementMethod = cv::aruco::CORNER_REFINE_SUBPIX;
    cv::aruco::detectMarkers(grey8, dict, marker_corners, marker_ids, params, rejected);
    if (!marker_ids.empty())
      cv::aruco::refineDetectedMarkers(grey8, cb, marker_corners, marker_ids, rejected);
    if (marker_ids.size() >= 2)
      cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, grey8, cb, *corners, *ids);
  } catch (const cv::Exception& e) {
    corners->clear();
    ids->clear();
  }
  // Enough corners for a pose of their own: 6, not all on one row or column.
  constexpr size_t kMinCorners = 6;
  bool spread = false;
  if (ids->size() >= kMinCorners)
    for (size_t n = 1; n < ids->size() && !spread; ++n)
      spread = (*ids)[n] / board.cols != (*ids)[0] / board.cols &&
               (*ids)[n] % board.cols != (*ids)[0] % board.cols;
  bool valid = spread;
  for (int id : *ids) valid = valid && id >= 0 && id < board.num_corners();
  if (!valid) {
    std::ostringstream o;
    o << "no " << board.ToString() << " ChArUco board found (" << marker_ids.size() << " markers, "
      << ids->size() << " corners; expected >= " << kMinCorners
      << " corners over more than one row; is the board description right?)";
    *why = o.str();
    return false;
  }
  return true;
}

}  // namespace

void CalibrateOptions::Check() const {
  if (homography_half_window_px < 3 || homography_half_window_px > 200)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "homography half window: expected 3..200 px, got " << homography_half_window_px);
  if (!(min_window_fraction > 0 && min_window_fraction <= 1))
    MESOSCAN_THROW(ErrorKind::kUsage, "min window fraction: expected (0, 1]");
  if (!(min_modulation >= 0 && min_modulation < 1))
    MESOSCAN_THROW(ErrorKind::kUsage, "min modulation: expected [0, 1)");
  if (!(min_code_confidence >= 0 && min_code_confidence <= 1))
    MESOSCAN_THROW(ErrorKind::kUsage, "min code confidence: expected [0, 1]");
  if (!(frame_sigma > 0)) MESOSCAN_THROW(ErrorKind::kUsage, "frame sigma: expected > 0");
  if (!(outlier_view_factor > 1))
    MESOSCAN_THROW(ErrorKind::kUsage, "outlier view factor: expected > 1");
  if (min_views < 3) MESOSCAN_THROW(ErrorKind::kUsage, "min views: expected >= 3");
  if (!(outlier_corner_sigmas > 3))
    MESOSCAN_THROW(ErrorKind::kUsage, "outlier corner sigmas: expected > 3");
  if (!(poor_coverage > 0 && poor_coverage <= 1))
    MESOSCAN_THROW(ErrorKind::kUsage, "poor coverage: expected (0, 1]");
  if (!(held_out_warning_ratio > 1) || !(scatter_warning_ratio > 1) || !(scale_warning_pct > 0))
    MESOSCAN_THROW(ErrorKind::kUsage, "warning thresholds: expected ratios > 1, a scale > 0");
}

void CalibrateOptions::ParseFix(const std::string& list) {
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item == "k2")
      fix_k2 = true;
    else if (item == "k3")
      fix_k3 = true;
    else if (item == "tangential")
      fix_tangential = true;
    else if (!item.empty())
      MESOSCAN_BAD_OPTION(
          "CalibrateOptions.fix",
          "'" << item << "': expected a comma-separated list of k2, k3, tangential");
  }
}

void CalibrateOptions::ParseModel(const std::string& text) {
  if (text == "auto")
    model = CalibrationModel::kAuto;
  else if (text == "none")
    model = CalibrationModel::kNone;
  else if (text == "k1")
    model = CalibrationModel::kK1;
  else if (text == "k1k2")
    model = CalibrationModel::kK1K2;
  else if (text == "full")
    model = CalibrationModel::kFull;
  else
    MESOSCAN_BAD_OPTION("CalibrateOptions.model",
                        "'" << text << "': expected auto, none, k1, k1k2 or full");
}

ProjectorCoordinates DecodeProjectorCoordinates(const Session& session,
                                                const std::vector<uint32_t>& pixels,
                                                const CalibrateOptions& options) {
  ProjectorCoordinates pc;
  if (HasCodedFrames(session)) {
    const CodedBoardFrames coded(session);
    coded.Decode(pixels, options.min_code_confidence, &pc.u, &pc.v);
    pc.eight_bit_frames = coded.eight_bit_frames();
    return pc;
  }
  const ViewFrames vf = PlanView(session);
  const FrameStack stack = LoadFrames(session, vf.session_frames, FrameLoadOptions());
  DecodeAt(stack, vf, pixels, options, &pc.u, &pc.v);
  pc.eight_bit_frames = stack.eight_bit_frames();
  return pc;
}

CalibrationView DetectView(const Session& session, const CalibrateOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  CalibrationView view;
  view.name = session.root.string();
  const int W = session.rig.camera.width, H = session.rig.camera.height;
  view.width = W;
  view.height = H;
  view.projector_width = session.rig.projector.width;
  view.projector_height = session.rig.projector.height;
  // The projector's patterns: sines along both axes (decoded here), or a Gray code alone or
  // ordering a sine period (the reconstruction's codecs, calibration/calibrate_codecs.h).
  std::optional<CodedBoardFrames> coded;
  ViewFrames vf;
  FrameStack stack;
  if (HasCodedFrames(session)) {
    coded.emplace(session);
    view.codec = coded->codec();
  } else {
    vf = PlanView(session);
    stack = LoadFrames(session, vf.session_frames, FrameLoadOptions());
    view.codec = "sine";
  }

  // 1. Texture: the white frame, else the mean of a full phase set.
  cv::Mat texture(H, W, CV_32F);
  if (coded) {
    const std::vector<float> t = coded->Texture();
    std::copy(t.begin(), t.end(), texture.ptr<float>());
  } else {
    float* t = texture.ptr<float>();
    ParallelForRows(H, [&](int y0, int y1) {
      for (size_t i = static_cast<size_t>(y0) * W; i < static_cast<size_t>(y1) * W; ++i) {
        if (vf.white >= 0) {
          t[i] = stack.Value(vf.white, i);
          continue;
        }
        float s = 0;
        for (int k : vf.texture_set) s += stack.Value(k, i);
        t[i] = s / vf.texture_set.size();
      }
    });
  }
  // 8-bit for the detector: 0 .. the 99.5th percentile.
  cv::Mat grey8;
  {
    std::vector<float> sample;
    for (int y = 0; y < H; y += 4)
      for (int x = 0; x < W; x += 4) sample.push_back(texture.at<float>(y, x));
    std::nth_element(sample.begin(), sample.begin() + sample.size() * 995 / 1000, sample.end());
    const float hi = std::max(1e-6f, sample[sample.size() * 995 / 1000]);
    texture.convertTo(grey8, CV_8U, 255.0 / hi);
  }

  // 2. Corners: findChessboardCornersSB (checker) or ArUco markers and the ChArUco corners they
  //    identify (any subset of the board), refined by cornerSubPix on the float texture.
  const CalibrationBoard& board = options.board;
  const int nc = board.num_corners();
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;  // board corner index of each entry of `corners`
  if (board.charuco()) {
    std::string why;
    if (!DetectCharuco(board, grey8, &corners, &ids, &why)) {
      view.problem = why;
      view.decode_seconds = Seconds(t0);
      return view;
    }
  } else {
    const cv::Size pattern(board.cols, board.rows);
    bool found = false;
    try {
      found = cv::findChessboardCornersSB(grey8, pattern, corners,
                                          cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE);
    } catch (const cv::Exception& e) {
      found = false;
    }
    if (!found || static_cast<int>(corners.size()) != nc) {
      // A checkerboard partly out of view cannot be labelled (no corner is identified): the
      // view is skipped; a ChArUco board works there.
      view.problem = "no " + std::to_string(board.cols) + "x" + std::to_string(board.rows) +
                     " checkerboard found (inner corners; is the board description right and the "
                     "whole board in view? a ChArUco board may be partly out of view)";
      view.decode_seconds = Seconds(t0);
      return view;
    }
    NormaliseOrder(board, texture, &corners);
    ids.resize(nc);
    std::iota(ids.begin(), ids.end(), 0);
  }
  // Half the smallest corner spacing bounds the refinement window.
  {
    std::vector<Vec2d> at(nc, Vec2d(kNaN, kNaN));
    for (size_t n = 0; n < ids.size(); ++n) at[ids[n]] = Vec2d(corners[n].x, corners[n].y);
    double spacing = 1e30;
    for (int j = 0; j < board.rows; ++j)
      for (int i = 0; i < board.cols; ++i) {
        const Vec2d& a = at[j * board.cols + i];
        if (i + 1 < board.cols && (at[j * board.cols + i + 1] - a).allFinite())
          spacing = std::min(spacing, (at[j * board.cols + i + 1] - a).norm());
        if (j + 1 < board.rows && (at[(j + 1) * board.cols + i] - a).allFinite())
          spacing = std::min(spacing, (at[(j + 1) * board.cols + i] - a).norm());
      }
    if (options.refine_corners && spacing < 1e30) {
      const int win = std::clamp(static_cast<int>(spacing / 4), 2, 11);
      cv::Mat smooth;
      cv::GaussianBlur(texture, smooth, cv::Size(0, 0), 0.7);
      cv::cornerSubPix(
          smooth, corners, cv::Size(win, win), cv::Size(-1, -1),
          cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
    }
  }
  view.found = true;
  view.camera_px.assign(nc, Vec2d(kNaN, kNaN));
  for (size_t n = 0; n < ids.size(); ++n)
    view.camera_px[ids[n]] = Vec2d(corners[n].x, corners[n].y);

  // 3. Decode (u, v) in a window around each corner, one homography per corner (Moreno & Taubin
  //    2012), fitted with LMEDS (least median of squares: half the window may be wrong).
  const int hw = options.homography_half_window_px;
  std::vector<uint8_t> mask(static_cast<size_t>(W) * H, 0);
  for (const auto& c : view.camera_px) {
    if (!c.allFinite()) continue;
    const int cx = static_cast<int>(std::lround(c.x())), cy = static_cast<int>(std::lround(c.y()));
    for (int y = std::max(0, cy - hw); y <= std::min(H - 1, cy + hw); ++y)
      for (int x = std::max(0, cx - hw); x <= std::min(W - 1, cx + hw); ++x)
        mask[static_cast<size_t>(y) * W + x] = 1;
  }
  std::vector<uint32_t> pixels;
  std::vector<int32_t> index(mask.size(), -1);
  for (size_t i = 0; i < mask.size(); ++i)
    if (mask[i]) {
      index[i] = static_cast<int32_t>(pixels.size());
      pixels.push_back(static_cast<uint32_t>(i));
    }
  std::vector<float> u, v;
  if (coded)
    coded->Decode(pixels, options.min_code_confidence, &u, &v);
  else
    DecodeAt(stack, vf, pixels, options, &u, &v);
  view.projector_px.assign(nc, Vec2d(kNaN, kNaN));
  view.projector_inliers.assign(nc, 0);
  ParallelFor(nc, [&](int64_t k) {
    const Vec2d c = view.camera_px[k];
    if (!c.allFinite()) return;
    const int cx = static_cast<int>(std::lround(c.x())), cy = static_cast<int>(std::lround(c.y()));
    std::vector<cv::Point2d> src, dst;
    int area = 0;
    for (int y = cy - hw; y <= cy + hw; ++y)
      for (int x = cx - hw; x <= cx + hw; ++x) {
        ++area;
        if (x < 0 || y < 0 || x >= W || y >= H) continue;
        const int32_t n = index[static_cast<size_t>(y) * W + x];
        if (n < 0 || !std::isfinite(u[n]) || !std::isfinite(v[n])) continue;
        // Centred on the corner: better conditioned homographies.
        src.emplace_back(x - c.x(), y - c.y());
        dst.emplace_back(u[n], v[n]);
      }
    if (static_cast<double>(src.size()) < options.min_window_fraction * area || src.size() < 8)
      return;
    cv::Mat inliers;
    cv::Mat h = cv::findHomography(src, dst, cv::LMEDS, 3.0, inliers);
    if (h.empty()) return;
    const double w = h.at<double>(2, 2);
    if (!(std::abs(w) > 1e-12)) return;
    view.projector_px[k] = Vec2d(h.at<double>(0, 2) / w, h.at<double>(1, 2) / w);
    view.projector_inliers[k] = cv::countNonZero(inliers);
  });
  view.decode_seconds = Seconds(t0);
  return view;
}

namespace {

double Rms(const std::vector<Vec2d>& r) {
  double s = 0;
  int n = 0;
  for (const auto& v : r)
    if (v.allFinite()) {
      s += v.squaredNorm();
      ++n;
    }
  return n ? std::sqrt(s / n) : 0.0;
}

Json DeviceParamsJson(const DeviceParams& d) {
  return {{"fx", d.intr[0]},
          {"fy", d.intr[1]},
          {"cx", d.intr[2]},
          {"cy", d.intr[3]},
          {"distortion", std::vector<double>(d.dist.begin(), d.dist.end())}};
}

// OpenCV's own joint refinement (stereoCalibrate with every intrinsic free, from its per-device
// calibrations), for the baseline figures.
Json OpenCvJoint(const std::vector<const CalibrationView*>& views, const CalibrationBoard& board,
                 const BundleParams& init, int cv_flags) {
  std::vector<std::vector<cv::Point3f>> obj;
  std::vector<std::vector<cv::Point2f>> img_cam, img_prj;
  for (const auto* v : views) {
    std::vector<cv::Point3f> o;
    std::vector<cv::Point2f> c, p;
    for (int k = 0; k < board.num_corners(); ++k) {
      if (!v->camera_px[k].allFinite() || !v->projector_px[k].allFinite()) continue;
      const Vec3d x = board.Corner(k);
      o.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      c.emplace_back(static_cast<float>(v->camera_px[k].x()),
                     static_cast<float>(v->camera_px[k].y()));
      p.emplace_back(static_cast<float>(v->projector_px[k].x()),
                     static_cast<float>(v->projector_px[k].y()));
    }
    obj.push_back(o);
    img_cam.push_back(c);
    img_prj.push_back(p);
  }
  auto mat = [](const DeviceParams& d, cv::Mat* k, cv::Mat* dist) {
    *k = (cv::Mat_<double>(3, 3) << d.intr[0], 0, d.intr[2], 0, d.intr[1], d.intr[3], 0, 0, 1);
    *dist = cv::Mat(1, 5, CV_64F);
    for (int i = 0; i < 5; ++i) dist->at<double>(i) = d.dist[i];
  };
  cv::Mat kc, dc, kp, dp, r, t, e, f;
  mat(init.cam, &kc, &dc);
  mat(init.prj, &kp, &dp);
  double rms = 0;
  try {
    rms = cv::stereoCalibrate(obj, img_cam, img_prj, kc, dc, kp, dp,
                              cv::Size(init.cam.width, init.cam.height), r, t, e, f,
                              cv::CALIB_USE_INTRINSIC_GUESS | cv_flags);
  } catch (const cv::Exception& ex) {
    return {{"error", ex.err}};
  }
  Mat3d rm;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) rm(a, b) = r.at<double>(a, b);
  const Vec3d tv(t.at<double>(0), t.at<double>(1), t.at<double>(2));
  auto dev = [](const cv::Mat& k, const cv::Mat& d, int w, int h) {
    DeviceParams p;
    p.width = w;
    p.height = h;
    p.intr = {k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2), k.at<double>(1, 2)};
    for (int i = 0; i < 5 && i < static_cast<int>(d.total()); ++i) p.dist[i] = d.at<double>(i);
    return DeviceParamsJson(p);
  };
  return {{"rms_px", rms},
          {"camera", dev(kc, dc, init.cam.width, init.cam.height)},
          {"projector", dev(kp, dp, init.prj.width, init.prj.height)},
          {"baseline_m", tv.norm()},
          {"prj_from_cam_rotation_deg", Eigen::AngleAxisd(rm).angle() * 180.0 / std::numbers::pi},
          {"prj_from_cam_translation_m", {tv.x(), tv.y(), tv.z()}}};
}

unsigned FixedTerms(const CalibrateOptions& o) {
  unsigned t = 0;
  if (o.fix_k2) t |= DeviceModel::kK2;
  if (o.fix_k3) t |= DeviceModel::kK3;
  if (o.fix_tangential) t |= DeviceModel::kTangential;
  return t;
}

// The most flexible model the options allow (the noise estimate's, and the ladder's top).
DeviceModel TopModel(const CalibrateOptions& o) {
  DeviceModel m;
  m.terms &= ~FixedTerms(o);
  m.free_principal_point = !o.fix_principal_point;
  return m;
}

// --model k1|k1k2|full|none (not auto): that distortion model less --fix, the principal point
// free unless --fix-principal-point, fx and fy.
DeviceModel ModelFromOptions(const CalibrateOptions& o) {
  DeviceModel m = TopModel(o);
  switch (o.model) {
    case CalibrationModel::kNone:
      m.terms = 0;
      break;
    case CalibrationModel::kK1:
      m.terms = DeviceModel::kK1;
      break;
    case CalibrationModel::kK1K2:
      m.terms = DeviceModel::kK1 | DeviceModel::kK2;
      break;
    case CalibrationModel::kAuto:
    case CalibrationModel::kFull:
      break;
  }
  m.terms &= ~FixedTerms(o);
  return m;
}

// The distortion ladder: none, k1, k1 k2, + tangential, + k3, less the --fix terms.
std::vector<unsigned> LadderTerms(const CalibrateOptions& o) {
  using M = DeviceModel;
  const unsigned fixed = FixedTerms(o);
  std::vector<unsigned> out;
  for (unsigned t : {0u, unsigned{M::kK1}, M::kK1 | M::kK2, M::kK1 | M::kK2 | M::kTangential,
                     M::kK1 | M::kK2 | M::kTangential | M::kK3}) {
    const unsigned u = t & ~fixed;
    if (std::find(out.begin(), out.end(), u) == out.end()) out.push_back(u);
  }
  return out;
}

// Of candidates scored by leave-one-view-out, the simplest whose held-out chi^2 exceeds the
// best's by no more than the standard error of the per-view differences (the one-standard-error
// rule on paired folds). Every candidate's figures go to `log`.
template <typename Eval>
DeviceModel ChooseModel(const std::vector<DeviceModel>& cands, Eval&& eval,
                        const std::string& device, const std::string& stage, Json* log) {
  std::vector<const CrossValidation*> cv;
  for (const auto& c : cands) cv.push_back(&eval(c));
  size_t best = 0;
  for (size_t i = 1; i < cv.size(); ++i)
    if (cv[i]->chi2 < cv[best]->chi2) best = i;
  const size_t n = cv[best]->held_out.size();
  std::vector<double> excess(cv.size(), 0.0), se(cv.size(), 0.0);
  size_t pick = best;
  for (size_t i = 0; i < cv.size(); ++i) {
    double s = 0, s2 = 0;
    for (size_t j = 0; j < n; ++j) {
      const double d = cv[i]->held_out[j].chi2 - cv[best]->held_out[j].chi2;
      s += d;
      s2 += d * d;
    }
    const double mean = s / n;
    const double var = n > 1 ? std::max(0.0, (s2 - n * mean * mean) / (n - 1)) : 0.0;
    excess[i] = mean;
    se[i] = std::sqrt(var / n);
    const bool ok = mean <= se[i];
    const int fi = cands[i].FreeParameters(), fp = cands[pick].FreeParameters();
    if (ok && (fi < fp || (fi == fp && cv[i]->chi2 < cv[pick]->chi2))) pick = i;
  }
  for (size_t i = 0; i < cv.size(); ++i) {
    const HeldOutSummary s = SummariseHeldOut(cv[i]->held_out);
    const DeviceModel& m = cands[i];
    const std::string label = stage == "distortion" ? m.TermsString()
                              : stage == "principal point"
                                  ? (m.free_principal_point ? "free" : "centre")
                                  : (m.equal_focal ? "fx = fy" : "fx, fy");
    log->push_back({{"device", device},
                    {"stage", stage},
                    {"label", label},
                    {"model", cands[i].ToString()},
                    {"held_out_error_over_noise", std::sqrt(cv[i]->Chi2PerResidual())},
                    {"free_parameters", cands[i].FreeParameters()},
                    {"held_out_chi2_per_residual", cv[i]->Chi2PerResidual()},
                    {"held_out_rms_camera_px", s.rms_camera_px},
                    {"held_out_rms_projector_px", s.rms_projector_px},
                    {"held_out_adjacent_distance_rms_um", s.adjacent_rms_um},
                    {"held_out_max_abs_scale_error_pct", s.max_abs_scale_error_pct},
                    {"excess_chi2_per_view_over_best", excess[i]},
                    {"standard_error", se[i]},
                    {"chosen", i == pick}});
  }
  return cands[pick];
}

// RMS reprojection residual of each device over the views (px).
void ResidualRms(const std::vector<const CalibrationView*>& views, const CalibrationBoard& board,
                 const BundleParams& p, double* cam_rms, double* prj_rms) {
  const PinholeCamera cam = p.cam.Camera(), prj = p.prj.Camera();
  const Rigid3d prj_from_cam = p.PrjFromCam();
  double sc = 0, sp = 0;
  int nc = 0, np = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const Rigid3d cam_from_board = PoseFromArray(p.cam_from_board[i].data());
    for (int k = 0; k < board.num_corners(); ++k) {
      const Vec3d pc = cam_from_board * board.Corner(k);
      Vec2d uv;
      if (views[i]->camera_px[k].allFinite() && cam.ProjectDevice(pc.data(), uv.data())) {
        sc += (views[i]->camera_px[k] - uv).squaredNorm();
        ++nc;
      }
      const Vec3d pp = prj_from_cam * pc;
      if (views[i]->projector_px[k].allFinite() && prj.ProjectDevice(pp.data(), uv.data())) {
        sp += (views[i]->projector_px[k] - uv).squaredNorm();
        ++np;
      }
    }
  }
  *cam_rms = nc ? std::sqrt(sc / nc) : 0.0;
  *prj_rms = np ? std::sqrt(sp / np) : 0.0;
}

// The fitted parameters by JSON pointer ("/camera/fx", "/camera/distortion/k1",
// "/prj_from_cam/tx_m"), held ones left out.
std::vector<std::pair<std::string, double>> NamedParameters(const BundleParams& p,
                                                            const DeviceModel& cm,
                                                            const DeviceModel& pm) {
  std::vector<std::pair<std::string, double>> out;
  const char* dn[5] = {"k1", "k2", "p1", "p2", "k3"};
  const unsigned bit[5] = {DeviceModel::kK1, DeviceModel::kK2, DeviceModel::kTangential,
                           DeviceModel::kTangential, DeviceModel::kK3};
  for (int d = 0; d < 2; ++d) {
    const DeviceParams& q = d ? p.prj : p.cam;
    const DeviceModel& m = d ? pm : cm;
    const std::string dev = d ? "/projector/" : "/camera/";
    out.emplace_back(dev + "fx", q.intr[0]);
    out.emplace_back(dev + "fy", q.intr[1]);
    if (m.free_principal_point) {
      out.emplace_back(dev + "cx", q.intr[2]);
      out.emplace_back(dev + "cy", q.intr[3]);
    }
    for (int i = 0; i < 5; ++i)
      if (m.terms & bit[i]) out.emplace_back(dev + "distortion/" + dn[i], q.dist[i]);
  }
  const char* pn[6] = {"rx_rad", "ry_rad", "rz_rad", "tx_m", "ty_m", "tz_m"};
  for (int i = 0; i < 6; ++i)
    out.emplace_back(std::string("/prj_from_cam/") + pn[i], p.prj_from_cam[i]);
  return out;
}

// The reported 1-sigma: the larger of the least-squares sigma (covariance scaled by each
// device's residual variance) and the scatter of the leave-one-view-out fits (their standard
// deviation: how far the rig moves when one view more or fewer is used), which sees what the
// residuals do not: views that disagree beyond their noise, a model that fits each subset
// differently. Also kept: the jackknife, sigma_J^2 = (n - 1) / n sum (theta_i - mean)^2 (Efron &
// Stein 1981), the all-view estimate's sigma when the views' disagreement dominates, (n - 1) /
// sqrt(n) times the scatter.
Json Uncertainties(const std::vector<const CalibrationView*>& views, const CalibrationBoard& board,
                   const CrossValidation& cv) {
  const Json cov = BundleCovariance(views, board, cv.cam, cv.prj, cv.all);
  const auto named = NamedParameters(cv.all, cv.cam, cv.prj);
  const size_t n = cv.folds.size();
  Json jack, scatter, out;
  for (size_t k = 0; k < named.size(); ++k) {
    double mean = 0;
    std::vector<double> v;
    for (const auto& f : cv.folds) v.push_back(NamedParameters(f, cv.cam, cv.prj)[k].second);
    for (double x : v) mean += x / n;
    double ss = 0;
    for (double x : v) ss += (x - mean) * (x - mean);
    const Json::json_pointer ptr(named[k].first);
    jack[ptr] = std::sqrt((n - 1.0) / n * ss);
    scatter[ptr] = n > 1 ? std::sqrt(ss / (n - 1)) : 0.0;
    const double ls = cov.contains(ptr) ? cov[ptr].get<double>() : 0.0;
    out[ptr] = std::max(ls, scatter[ptr].get<double>());
  }
  out["least_squares"] = cov;
  out["jackknife"] = jack;
  out["fold_scatter"] = scatter;
  if (cov.contains("residual_sigma_px")) out["residual_sigma_px"] = cov["residual_sigma_px"];
  if (cov.contains("error")) out["error"] = cov["error"];
  out["note"] =
      "1-sigma: the larger of the least-squares sigma (scaled by each device's residuals) and "
      "fold_scatter, the standard deviation of the leave-one-view-out fits; jackknife: the "
      "all-view estimate's sigma from the folds (Efron & Stein)";
  return out;
}

// Each device's calibrated region (the views' corner hulls) and its coverage of the field both
// devices share on the boards' mean plane.
void MeasureCoverages(const std::vector<const CalibrationView*>& views, const BundleParams& fit,
                      const CalibrateOptions& options, CalibrationResult* result) {
  CalibratedRegion cr, pr;
  cr.width = fit.cam.width;
  cr.height = fit.cam.height;
  pr.width = fit.prj.width;
  pr.height = fit.prj.height;
  Vec3d centre = Vec3d::Zero(), normal = Vec3d::Zero();
  for (size_t i = 0; i < views.size(); ++i) {
    auto h = ConvexHull(views[i]->camera_px);
    if (!h.empty()) cr.hulls.push_back(std::move(h));
    h = ConvexHull(views[i]->projector_px);
    if (!h.empty()) pr.hulls.push_back(std::move(h));
    const Rigid3d cam_from_board = PoseFromArray(fit.cam_from_board[i].data());
    centre += cam_from_board.translation / views.size();
    Vec3d nb = cam_from_board.rotation.col(2);
    if (nb.z() > 0) nb = -nb;  // towards the camera
    normal += nb;
  }
  normal.normalize();
  const PinholeCamera cam = fit.cam.Camera(), prj = fit.prj.Camera();
  const Rigid3d prj_from_cam = fit.PrjFromCam(), cam_from_prj = prj_from_cam.Inverse();
  auto inside = [](const PinholeCamera& c, const Vec3d& p) {
    Vec2d uv;
    return c.ProjectDevice(p.data(), uv.data()) && uv.x() >= -0.5 && uv.y() >= -0.5 &&
           uv.x() <= c.width - 0.5 && uv.y() <= c.height - 0.5;
  };
  // The point of the mean plane on the ray o + t d (camera frame), if in front.
  auto on_plane = [&](const Vec3d& o, const Vec3d& d, Vec3d* x) {
    const double den = normal.dot(d);
    if (std::abs(den) < 1e-9) return false;
    const double t = normal.dot(centre - o) / den;
    if (!(t > 0)) return false;
    *x = o + t * d;
    return true;
  };
  const DeviceCoverage c = MeasureCoverage(
      "camera", cr,
      [&](const Vec2d& px) {
        const Vec2d n = cam.UndistortNormalized(px);
        Vec3d x;
        return on_plane(Vec3d::Zero(), Vec3d(n.x(), n.y(), 1.0), &x) &&
               inside(prj, prj_from_cam * x);
      },
      options.poor_coverage);
  const DeviceCoverage p = MeasureCoverage(
      "projector", pr,
      [&](const Vec2d& px) {
        const Vec2d n = prj.UndistortNormalized(px);
        Vec3d x;
        return on_plane(cam_from_prj.translation, cam_from_prj.rotation * Vec3d(n.x(), n.y(), 1.0),
                        &x) &&
               inside(cam, x);
      },
      options.poor_coverage);
  result->camera_region = cr;
  result->projector_region = pr;
  result->coverage = {c, p};
}

// Warning lines (report.json "warnings"; `calibrate --strict` exits 3 on any).
void AddWarnings(const CalibrateOptions& options, const CrossValidation& cv, double sigma_cam,
                 double sigma_prj, CalibrationResult* result) {
  std::vector<std::string>& w = result->warnings;
  for (const auto& c : result->coverage)
    if (c.poor) w.push_back(c.device + ": " + c.advice);
  // A fitted term no better determined than its own size.
  const Json& u = result->uncertainties;
  for (const auto& [path, value] : NamedParameters(cv.all, cv.cam, cv.prj)) {
    if (path.find("/distortion/") == std::string::npos) continue;
    const Json::json_pointer ptr(path);
    if (!u.contains(ptr)) continue;
    const double sd = u[ptr].get<double>();
    if (sd > std::abs(value)) {
      const std::string dev = path.substr(1, path.find('/', 1) - 1);
      const std::string term = path.substr(path.rfind('/') + 1);
      std::ostringstream o;
      o << std::setprecision(3) << dev << " " << term << " = " << value << " +- " << sd
        << ": not determined by these views (the model extrapolates it); add views reaching the "
           "image edges, or --fix "
        << (term == "p1" || term == "p2" ? "tangential" : term);
      w.push_back(o.str());
    }
  }
  // Held-out views that the fit without them does not predict to within their noise.
  for (const auto& h : cv.held_out) {
    const int n = 2 * (h.camera_corners + h.projector_corners);
    if (n == 0) continue;
    const double ratio = std::sqrt(h.chi2 / n);
    if (ratio > options.held_out_warning_ratio) {
      std::ostringstream o;
      o << std::setprecision(3) << h.name << ": held out, its corners reproject at " << ratio
        << "x their noise (camera " << h.rms_camera_px << " px, projector " << h.rms_projector_px
        << " px, noise " << sigma_cam * std::sqrt(2.0) << " / " << sigma_prj * std::sqrt(2.0)
        << " px): the views disagree beyond their noise (a board that moved or bent during the "
           "session, a wrong --board?)";
      w.push_back(o.str());
    }
  }
  for (const auto& h : cv.held_out)
    if (h.triangulated >= 4 && std::abs(h.scale_error_pct) > options.scale_warning_pct) {
      std::ostringstream o;
      o << std::setprecision(3) << h.name << ": held out, its board triangulates "
        << h.scale_error_pct << "% off in scale (adjacent corners " << h.adjacent_rms_um
        << " um RMS): the rig without it does not predict it";
      w.push_back(o.str());
    }
  // Intrinsics whose leave-one-view-out fits scatter far beyond their least-squares sigma.
  if (u.contains("least_squares") && u.contains("jackknife"))
    for (const char* dev : {"camera", "projector"})
      for (const char* k : {"fx", "cx", "cy"}) {
        const Json::json_pointer ptr(std::string("/") + dev + "/" + k);
        if (!u["least_squares"].contains(ptr) || !u["jackknife"].contains(ptr)) continue;
        const double ls = u["least_squares"][ptr].get<double>();
        const double jk = u["jackknife"][ptr].get<double>();
        if (ls > 0 && jk > options.scatter_warning_ratio * ls) {
          std::ostringstream o;
          o << std::setprecision(3) << dev << " " << k << ": the fits without one view scatter "
            << jk / ls << "x its least-squares sigma (jackknife " << jk << " px against " << ls
            << " px): the views disagree beyond their noise";
          w.push_back(o.str());
        }
      }
}

}  // namespace

namespace {

// The views in the adjustment: every found view with enough projector corners, then the mount
// board if given. Bad input: too few usable views, a mount without its board, every view at
// one pose.
std::vector<CalibrationView*> SelectViews(std::vector<CalibrationView>& views,
                                          std::optional<CalibrationView>& mount,
                                          const CalibrateOptions& options, size_t* n_regular) {
  const int nc = options.board.num_corners();
  std::vector<CalibrationView*> used;
  for (auto& v : views) {
    if (!v.found) continue;
    int np = 0, ncam = 0;
    for (const auto& p : v.projector_px) np += p.allFinite();
    for (const auto& p : v.camera_px) ncam += p.allFinite();
    if (np < std::max(6, ncam / 4)) {
      v.problem = "the projector was decoded at only " + std::to_string(np) + " of " +
                  std::to_string(ncam) + " corners";
      continue;
    }
    used.push_back(&v);
  }
  *n_regular = used.size();
  if (static_cast<int>(used.size()) < options.min_views) {
    std::ostringstream o;
    o << "calibrate: " << used.size() << " of " << views.size()
      << " views usable, expected at least " << options.min_views;
    for (const auto& v : views)
      if (!v.problem.empty()) {
        o << "; " << v.name << ": " << v.problem;
        break;
      }
    MESOSCAN_BAD_INPUT(o.str());
  }
  if (mount) {
    if (!mount->found)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(mount->name), "mount view: " << mount->problem);
    used.push_back(&*mount);
  }
  // Degenerate: every view at one pose (the camera's corners move less than a pixel).
  double spread = 0;
  for (const auto* v : used)
    for (int k = 0; k < nc; ++k)
      if ((v->camera_px[k] - used[0]->camera_px[k]).allFinite())
        spread = std::max(spread, (v->camera_px[k] - used[0]->camera_px[k]).norm());
  if (spread < 1.0)
    MESOSCAN_BAD_INPUT("calibrate: all " << used.size()
                                         << " views show the board at one pose (corners move "
                                         << spread
                                         << " px), expected views at different tilts "
                                            "and positions (degenerate)");
  return used;
}

// OpenCV's flags for the --fix terms.
int OpenCvFlags(const CalibrateOptions& options) {
  int flags = 0;
  if (options.fix_k2) flags |= cv::CALIB_FIX_K2;
  if (options.fix_k3) flags |= cv::CALIB_FIX_K3;
  if (options.fix_tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  return flags;
}

// OpenCV: calibrateCamera per device, stereoCalibrate: the initial values, and the plain
// baseline the report shows (its model as --fix says, else OpenCV's k1 k2 p1 p2 k3).
BundleParams OpenCvStart(const std::vector<const CalibrationView*>& views,
                         const CalibrationBoard& board, const Rig& size_rig, int cv_flags,
                         Json* report) {
  double rms_cam = 0, rms_prj = 0, rms_stereo = 0;
  const BundleParams init = OpenCvCalibration(
      views, -1, board, size_rig.camera.width, size_rig.camera.height, size_rig.projector.width,
      size_rig.projector.height, cv_flags, &rms_cam, &rms_prj, &rms_stereo);
  *report = {{"note",
              "cv::calibrateCamera per device, cv::stereoCalibrate with "
              "CALIB_FIX_INTRINSIC; joint: stereoCalibrate refining everything"},
             {"rms_camera_px", rms_cam},
             {"rms_projector_px", rms_prj},
             {"rms_stereo_px", rms_stereo},
             {"camera", DeviceParamsJson(init.cam)},
             {"projector", DeviceParamsJson(init.prj)},
             {"joint", OpenCvJoint(views, board, init, cv_flags)}};
  return init;
}

// The corners' noise per coordinate and device: the residuals of the most flexible model the
// options allow, fitted from `start` (*fit).
void CornerNoise(const std::vector<const CalibrationView*>& views, const CalibrationBoard& board,
                 const DeviceModel& top, BundleParams* fit, double* sigma_cam, double* sigma_prj) {
  BundleSolveOptions so;
  so.threads = 2;
  const BundleSolveSummary s = SolveBundle(views, -1, board, top, top, so, fit);
  if (!s.usable) MESOSCAN_BAD_INPUT("calibrate: the bundle adjustment failed: " << s.brief);
  ResidualRms(views, board, *fit, sigma_cam, sigma_prj);
  // Per coordinate (a corner's residual has two).
  *sigma_cam = std::max(*sigma_cam / std::sqrt(2.0), 1e-4);
  *sigma_prj = std::max(*sigma_prj / std::sqrt(2.0), 1e-4);
}

// Corners the fit of the most flexible model does not explain: a residual beyond
// `threshold` robust sigmas of its device (the median absolute residual per coordinate / 0.6745),
// e.g. a projector corner whose fringe order was misread or a corner on a smudge. They are
// removed from the views (NaN) and counted per device, and the fit and the noise redone.
std::array<int, 2> RejectOutlierCorners(const std::vector<CalibrationView*>& used,
                                        const CalibrationBoard& board, const BundleParams& fit,
                                        double threshold) {
  const PinholeCamera cam = fit.cam.Camera(), prj = fit.prj.Camera();
  const Rigid3d prj_from_cam = fit.PrjFromCam();
  struct Residual {
    CalibrationView* view;
    int corner;
    bool projector;
    double norm;
  };
  std::vector<Residual> res;
  std::array<std::vector<double>, 2> coords;
  for (size_t i = 0; i < used.size(); ++i) {
    const Rigid3d cam_from_board = PoseFromArray(fit.cam_from_board[i].data());
    for (int k = 0; k < board.num_corners(); ++k) {
      const Vec3d pc = cam_from_board * board.Corner(k), pp = prj_from_cam * pc;
      Vec2d uv;
      for (int d = 0; d < 2; ++d) {
        const Vec2d& obs = d ? used[i]->projector_px[k] : used[i]->camera_px[k];
        if (!obs.allFinite() || !(d ? prj : cam).ProjectDevice((d ? pp : pc).data(), uv.data()))
          continue;
        const Vec2d r = obs - uv;
        res.push_back({used[i], k, d == 1, r.norm()});
        coords[d].push_back(std::abs(r.x()));
        coords[d].push_back(std::abs(r.y()));
      }
    }
  }
  std::array<double, 2> sigma{};
  for (int d = 0; d < 2; ++d) {
    if (coords[d].empty()) continue;
    auto mid = coords[d].begin() + coords[d].size() / 2;
    std::nth_element(coords[d].begin(), mid, coords[d].end());
    sigma[d] = *mid / 0.6745;
  }
  std::array<int, 2> rejected{};
  for (const auto& r : res) {
    const int d = r.projector ? 1 : 0;
    if (!(r.norm > threshold * sigma[d])) continue;
    (r.projector ? r.view->projector_px : r.view->camera_px)[r.corner] = Vec2d(kNaN, kNaN);
    ++rejected[d];
  }
  return rejected;
}

// Each device's model by leave-one-view-out cross-validation, one device at a time, the other
// at its current model (the camera first, the projector at the top model; then the projector
// with the camera's choice). Per device: the distortion terms (principal point free, fx and
// fy), then the principal point, then the aspect; each stage keeps the simplest model that is
// not worse on the held-out views than the best by more than its standard error.
template <typename Run>
void ChooseModels(const CalibrateOptions& options, Run&& run, DeviceModel* cam_model,
                  DeviceModel* prj_model, Json* candidates) {
  *cam_model = *prj_model = TopModel(options);
  for (int d = 0; d < 2; ++d) {
    DeviceModel& m = d ? *prj_model : *cam_model;
    auto eval = [&](const DeviceModel& x) -> const CrossValidation& {
      return d ? run(*cam_model, x) : run(x, *prj_model);
    };
    std::vector<DeviceModel> stage;
    for (unsigned t : LadderTerms(options)) {
      DeviceModel x = m;
      x.terms = t;
      stage.push_back(x);
    }
    const std::string dev = d ? "projector" : "camera";
    m = ChooseModel(stage, eval, dev, "distortion", candidates);
    if (!options.fix_principal_point) {
      DeviceModel x = m;
      x.free_principal_point = !m.free_principal_point;
      m = ChooseModel({x, m}, eval, dev, "principal point", candidates);
    }
    DeviceModel x = m;
    x.equal_focal = !m.equal_focal;
    m = ChooseModel({x, m}, eval, dev, "aspect", candidates);
  }
}

// Every used view's pose and corner residuals under the fit; the RMS figures; views whose
// combined RMS exceeds outlier_view_factor x the median view's are marked, with a warning.
void ViewResiduals(const std::vector<CalibrationView*>& used, const CalibrationBoard& board,
                   const BundleParams& fit, double outlier_view_factor, CalibrationResult* result) {
  const int nc = board.num_corners();
  const PinholeCamera cam = fit.cam.Camera(), prj = fit.prj.Camera();
  const Rigid3d prj_from_cam = fit.PrjFromCam();
  std::vector<Vec2d> all_cam, all_prj;
  for (size_t i = 0; i < used.size(); ++i) {
    CalibrationView& v = *used[i];
    v.cam_from_board = PoseFromArray(fit.cam_from_board[i].data());
    v.camera_residual_px.assign(nc, Vec2d(kNaN, kNaN));
    v.projector_residual_px.assign(nc, Vec2d(kNaN, kNaN));
    for (int k = 0; k < nc; ++k) {
      const Vec3d pc = v.cam_from_board * board.Corner(k);
      Vec2d uv;
      if (v.camera_px[k].allFinite() && cam.ProjectDevice(pc.data(), uv.data()))
        v.camera_residual_px[k] = v.camera_px[k] - uv;
      const Vec3d pp = prj_from_cam * pc;
      if (v.projector_px[k].allFinite() && prj.ProjectDevice(pp.data(), uv.data()))
        v.projector_residual_px[k] = v.projector_px[k] - uv;
    }
    v.rms_camera_px = Rms(v.camera_residual_px);
    v.rms_projector_px = Rms(v.projector_residual_px);
    for (const auto& r : v.camera_residual_px) all_cam.push_back(r);
    for (const auto& r : v.projector_residual_px) all_prj.push_back(r);
  }
  result->rms_camera_px = Rms(all_cam);
  result->rms_projector_px = Rms(all_prj);
  std::vector<Vec2d> both = all_cam;
  both.insert(both.end(), all_prj.begin(), all_prj.end());
  result->rms_stereo_px = Rms(both);
  std::vector<double> rms;
  for (const auto* v : used) rms.push_back(std::hypot(v->rms_camera_px, v->rms_projector_px));
  std::vector<double> sorted = rms;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double median = sorted[sorted.size() / 2];
  for (size_t i = 0; i < used.size(); ++i)
    if (rms[i] > outlier_view_factor * median) {
      used[i]->outlier = true;
      MESOSCAN_LOG(kWarning) << used[i]->name << ": reprojection RMS " << rms[i]
                             << " px is an outlier (median view " << median << " px)";
    }
}

// The chosen models' held-out views (and the rig fitted without each), and OpenCV's
// calibration (k1 k2) held out on the same views and corners.
void Validate(const std::vector<const CalibrationView*>& views, const CalibrationBoard& board,
              const Rig& size_rig, const CrossValidation& chosen, int cv_flags, double sigma_cam,
              double sigma_prj, bool with_opencv, CalibrationResult* result) {
  result->held_out = chosen.held_out;
  result->validation = {
      {"method",
       "leave one view out: the rig fitted without the view (same models), the "
       "view's board pose fitted with that rig held and its corners reprojected; "
       "its corners triangulated as a scan would (camera ray against the "
       "projector column) against the board"},
      {"noise_sigma_px_per_coordinate", {{"camera", sigma_cam}, {"projector", sigma_prj}}},
      {"summary", SummariseHeldOut(chosen.held_out).ToJson()}};
  Json hv = Json::array();
  for (size_t i = 0; i < chosen.held_out.size(); ++i) {
    Json j = chosen.held_out[i].ToJson();
    j["rig_without_it"] = {{"camera", DeviceParamsJson(chosen.folds[i].cam)},
                           {"projector", DeviceParamsJson(chosen.folds[i].prj)}};
    hv.push_back(j);
  }
  result->validation["held_out"] = hv;
  if (!with_opencv) return;
  const int flags = cv_flags | cv::CALIB_FIX_K3 | cv::CALIB_ZERO_TANGENT_DIST;
  try {
    result->opencv_held_out = OpenCvCrossValidate(
        views, board, size_rig.camera.width, size_rig.camera.height, size_rig.projector.width,
        size_rig.projector.height, flags, sigma_cam, sigma_prj);
    Json ov = Json::array();
    for (const auto& h : result->opencv_held_out) ov.push_back(h.ToJson());
    result->validation["opencv"] = {
        {"model",
         "calibrateCamera per device with CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST (k1 "
         "k2, principal point free), stereoCalibrate with CALIB_FIX_INTRINSIC"},
        {"summary", SummariseHeldOut(result->opencv_held_out).ToJson()},
        {"held_out", ov}};
  } catch (const Error& e) {
    result->validation["opencv"] = {{"error", e.what()}};
  }
}

// The rig in the world of `world_view`'s board (the mount board if given, else the first).
Rig RigInBoardWorld(const Rig& size_rig, const BundleParams& fit,
                    const CalibrationView& world_view) {
  const Rigid3d world_from_cam = world_view.cam_from_board.Inverse();
  Rig rig = size_rig;
  rig.uncalibrated = false;
  rig.camera = fit.cam.Camera();
  rig.camera.world_from_device = world_from_cam;
  rig.projector = fit.prj.Camera();
  rig.projector.world_from_device = world_from_cam * fit.PrjFromCam().Inverse();
  return rig;
}

}  // namespace

CalibrationResult Calibrate(std::vector<CalibrationView> views, const Rig& size_rig,
                            const std::optional<CalibrationView>& mount_view,
                            const CalibrateOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  CalibrationResult result;
  const CalibrationBoard& board = options.board;
  std::optional<CalibrationView> mount = mount_view;
  size_t n_regular = 0;
  const std::vector<CalibrationView*> used = SelectViews(views, mount, options, &n_regular);
  const std::vector<const CalibrationView*> cused(used.begin(), used.end());

  const int cv_flags = OpenCvFlags(options);
  BundleParams full = OpenCvStart(cused, board, size_rig, cv_flags, &result.opencv);
  double sigma_cam = 0, sigma_prj = 0;
  CornerNoise(cused, board, TopModel(options), &full, &sigma_cam, &sigma_prj);
  result.corners_rejected = RejectOutlierCorners(used, board, full, options.outlier_corner_sigmas);
  if (result.corners_rejected[0] + result.corners_rejected[1] > 0) {
    MESOSCAN_LOG(kWarning) << "calibrate: " << result.corners_rejected[0] << " camera and "
                           << result.corners_rejected[1]
                           << " projector corner(s) left out: their residuals exceed "
                           << options.outlier_corner_sigmas << " robust sigmas of their device";
    CornerNoise(cused, board, TopModel(options), &full, &sigma_cam, &sigma_prj);
  }

  // Each candidate pair of models cross-validated once.
  std::map<std::string, CrossValidation> cache;
  auto run = [&](const DeviceModel& c, const DeviceModel& p) -> const CrossValidation& {
    const std::string key = c.ToString() + "|" + p.ToString();
    auto it = cache.find(key);
    if (it == cache.end())
      it = cache.emplace(key, CrossValidate(cused, board, c, p, full, sigma_cam, sigma_prj)).first;
    return it->second;
  };
  DeviceModel cam_model = ModelFromOptions(options), prj_model = cam_model;
  result.candidates = Json::array();
  if (options.model == CalibrationModel::kAuto)
    ChooseModels(options, run, &cam_model, &prj_model, &result.candidates);
  const CrossValidation& chosen = run(cam_model, prj_model);
  if (!chosen.all_summary.usable)
    MESOSCAN_BAD_INPUT("calibrate: the bundle adjustment failed: " << chosen.all_summary.brief);
  result.camera_model = cam_model;
  result.projector_model = prj_model;
  result.ceres_brief = chosen.all_summary.brief;

  ViewResiduals(used, board, chosen.all, options.outlier_view_factor, &result);
  result.uncertainties = Uncertainties(cused, board, chosen);
  Validate(cused, board, size_rig, chosen, cv_flags, sigma_cam, sigma_prj, options.validate_opencv,
           &result);
  MeasureCoverages(cused, chosen.all, options, &result);
  AddWarnings(options, chosen, sigma_cam, sigma_prj, &result);

  const CalibrationView& world_view = mount ? *used.back() : *used.front();
  result.world = (mount ? "mount board " : "first board ") + world_view.name;
  result.rig = RigInBoardWorld(size_rig, chosen.all, world_view);
  // The mount view is reported with the others.
  if (mount) views.push_back(*mount);
  result.views = std::move(views);
  result.views_used = static_cast<int>(n_regular);
  result.seconds = Seconds(t0);
  return result;
}

namespace {

Json DeviceJson(const PinholeCamera& c) {
  return {{"fx", c.K(0, 0)},
          {"fy", c.K(1, 1)},
          {"cx", c.K(0, 2)},
          {"cy", c.K(1, 2)},
          {"distortion", std::vector<double>(c.distortion.begin(), c.distortion.end())}};
}

// A PNG of each view's residual vectors (scaled) or corners over one device's image.
void DrawDevice(const CalibrationResult& r, bool projector, bool residuals, const fs::path& path) {
  if (r.views.empty()) return;
  const CalibrationView* first = nullptr;
  for (const auto& v : r.views)
    if (v.found) first = &v;
  if (!first) return;
  const int w = projector ? first->projector_width : first->width;
  const int h = projector ? first->projector_height : first->height;
  const double scale = 1200.0 / std::max(w, h);
  const int cw = std::max(1, static_cast<int>(w * scale)),
            ch = std::max(1, static_cast<int>(h * scale));
  cv::Mat canvas(ch, cw, CV_8UC3, cv::Scalar(255, 255, 255));
  // Residuals are drawn magnified so that the largest is ~5% of the canvas.
  double max_res = 0;
  for (const auto& v : r.views)
    for (const auto& e : projector ? v.projector_residual_px : v.camera_residual_px)
      if (e.allFinite()) max_res = std::max(max_res, e.norm());
  const double gain = max_res > 0 ? 0.05 * cw / max_res : 1.0;
  int vi = 0;
  for (const auto& v : r.views) {
    if (!v.found) continue;
    const cv::Scalar colour(((vi * 97) % 200), ((vi * 57 + 80) % 200), ((vi * 151 + 40) % 200));
    ++vi;
    const auto& pts = projector ? v.projector_px : v.camera_px;
    const auto& res = projector ? v.projector_residual_px : v.camera_residual_px;
    std::vector<cv::Point> hull;
    for (size_t k = 0; k < pts.size(); ++k) {
      if (!pts[k].allFinite()) continue;
      const cv::Point p(static_cast<int>(pts[k].x() * scale), static_cast<int>(pts[k].y() * scale));
      hull.push_back(p);
      if (residuals) {
        if (k < res.size() && res[k].allFinite()) {
          const cv::Point q(static_cast<int>(p.x + res[k].x() * gain),
                            static_cast<int>(p.y + res[k].y() * gain));
          cv::line(canvas, p, q, v.outlier ? cv::Scalar(0, 0, 255) : colour, 1, cv::LINE_AA);
          cv::circle(canvas, p, 1, cv::Scalar(0, 0, 0), -1);
        }
      } else {
        cv::circle(canvas, p, 2, colour, -1, cv::LINE_AA);
      }
    }
    if (!residuals && hull.size() >= 3) {
      std::vector<cv::Point> convex;
      cv::convexHull(hull, convex);
      cv::polylines(canvas, convex, true, colour, 1, cv::LINE_AA);
    }
  }
  std::ostringstream label;
  label << (projector ? "projector " : "camera ") << w << "x" << h;
  if (residuals)
    label << ", residuals x" << std::setprecision(3) << gain / scale << " (max " << max_res
          << " px), RMS " << (projector ? r.rms_projector_px : r.rms_camera_px) << " px";
  else
    label << ", board corners of " << vi << " views";
  cv::putText(canvas, label.str(), cv::Point(8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.5,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  ImageU8 out(cw, ch, 3);
  for (int y = 0; y < ch; ++y)
    for (int x = 0; x < cw; ++x) {
      const cv::Vec3b px = canvas.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) out.channel(c)[static_cast<size_t>(y) * cw + x] = px[2 - c];
    }
  WritePng8(path, out);
}

}  // namespace

Json CalibrationResult::ToJson() const {
  Json j;
  j["rms_camera_px"] = rms_camera_px;
  j["rms_projector_px"] = rms_projector_px;
  j["rms_stereo_px"] = rms_stereo_px;
  j["views_used"] = views_used;
  j["corners_rejected"] = {{"camera", corners_rejected[0]}, {"projector", corners_rejected[1]}};
  j["world"] = world;
  j["camera"] = DeviceJson(rig.camera);
  j["projector"] = DeviceJson(rig.projector);
  const Rigid3d prj_from_cam =
      rig.projector.world_from_device.Inverse() * rig.camera.world_from_device;
  j["baseline_m"] = prj_from_cam.translation.norm();
  j["prj_from_cam_rotation_deg"] =
      Eigen::AngleAxisd(prj_from_cam.rotation).angle() * 180.0 / std::numbers::pi;
  j["model"] = {{"camera", camera_model.ToJson()},
                {"projector", projector_model.ToJson()},
                {"candidates", candidates}};
  j["uncertainties"] = uncertainties;
  j["validation"] = validation;
  j["coverage"] = Json::object();
  for (const auto& c : coverage) j["coverage"][c.device] = c.ToJson();
  j["calibrated_region"] = {{"camera", camera_region.ToJson()},
                            {"projector", projector_region.ToJson()}};
  j["warnings"] = warnings;
  j["ceres"] = ceres_brief;
  j["opencv_baseline"] = opencv;
  j["seconds"] = seconds;
  Json vs = Json::array();
  for (const auto& v : views) {
    Json vj = {{"session", v.name}, {"found", v.found}};
    if (!v.codec.empty()) vj["codec"] = v.codec;
    if (!v.problem.empty()) vj["problem"] = v.problem;
    if (v.found && !v.camera_residual_px.empty()) {
      int np = 0;
      for (const auto& p : v.projector_px) np += p.allFinite();
      vj["rms_camera_px"] = v.rms_camera_px;
      vj["rms_projector_px"] = v.rms_projector_px;
      vj["projector_corners"] = np;
      vj["outlier"] = v.outlier;
      const Rigid3d board_in_cam = v.cam_from_board;
      vj["cam_from_board_translation_m"] = {
          board_in_cam.translation.x(), board_in_cam.translation.y(), board_in_cam.translation.z()};
    }
    vj["decode_seconds"] = v.decode_seconds;
    vs.push_back(vj);
  }
  j["views"] = vs;
  return j;
}

std::string CalibrationResult::BriefReport() const {
  std::ostringstream o;
  o << std::setprecision(4) << views_used << " views, RMS camera " << rms_camera_px
    << " px, projector " << rms_projector_px << " px, stereo " << rms_stereo_px
    << " px (OpenCV: " << opencv.value("rms_camera_px", 0.0) << " / "
    << opencv.value("rms_projector_px", 0.0) << " / " << opencv.value("rms_stereo_px", 0.0)
    << " px); fx camera " << rig.camera.K(0, 0) << ", projector " << rig.projector.K(0, 0)
    << " px; " << seconds << " s";
  if (corners_rejected[0] + corners_rejected[1] > 0)
    o << "; " << corners_rejected[0] << " camera and " << corners_rejected[1]
      << " projector corner(s) left out";
  if (!warnings.empty()) o << "; " << warnings.size() << " warning(s)";
  int outliers = 0;
  for (const auto& v : views) outliers += v.outlier;
  if (outliers) o << "; " << outliers << " outlier view(s)";
  return o.str();
}

std::vector<std::string> CalibrationResult::ReportLines() const {
  std::vector<std::string> lines;
  // The models, with each stage's candidates: held-out error over the corners' noise.
  for (const char* dev : {"camera", "projector"}) {
    std::ostringstream o;
    o << std::setprecision(4) << dev
      << " model: " << (std::string(dev) == "camera" ? camera_model : projector_model).ToString();
    if (candidates.is_array() && !candidates.empty()) {
      o << "; held-out error / noise:";
      std::string stage;
      for (const auto& c : candidates) {
        if (c["device"] != dev) continue;
        const bool first = c["stage"] != stage;
        stage = c["stage"].get<std::string>();
        o << (first ? (stage == "distortion" ? " " : "; ") : ", ") << c["label"].get<std::string>()
          << " " << c["held_out_error_over_noise"].get<double>()
          << (c["chosen"].get<bool>() ? "*" : "");
      }
    }
    lines.push_back(o.str());
  }
  auto summary = [](const std::vector<HeldOutView>& h) {
    const HeldOutSummary s = SummariseHeldOut(h);
    std::ostringstream o;
    o << std::setprecision(3) << "RMS " << s.rms_camera_px << " / " << s.rms_projector_px
      << " px, adjacent corners " << s.adjacent_rms_um << " um RMS, flatness " << s.flatness_rms_um
      << " um, scale error up to " << s.max_abs_scale_error_pct << "%";
    return o.str();
  };
  if (!held_out.empty()) {
    lines.push_back("held-out views (" + std::to_string(held_out.size()) +
                    ", each left out in turn): " + summary(held_out));
    if (!opencv_held_out.empty())
      lines.push_back("OpenCV (k1 k2) on the same held-out views: " + summary(opencv_held_out));
  }
  for (const auto& c : coverage) lines.push_back(c.device + " coverage: " + c.advice);
  return lines;
}

Json CalibrationResult::RigFileJson() const {
  return {{"models", {{"camera", camera_model.ToJson()}, {"projector", projector_model.ToJson()}}},
          {"held_out", SummariseHeldOut(held_out).ToJson()},
          {"uncertainties",
           {{"camera", uncertainties.value("camera", Json())},
            {"projector", uncertainties.value("projector", Json())},
            {"prj_from_cam", uncertainties.value("prj_from_cam", Json())}}},
          {"calibrated_region",
           {{"camera", camera_region.ToJson()}, {"projector", projector_region.ToJson()}}},
          {"warnings", warnings}};
}

void WriteCalibrationReport(const CalibrationResult& result, const fs::path& dir,
                            const Json& extra) {
  fs::create_directories(dir);
  Json j = result.ToJson();
  for (auto it = extra.begin(); it != extra.end(); ++it) j[it.key()] = it.value();
  WriteJsonFile(dir / "report.json", j);
  DrawDevice(result, false, true, dir / "residuals_camera.png");
  DrawDevice(result, true, true, dir / "residuals_projector.png");
  DrawDevice(result, false, false, dir / "coverage_camera.png");
  DrawDevice(result, true, false, dir / "coverage_projector.png");
}

}  // namespace mesoscan
