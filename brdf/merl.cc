#include "brdf/merl.h"

#include <cstdint>
#include <cstring>
#include <fstream>

#include "core/error.h"
#include "core/fast_atan.h"
#include "core/fs.h"
#include "core/log.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// Half-vector parameterisation of the sampling table (the same as the RGL files use, Dupuy & Jakob
// 2018 sec. 5): u = sqrt(2 theta / pi) resolves highlights near the mirror direction.
double U2Theta(double u) { return u * u * (kPi / 2); }
double U2Phi(double u) { return (2 * u - 1) * kPi; }
double Theta2U(double theta) { return std::sqrt(theta * (2 / kPi)); }
double Phi2U(double phi) { return (phi + kPi) * (0.5 / kPi); }
double HalfVectorJacobian(double u_theta, double sin_theta_m, double wo_dot_wm) {
  return std::max(2 * kPi * kPi * u_theta * sin_theta_m, 1e-6) * 4 * wo_dot_wm;
}
// Largest outgoing elevation with its own sampling slice; steeper wo reuse the last slice.
constexpr double kMaxSamplingThetaO = 89.0 * kPi / 180.0;

// Continuous table coordinate of each angle (entry i sits at coordinate i).
double ThetaHCoord(double theta_h) {
  return theta_h <= 0 ? 0.0 : std::sqrt(theta_h / (kPi / 2)) * MerlBrdf::kThetaH;
}
double ThetaDCoord(double theta_d) { return theta_d / (kPi / 2) * MerlBrdf::kThetaD; }
double PhiDCoord(double phi_d) {
  if (phi_d < 0) phi_d += kPi;  // reciprocity: f(phi_d) = f(phi_d + pi)
  return phi_d / kPi * MerlBrdf::kPhiD;
}

// Directions (wi, wo) of half/difference angles with phi_h = 0 (inverse of HalfDiffAngles).
void DirectionsFromHalfDiff(double theta_h, double theta_d, double phi_d, Vec3* wi, Vec3* wo) {
  const Vec3 d = SphericalDirection(theta_d, phi_d);
  const double c = std::cos(theta_h), s = std::sin(theta_h);
  *wi = Vec3(d.x() * c + d.z() * s, d.y(), -d.x() * s + d.z() * c);
  const Vec3 h(s, 0, c);
  *wo = Reflect(*wi, h);
}

}  // namespace

void MerlOptions::Check() const {
  if (sampling_theta_nodes < 2 || sampling_phi_nodes < 2 || sampling_wo_nodes < 2)
    MESOSCAN_BAD_INPUT("MerlOptions: sampling_*_nodes must be >= 2");
}

void HalfDiffAngles(const Vec3& wi, const Vec3& wo, double* theta_h, double* theta_d,
                    double* phi_d) {
  const Vec3 h = (wi + wo).normalized();
  // The angles by FastAtan2 (~2 ulp, several times faster than glibc's asin/acos/atan2, which
  // were a tenth of the demo's render): theta = atan2(|xy|, z) is accurate at every elevation.
  const double r = std::sqrt(h.x() * h.x() + h.y() * h.y());
  *theta_h = FastAtan2(r, h.z());
  // Rotate wi by -phi_h about the normal, then by -theta_h about the binormal (y). The cosines
  // and sines come from h itself (h is a unit vector: cos theta_h = h.z, sin theta_h = |h.xy|),
  // without the trigonometric calls (phi_h = atan2(h.y, h.x) = 0 when h is the normal).
  const double cp = r > 0 ? h.x() / r : 1.0, sp = r > 0 ? h.y() / r : 0.0;
  const Vec3 t(wi.x() * cp + wi.y() * sp, -wi.x() * sp + wi.y() * cp, wi.z());
  const double ct = h.z(), st = r;
  const Vec3 d(t.x() * ct - t.z() * st, t.y(), t.x() * st + t.z() * ct);
  *theta_d = FastAtan2(std::sqrt(d.x() * d.x() + d.y() * d.y()), d.z());
  *phi_d = FastAtan2(d.y(), d.x());
}

std::shared_ptr<const MerlBrdf> MerlBrdf::Load(const fs::path& path, const MerlOptions& options) {
  options.Check();
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot open file");
  const auto size = static_cast<size_t>(in.tellg());
  in.seekg(0);
  if (size < 12)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "truncated MERL file: " << size << " bytes, expected " << kFileBytes);
  int32_t dims[3];
  in.read(reinterpret_cast<char*>(dims), sizeof(dims));
  if (dims[0] != kThetaH || dims[1] != kThetaD || dims[2] != kPhiD)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "MERL dimensions " << dims[0] << " x " << dims[1]
                                                                    << " x " << dims[2]
                                                                    << ", expected 90 x 90 x 180");
  if (size != kFileBytes)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "MERL file has "
                                                     << size << " bytes, expected " << kFileBytes
                                                     << (size < kFileBytes ? " (truncated)" : ""));
  std::vector<double> raw(3 * kEntries);
  in.read(reinterpret_cast<char*>(raw.data()), raw.size() * sizeof(double));
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "read error");

  auto brdf = std::shared_ptr<MerlBrdf>(new MerlBrdf());
  brdf->options_ = options;
  brdf->rgb_.resize(raw.size());
  size_t first_negative = SIZE_MAX;
  for (size_t i = 0; i < raw.size(); ++i) {
    const double v = raw[i];
    if (!std::isfinite(v))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "entry " << i % kEntries << " of channel "
                                                            << i / kEntries << " is " << v
                                                            << ", expected a finite value");
    if (v < 0) {
      if (first_negative == SIZE_MAX) first_negative = i;
      ++brdf->invalid_entries_;
      brdf->rgb_[3 * (i % kEntries) + i / kEntries] = 0.0f;
    } else {
      brdf->rgb_[3 * (i % kEntries) + i / kEntries] = static_cast<float>(v * kScale[i / kEntries]);
    }
  }
  if (brdf->invalid_entries_ > 0) {
    if (!options.accept_invalid_entries)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                            brdf->invalid_entries_
                                << " negative (unmeasured) entries, first at entry "
                                << first_negative % kEntries << " of channel "
                                << first_negative / kEntries << "; expected values >= 0 ("
                                << OptionRef{"MerlOptions.accept_invalid_entries"}
                                << " reads them as 0)");
    MESOSCAN_LOG(kWarning) << path.string() << ": " << brdf->invalid_entries_
                           << " unmeasured entries read as 0";
  }
  brdf->BuildProxy();
  brdf->BuildSamplingTable();
  brdf->BuildEnergyClamp(path.string());
  return brdf;
}

std::shared_ptr<const MerlBrdf> MerlBrdf::Tabulate(
    const std::function<Rgb(const Vec3& wo, const Vec3& wi)>& model, const MerlOptions& options) {
  options.Check();
  auto brdf = std::shared_ptr<MerlBrdf>(new MerlBrdf());
  brdf->options_ = options;
  brdf->rgb_.resize(3 * kEntries);
  ParallelFor(kThetaH, [&](int64_t ih) {
    const double u = static_cast<double>(ih) / kThetaH;
    const double theta_h = u * u * (kPi / 2);
    for (int id = 0; id < kThetaD; ++id) {
      const double theta_d = id * (kPi / 2) / kThetaD;
      for (int ip = 0; ip < kPhiD; ++ip) {
        const double phi_d = ip * kPi / kPhiD;
        Vec3 wi, wo;
        DirectionsFromHalfDiff(theta_h, theta_d, phi_d, &wi, &wo);
        // Below-horizon nodes: evaluate at the nearest configuration just above it.
        constexpr double kMinZ = 1e-3;
        if (wi.z() < kMinZ)
          wi = Vec3(wi.x(), wi.y(), 0).normalized() * std::sqrt(1 - kMinZ * kMinZ) +
               Vec3(0, 0, kMinZ);
        if (wo.z() < kMinZ)
          wo = Vec3(wo.x(), wo.y(), 0).normalized() * std::sqrt(1 - kMinZ * kMinZ) +
               Vec3(0, 0, kMinZ);
        const Rgb v = model(wo, wi);
        const size_t idx = (static_cast<size_t>(ih) * kThetaD + id) * kPhiD + ip;
        for (int c = 0; c < 3; ++c)
          brdf->rgb_[3 * idx + c] = static_cast<float>(std::max(0.0, v[c]));
      }
    }
  });
  brdf->BuildProxy();
  brdf->BuildSamplingTable();
  brdf->BuildEnergyClamp("tabulated model");
  return brdf;
}

void MerlBrdf::Write(const fs::path& path) const {
  WriteFileChecked(path, [&](CheckedFile& out) {
    const int32_t dims[3] = {kThetaH, kThetaD, kPhiD};
    out.Write(dims, sizeof(dims));
    std::vector<double> raw(rgb_.size());
    for (size_t i = 0; i < raw.size(); ++i)
      raw[i] = rgb_[3 * (i % kEntries) + i / kEntries] / kScale[i / kEntries];
    out.Write(raw.data(), raw.size() * sizeof(double));
  });
}

Rgb MerlBrdf::Node(int ih, int id, int ip) const {
  const size_t idx = (static_cast<size_t>(ih) * kThetaD + id) * kPhiD + ip;
  return Rgb(rgb_[3 * idx], rgb_[3 * idx + 1], rgb_[3 * idx + 2]);
}

Rgb MerlBrdf::Lookup(double theta_h, double theta_d, double phi_d) const {
  const double xh = ThetaHCoord(theta_h), xd = ThetaDCoord(theta_d), xp = PhiDCoord(phi_d);
  if (options_.interpolation == MerlInterpolation::kNearest) {
    return Node(std::clamp(static_cast<int>(xh), 0, kThetaH - 1),
                std::clamp(static_cast<int>(xd), 0, kThetaD - 1),
                std::clamp(static_cast<int>(xp), 0, kPhiD - 1));
  }
  // Trilinear; theta coordinates clamp at the last node, phi_d wraps (period pi).
  const int ih = std::clamp(static_cast<int>(std::floor(xh)), 0, kThetaH - 2);
  const int id = std::clamp(static_cast<int>(std::floor(xd)), 0, kThetaD - 2);
  const double th = std::clamp(xh - ih, 0.0, 1.0), td = std::clamp(xd - id, 0.0, 1.0);
  const double fp = std::floor(xp);
  const double tp = xp - fp;
  const int ip0 = ((static_cast<int>(fp) % kPhiD) + kPhiD) % kPhiD, ip1 = (ip0 + 1) % kPhiD;
  // RGB interleaved: each node's three channels share a cache line (the planar layout touched
  // three times the lines; the table does not fit the core's cache).
  float v[3] = {0, 0, 0};
  const float fp1 = static_cast<float>(tp), fp0 = 1.0f - fp1;
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b) {
      const float w = static_cast<float>((a ? th : 1 - th) * (b ? td : 1 - td));
      if (w == 0) continue;
      const size_t row = (static_cast<size_t>(ih + a) * kThetaD + id + b) * kPhiD;
      const float* n0 = &rgb_[3 * (row + ip0)];
      const float* n1 = &rgb_[3 * (row + ip1)];
      for (int c = 0; c < 3; ++c) v[c] += w * (fp0 * n0[c] + fp1 * n1[c]);
    }
  return Rgb(v[0], v[1], v[2]);
}

void MerlBrdf::BuildProxy() {
  constexpr int kD = kThetaD / 2, kP = kPhiD / 2;
  proxy_.assign(static_cast<size_t>(kThetaH) * kD * kP, 0.0f);
  for (int ih = 0; ih < kThetaH; ++ih)
    for (int id = 0; id < kD; ++id)
      for (int ip = 0; ip < kP; ++ip) {
        double sum = 0;
        for (int a = 0; a < 2; ++a)
          for (int b = 0; b < 2; ++b) sum += Luminance(Node(ih, 2 * id + a, 2 * ip + b));
        proxy_[(static_cast<size_t>(ih) * kD + id) * kP + ip] =
            static_cast<float>(std::max(0.0, 0.25 * sum));
      }
}

double MerlBrdf::ProxyLuminance(const Vec3& wo, const Vec3& wi) const {
  if (!SameHemisphereUp(wo, wi)) return 0.0;
  double theta_h, theta_d, phi_d;
  HalfDiffAngles(wi, wo, &theta_h, &theta_d, &phi_d);
  constexpr int kD = kThetaD / 2, kP = kPhiD / 2;
  const int ih = std::clamp(static_cast<int>(ThetaHCoord(theta_h)), 0, kThetaH - 1);
  const int id = std::clamp(static_cast<int>(0.5 * ThetaDCoord(theta_d)), 0, kD - 1);
  const int ip = std::clamp(static_cast<int>(0.5 * PhiDCoord(phi_d)), 0, kP - 1);
  return proxy_[(static_cast<size_t>(ih) * kD + id) * kP + ip];
}

Rgb MerlBrdf::RawF(const Vec3& wo, const Vec3& wi) const {
  if (!SameHemisphereUp(wo, wi)) return Rgb::Zero();
  double theta_h, theta_d, phi_d;
  HalfDiffAngles(wi, wo, &theta_h, &theta_d, &phi_d);
  return Lookup(theta_h, theta_d, phi_d);
}

Rgb MerlBrdf::f(const Vec3& wo, const Vec3& wi) const {
  const Rgb v = RawF(wo, wi);
  if (!energy_.active) return v;
  // min(s(theta_o), s(theta_i)) <= s(theta_o): albedo(wo) <= s(theta_o) albedo_raw(wo) <= 1, and
  // the factor is symmetric in wo and wi.
  return v * energy_.Scale(Elevation(wo)).min(energy_.Scale(Elevation(wi)));
}

void MerlBrdf::BuildEnergyClamp(const std::string& source) {
  // Every 1.5 degrees from 0 to 90: the table has no incident slices of its own.
  std::vector<double> grid;
  for (int k = 0; k <= 60; ++k) grid.push_back(k * 1.5 * kPi / 180);
  const auto f = [this](const Vec3& wo, const Vec3& wi) { return RawF(wo, wi); };
  energy_ = mesoscan::BuildEnergyClamp(
      grid, std::vector<bool>(grid.size(), true),
      [this](double theta) { return StratifiedAlbedo(*this, SphericalDirection(theta, 0.0), 16); },
      [&](double theta, int n) { return HalfVectorAlbedo(f, SphericalDirection(theta, 0.0), n); });
  energy_.slice_noun = "elevations";
  if (!options_.energy_clamp) energy_.active = false;
  if (energy_.exceeds)
    MESOSCAN_LOG(kWarning) << source << ": directional albedo exceeds 1; " << energy_.Summary();
}

void MerlBrdf::BuildSamplingTable() {
  const int nx = options_.sampling_theta_nodes, ny = options_.sampling_phi_nodes;
  const int nw = options_.sampling_wo_nodes;
  std::vector<double> theta_o(nw);
  for (int k = 0; k < nw; ++k) theta_o[k] = kMaxSamplingThetaO * k / (nw - 1);
  std::vector<double> table(static_cast<size_t>(nw) * nx * ny, 0.0);
  ParallelFor(nw, [&](int64_t k) {
    const Vec3 wo = SphericalDirection(theta_o[k], 0.0);
    double* slice = table.data() + k * static_cast<size_t>(nx) * ny;
    std::vector<double> jac(static_cast<size_t>(nx) * ny, 0.0);
    double lum_sum = 0;
    int valid = 0;
    // Density over (u_theta_m, u_phi_m) proportional to luminance(f) cos(theta_i) |dwi/du|.
    for (int y = 0; y < ny; ++y)
      for (int x = 0; x < nx; ++x) {
        const double ux = static_cast<double>(x) / (nx - 1), uy = static_cast<double>(y) / (ny - 1);
        const double theta_m = U2Theta(ux);
        const Vec3 wm = SphericalDirection(theta_m, U2Phi(uy));
        const double wo_dot_wm = wo.dot(wm);
        if (wo_dot_wm <= 0) continue;
        const Vec3 wi = Reflect(wo, wm);
        if (wi.z() <= 0) continue;
        const double lum = std::max(0.0, Luminance(RawF(wo, wi)));
        const size_t i = static_cast<size_t>(y) * nx + x;
        jac[i] = wi.z() * 2 * kPi * kPi * ux * std::sin(theta_m) * 4 * wo_dot_wm;
        slice[i] = lum;
        lum_sum += lum;
        ++valid;
      }
    // A floor of 1% of the mean keeps pdf > 0 wherever f may be > 0 (unbiased rendering).
    const double floor = valid > 0 && lum_sum > 0 ? 0.01 * lum_sum / valid : 1.0;
    for (size_t i = 0; i < jac.size(); ++i)
      slice[i] = jac[i] > 0 ? (slice[i] + floor) * jac[i] : 0.0;
  });
  sampling_ = Warp2D(nx, ny, std::move(table), {theta_o}, true, "MERL sampling table");
}

std::optional<BrdfSample> MerlBrdf::Sample(const Vec3& wo, const Vec2& u) const {
  if (wo.z() <= 0) return std::nullopt;
  const double theta_o = Elevation(wo), phi_o = FastAtan2(wo.y(), wo.x());
  const auto [u_wm, pdf_u] = sampling_.Sample(u, &theta_o);
  const double theta_m = U2Theta(u_wm.x());
  const Vec3 wm = SphericalDirection(theta_m, U2Phi(u_wm.y()) + phi_o);
  const double wo_dot_wm = wo.dot(wm);
  if (wo_dot_wm <= 0) return std::nullopt;
  const Vec3 wi = Reflect(wo, wm);
  const double pdf = pdf_u / HalfVectorJacobian(u_wm.x(), std::sin(theta_m), wo_dot_wm);
  if (wi.z() <= 0 || !(pdf > 0)) return std::nullopt;
  return BrdfSample{wi, f(wo, wi), pdf};
}

double MerlBrdf::Pdf(const Vec3& wo, const Vec3& wi) const {
  if (!SameHemisphereUp(wo, wi)) return 0.0;
  const Vec3 wm = (wo + wi).normalized();
  const double wo_dot_wm = wo.dot(wm);
  if (wo_dot_wm <= 0) return 0.0;
  const double theta_o = Elevation(wo), phi_o = FastAtan2(wo.y(), wo.x());
  const double theta_m = Elevation(wm), phi_m = FastAtan2(wm.y(), wm.x());
  Vec2 u_wm(Theta2U(theta_m), Phi2U(phi_m - phi_o));
  u_wm.y() -= std::floor(u_wm.y());
  const double sin_theta_m = std::sqrt(wm.x() * wm.x() + wm.y() * wm.y());
  return sampling_.Eval(u_wm, &theta_o) / HalfVectorJacobian(u_wm.x(), sin_theta_m, wo_dot_wm);
}

}  // namespace mesoscan
