#include "brdf/rgl.h"

#include <cstring>
#include <fstream>
#include <map>
#include <vector>

#include "core/error.h"
#include "core/log.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// Element types of the tensor_file format (Mitsuba 0.6 Struct::EType numbering).
constexpr uint8_t kTypeUInt8 = 1;
constexpr uint8_t kTypeFloat32 = 10;
constexpr size_t TypeSize(uint8_t t) {
  switch (t) {
    case 1:
    case 2:
      return 1;  // uint8, int8
    case 3:
    case 4:
    case 9:
      return 2;  // uint16, int16, float16
    case 5:
    case 6:
    case 10:
      return 4;  // uint32, int32, float32
    case 7:
    case 8:
    case 11:
      return 8;  // uint64, int64, float64
    default:
      return 0;
  }
}

struct Field {
  uint8_t dtype = 0;
  std::vector<uint64_t> shape;
  const uint8_t* data = nullptr;
  size_t count() const {
    size_t n = 1;
    for (uint64_t s : shape) n *= s;
    return n;
  }
};

// Bounds-checked little-endian reader over the file's bytes.
class Reader {
 public:
  Reader(const std::vector<uint8_t>& bytes, const fs::path& path) : bytes_(bytes), path_(path) {}
  template <typename T>
  T Get(const char* what) {
    if (pos_ + sizeof(T) > bytes_.size())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path_), "truncated header while reading " << what);
    T v;
    std::memcpy(&v, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string GetString(size_t n, const char* what) {
    if (pos_ + n > bytes_.size())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path_), "truncated header while reading " << what);
    std::string s(reinterpret_cast<const char*>(bytes_.data() + pos_), n);
    pos_ += n;
    return s;
  }

 private:
  const std::vector<uint8_t>& bytes_;
  const fs::path& path_;
  size_t pos_ = 0;
};

std::map<std::string, Field> ParseTensorFile(const std::vector<uint8_t>& bytes,
                                             const fs::path& path) {
  static const char kMagic[] = "tensor_file";  // followed by its NUL: 12 bytes
  if (bytes.size() < 12 || std::memcmp(bytes.data(), kMagic, 12) != 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "not a tensor_file (.bsdf) file: bad magic");
  Reader r(bytes, path);
  r.GetString(12, "magic");
  const uint8_t major = r.Get<uint8_t>("version");
  r.Get<uint8_t>("version");
  if (major != 1)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "tensor_file version " << int(major) << ", expected 1");
  const uint32_t n_fields = r.Get<uint32_t>("field count");
  if (n_fields > 1000)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "implausible field count " << n_fields);
  std::map<std::string, Field> fields;
  for (uint32_t i = 0; i < n_fields; ++i) {
    const uint16_t name_len = r.Get<uint16_t>("field name length");
    const std::string name = r.GetString(name_len, "field name");
    const uint16_t ndim = r.Get<uint16_t>("field ndim");
    Field f;
    f.dtype = r.Get<uint8_t>("field dtype");
    const uint64_t offset = r.Get<uint64_t>("field offset");
    for (uint16_t d = 0; d < ndim; ++d) f.shape.push_back(r.Get<uint64_t>("field shape"));
    const size_t elem = TypeSize(f.dtype);
    if (elem == 0)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                            "field '" << name << "' has unknown dtype " << int(f.dtype));
    const size_t n = f.count();
    if (n > bytes.size() || offset > bytes.size() || offset + n * elem > bytes.size())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                            "field '" << name << "' extends past the end of the " << bytes.size()
                                      << "-byte file (truncated?)");
    f.data = bytes.data() + offset;
    fields[name] = f;
  }
  return fields;
}

const Field& Require(const std::map<std::string, Field>& fields, const std::string& name,
                     uint8_t dtype, size_t ndim, const fs::path& path) {
  auto it = fields.find(name);
  if (it == fields.end()) {
    if (name == "rgb" && fields.count("spectra"))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                            "spectral .bsdf files are not supported (field "
                            "'spectra'); use the RGB variant (*_rgb.bsdf)");
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "missing field '" << name << "'");
  }
  if (it->second.dtype != dtype || it->second.shape.size() != ndim)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "field '" << name << "' has dtype " << int(it->second.dtype) << " and "
                                    << it->second.shape.size() << " dimensions, expected dtype "
                                    << int(dtype) << " and " << ndim);
  return it->second;
}

std::vector<double> Floats(const Field& f, size_t begin = 0, size_t count = SIZE_MAX) {
  count = std::min(count, f.count() - begin);
  std::vector<double> out(count);
  for (size_t i = 0; i < count; ++i) {
    float v;
    std::memcpy(&v, f.data + (begin + i) * 4, 4);
    out[i] = v;
  }
  return out;
}

// Dupuy & Jakob 2018 sec. 5: theta is stored as u = sqrt(2 theta / pi) to resolve the pole.
double U2Theta(double u) { return u * u * (kPi / 2); }
double U2Phi(double u) { return (2 * u - 1) * kPi; }
double Theta2U(double theta) { return std::sqrt(theta * (2 / kPi)); }
double Phi2U(double phi) { return (phi + kPi) * (0.5 / kPi); }

// x with its sign flipped when s >= 0 (folds a direction into the half space s < 0).
double MulSignNeg(double x, double s) { return s >= 0 ? -x : x; }

// Solid-angle Jacobian of the (u_theta, u_phi) half-vector parameterisation times that of the
// reflection wm -> wi (4 wo.wm), Dupuy & Jakob 2018 eq. 9; floored like the reference.
double HalfVectorJacobian(double u_theta, double sin_theta_m, double wo_dot_wm) {
  return std::max(2 * kPi * kPi * u_theta * sin_theta_m, 1e-6) * 4 * wo_dot_wm;
}

}  // namespace

std::shared_ptr<const RglBrdf> RglBrdf::Load(const fs::path& path, bool energy_clamp) {
  std::ifstream in(path, std::ios::binary);
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot open file");
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                             std::istreambuf_iterator<char>());
  const auto fields = ParseTensorFile(bytes, path);

  const Field& theta_i = Require(fields, "theta_i", kTypeFloat32, 1, path);
  const Field& phi_i = Require(fields, "phi_i", kTypeFloat32, 1, path);
  const Field& ndf = Require(fields, "ndf", kTypeFloat32, 2, path);
  const Field& sigma = Require(fields, "sigma", kTypeFloat32, 2, path);
  const Field& vndf = Require(fields, "vndf", kTypeFloat32, 4, path);
  const Field& luminance = Require(fields, "luminance", kTypeFloat32, 4, path);
  const Field& rgb = Require(fields, "rgb", kTypeFloat32, 5, path);
  const Field& jacobian = Require(fields, "jacobian", kTypeUInt8, 1, path);
  const size_t n_phi = phi_i.shape[0], n_theta = theta_i.shape[0];
  auto expect = [&](bool ok, const char* field, const char* what) {
    if (!ok)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "field '" << field << "': expected " << what);
  };
  expect(n_phi >= 1 && n_theta >= 2, "theta_i", ">= 2 theta_i and >= 1 phi_i values");
  expect(vndf.shape[0] == n_phi && vndf.shape[1] == n_theta, "vndf",
         "shape [phi_i, theta_i, h, w]");
  expect(luminance.shape[0] == n_phi && luminance.shape[1] == n_theta &&
             luminance.shape[2] == luminance.shape[3],
         "luminance", "shape [phi_i, theta_i, n, n]");
  expect(rgb.shape[0] == n_phi && rgb.shape[1] == n_theta && rgb.shape[2] == 3 &&
             rgb.shape[3] == luminance.shape[2] && rgb.shape[4] == luminance.shape[3],
         "rgb", "shape [phi_i, theta_i, 3, n, n] matching 'luminance'");
  expect(jacobian.shape[0] == 1, "jacobian", "one byte");

  auto brdf = std::shared_ptr<RglBrdf>(new RglBrdf());
  brdf->theta_i_count_ = static_cast<int>(n_theta);
  brdf->phi_i_count_ = static_cast<int>(n_phi);
  brdf->isotropic_ = n_phi <= 2;
  brdf->jacobian_ = jacobian.data[0] != 0;
  const std::vector<double> theta_v = Floats(theta_i), phi_v = Floats(phi_i);
  for (double t : theta_v) expect(std::isfinite(t), "theta_i", "finite angles");
  for (double p : phi_v) expect(std::isfinite(p), "phi_i", "finite angles");
  if (!brdf->isotropic_) {
    // Anisotropic files store one symmetric wedge of phi_i (the full circle over 1, 2 or 4).
    brdf->reduction_ = static_cast<int>(std::lround(2 * kPi / (phi_v.back() - phi_v.front())));
  }
  if (auto it = fields.find("description"); it != fields.end() && it->second.dtype == kTypeUInt8)
    brdf->description_.assign(reinterpret_cast<const char*>(it->second.data), it->second.count());

  try {
    const std::vector<std::vector<double>> params = {phi_v, theta_v};
    brdf->ndf_ = Warp2D(static_cast<int>(ndf.shape[1]), static_cast<int>(ndf.shape[0]), Floats(ndf),
                        {}, false, "ndf");
    brdf->sigma_ = Warp2D(static_cast<int>(sigma.shape[1]), static_cast<int>(sigma.shape[0]),
                          Floats(sigma), {}, false, "sigma");
    brdf->vndf_ = Warp2D(static_cast<int>(vndf.shape[3]), static_cast<int>(vndf.shape[2]),
                         Floats(vndf), params, true, "vndf");
    brdf->luminance_ =
        Warp2D(static_cast<int>(luminance.shape[3]), static_cast<int>(luminance.shape[2]),
               Floats(luminance), params, true, "luminance");
    // rgb is [phi_i][theta_i][channel][n][n]: split it into one interpolant per channel.
    const size_t n = rgb.shape[3] * rgb.shape[4];
    const std::vector<double> all = Floats(rgb);
    size_t negatives = 0;
    for (int c = 0; c < 3; ++c) {
      std::vector<double> channel;
      channel.reserve(n_phi * n_theta * n);
      for (size_t s = 0; s < n_phi * n_theta; ++s)
        for (size_t i = 0; i < n; ++i) {
          double v = all[(s * 3 + c) * n + i];
          if (!std::isfinite(v))
            MESOSCAN_BAD_INPUT("rgb: entry " << (s * 3 + c) * n + i << " is not finite");
          // Spectral-to-RGB conversion leaves small out-of-gamut negatives; a BRDF is >= 0.
          if (v < 0) {
            ++negatives;
            v = 0;
          }
          channel.push_back(v);
        }
      brdf->rgb_[c] = Warp2D(static_cast<int>(rgb.shape[4]), static_cast<int>(rgb.shape[3]),
                             std::move(channel), params, false, "rgb");
    }
    if (negatives)
      MESOSCAN_LOG(kDebug) << path.string() << ": clamped " << negatives
                           << " out-of-gamut negative rgb entries to 0";
  } catch (const Error& e) {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), e.what());
  }

  // Energy: albedo at every incident slice and at kPieces - 1 elevations between two slices (the
  // interpolated tables can exceed both neighbours). Anisotropic files take the largest albedo
  // over the tabulated azimuths.
  constexpr int kPieces = 8;
  std::vector<double> grid;
  std::vector<bool> is_slice;
  for (size_t k = 0; k < theta_v.size(); ++k) {
    grid.push_back(theta_v[k]);
    is_slice.push_back(true);
    if (k + 1 == theta_v.size()) break;
    for (int p = 1; p < kPieces; ++p) {
      grid.push_back(theta_v[k] + (theta_v[k + 1] - theta_v[k]) * p / kPieces);
      is_slice.push_back(false);
    }
  }
  const RglBrdf& raw = *brdf;
  const auto f = [&raw](const Vec3& wo, const Vec3& wi) { return raw.f(wo, wi); };
  EnergyClamp energy = BuildEnergyClamp(
      std::move(grid), std::move(is_slice),
      [&](double theta) {
        Rgb a = Rgb::Zero();
        for (double phi : raw.isotropic_ ? std::vector<double>{0.0} : phi_v)
          a = a.max(StratifiedAlbedo(raw, SphericalDirection(theta, phi), 16));
        return a;
      },
      [&](double theta, int n) {
        Rgb a = Rgb::Zero();
        for (double phi : raw.isotropic_ ? std::vector<double>{0.0} : phi_v)
          a = a.max(HalfVectorAlbedo(f, SphericalDirection(theta, phi), n));
        return a;
      });
  if (!energy_clamp) energy.active = false;
  if (energy.exceeds)
    MESOSCAN_LOG(kWarning) << path.string() << ": directional albedo exceeds 1; "
                           << energy.Summary();
  brdf->energy_ = std::move(energy);
  return brdf;
}

std::optional<RglBrdf::Query> RglBrdf::MakeQuery(const Vec3& wo_in, const Vec3& wi_in) const {
  if (wo_in.z() <= 0 || wi_in.z() <= 0) return std::nullopt;
  Query q;
  q.wo = wo_in;
  q.wi = wi_in;
  if (reduction_ >= 2) {
    const double sy = q.wo.y(), sx = reduction_ == 4 ? q.wo.x() : sy;
    q.wo.x() = MulSignNeg(q.wo.x(), sx);
    q.wo.y() = MulSignNeg(q.wo.y(), sy);
    q.wi.x() = MulSignNeg(q.wi.x(), sx);
    q.wi.y() = MulSignNeg(q.wi.y(), sy);
  }
  q.wm = (q.wo + q.wi).normalized();
  const double theta_o = Elevation(q.wo), phi_o = std::atan2(q.wo.y(), q.wo.x());
  const double theta_m = Elevation(q.wm), phi_m = std::atan2(q.wm.y(), q.wm.x());
  q.u_wo = Vec2(Theta2U(theta_o), Phi2U(phi_o));
  q.u_wm = Vec2(Theta2U(theta_m), Phi2U(isotropic_ ? phi_m - phi_o : phi_m));
  q.u_wm.y() -= std::floor(q.u_wm.y());
  q.params[0] = phi_o;
  q.params[1] = theta_o;
  return q;
}

Rgb RglBrdf::Value(const Vec2& sample, const Vec2& u_wm, const Vec2& u_wo,
                   const double* params) const {
  Rgb v(rgb_[0].Eval(sample, params), rgb_[1].Eval(sample, params), rgb_[2].Eval(sample, params));
  // With the jacobian flag the tables hold f / (D / (4 sigma)) (paper eq. 12): undo it.
  if (jacobian_) {
    const double sigma = sigma_.Eval(u_wo);
    v *= sigma > 0 ? ndf_.Eval(u_wm) / (4 * sigma) : 0.0;
  }
  // params[1] is theta_o.
  if (energy_.active) v *= energy_.Scale(params[1]);
  return v;
}

Rgb RglBrdf::f(const Vec3& wo, const Vec3& wi) const {
  const auto q = MakeQuery(wo, wi);
  if (!q) return Rgb::Zero();
  const Vec2 sample = vndf_.Invert(q->u_wm, q->params).first;
  // The tables hold f * cos(theta_i) (our wi): divide it out.
  return Value(sample, q->u_wm, q->u_wo, q->params) / q->wi.z();
}

double RglBrdf::Pdf(const Vec3& wo, const Vec3& wi) const {
  const auto q = MakeQuery(wo, wi);
  if (!q) return 0.0;
  const double wo_dot_wm = q->wo.dot(q->wm);
  if (wo_dot_wm <= 0) return 0.0;
  const auto [sample, vndf_pdf] = vndf_.Invert(q->u_wm, q->params);
  const double lum_pdf = luminance_.Eval(sample, q->params);
  const double sin_theta_m = std::sqrt(q->wm.x() * q->wm.x() + q->wm.y() * q->wm.y());
  return vndf_pdf * lum_pdf / HalfVectorJacobian(q->u_wm.x(), sin_theta_m, wo_dot_wm);
}

std::optional<BrdfSample> RglBrdf::Sample(const Vec3& wo_in, const Vec2& u) const {
  if (wo_in.z() <= 0) return std::nullopt;
  Vec3 wo = wo_in;
  double sx = -1, sy = -1;  // MulSignNeg(x, -1) = x: no folding
  if (reduction_ >= 2) {
    sy = wo.y();
    sx = reduction_ == 4 ? wo.x() : sy;
    wo.x() = MulSignNeg(wo.x(), sx);
    wo.y() = MulSignNeg(wo.y(), sy);
  }
  const double theta_o = Elevation(wo), phi_o = std::atan2(wo.y(), wo.x());
  const double params[2] = {phi_o, theta_o};
  const Vec2 u_wo(Theta2U(theta_o), Phi2U(phi_o));
  // Luminance warp, then the visible-normal warp (paper sec. 5, fig. 7).
  const auto [sample, lum_pdf] = luminance_.Sample(u, params);
  const auto [u_wm, vndf_pdf] = vndf_.Sample(sample, params);
  double phi_m = U2Phi(u_wm.y());
  const double theta_m = U2Theta(u_wm.x());
  if (isotropic_) phi_m += phi_o;
  const Vec3 wm = SphericalDirection(theta_m, phi_m);
  const double wo_dot_wm = wo.dot(wm);
  if (wo_dot_wm <= 0) return std::nullopt;
  const double pdf =
      vndf_pdf * lum_pdf / HalfVectorJacobian(u_wm.x(), std::sin(theta_m), wo_dot_wm);
  Vec3 wi = Reflect(wo, wm);
  if (wi.z() <= 0 || !(pdf > 0)) return std::nullopt;
  const Rgb value = Value(sample, u_wm, u_wo, params);
  wi.x() = MulSignNeg(wi.x(), sx);
  wi.y() = MulSignNeg(wi.y(), sy);
  return BrdfSample{wi, value / wi.z(), pdf};
}

}  // namespace mesoscan
