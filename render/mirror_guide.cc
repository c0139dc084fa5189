#include "render/mirror_guide.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {

namespace {
constexpr double kTwoPi = 2.0 * kPi;

double Power(double a, double b) {
  const double a2 = a * a, b2 = b * b;
  return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}
}  // namespace

bool MirrorGuide::Useful(const EnvironmentMap& env, const Brdf& brdf) {
  return !env.is_constant() && !brdf.Is<LambertBrdf>();
}

MirrorGuide::MirrorGuide(const EnvironmentMap& env, const Brdf& brdf, const Options& o)
    : nphi_(o.phi_cells), nz_(o.z_cells) {
  MESOSCAN_CHECK(nphi_ >= 1 && nz_ >= 1 && o.env_samples >= 1 && o.floor > 0 && o.max_select >= 0 &&
                 o.max_select < 1);
  const int cells = nphi_ * nz_;
  cell_solid_angle_ = kTwoPi / nphi_ / nz_;
  // Luminance of the radiance the flat field (normal +z, world frame = BRDF frame) reflects
  // towards -d at each cell's centre d, from stratified environment samples and BRDF samples
  // combined by the power heuristic.
  const int side = std::max(1, static_cast<int>(std::lround(std::sqrt(o.env_samples))));
  std::vector<double> lum(cells, 0.0);
  ParallelFor(
      cells,
      [&](int64_t c) {
        const int iz = static_cast<int>(c / nphi_), ip = static_cast<int>(c % nphi_);
        const double z = -(iz + 0.5) / nz_, r = std::sqrt(std::max(0.0, 1 - z * z));
        const double phi = (ip + 0.5) / nphi_ * kTwoPi;
        const Vec3 wo(-r * std::cos(phi), -r * std::sin(phi), -z);  // towards the viewer, z > 0
        Rgb L = Rgb::Zero();
        for (int a = 0; a < side; ++a)
          for (int b = 0; b < side; ++b) {
            const Vec2 u((a + 0.5) / side, (b + 0.5) / side);
            if (auto ls = env.Sample(u); ls && ls->wi.z() > 0) {
              const Rgb f = brdf.f(wo, ls->wi);
              L += f * ls->Le * (ls->wi.z() * Power(ls->pdf, brdf.Pdf(wo, ls->wi)) / ls->pdf);
            }
            if (auto bs = brdf.Sample(wo, u); bs && bs->pdf > 0 && bs->wi.z() > 0) {
              double env_pdf = 0;
              const Rgb Le = env.LeAndPdf(bs->wi, &env_pdf);
              L += bs->f * Le * (bs->wi.z() * Power(bs->pdf, env_pdf) / bs->pdf);
            }
          }
        const double y = Luminance(L);
        lum[c] = std::isfinite(y) ? std::max(0.0, y) : 0.0;
      },
      16);
  double mean = 0;
  for (const double v : lum) mean += v / cells;
  // The floor keeps every downward direction reachable (and the table usable when the field
  // reflects nothing).
  const double floor = mean > 0 ? o.floor * mean : 1.0;
  cdf_.assign(cells + 1, 0.0);
  for (int c = 0; c < cells; ++c) cdf_[c + 1] = cdf_[c] + lum[c] + floor;
  const double total = cdf_[cells];
  lum_.resize(cells);
  for (int c = 0; c < cells; ++c) lum_[c] = lum[c] + floor;
  mean_lum_ = mean + floor;
  pdf_.resize(cells);
  for (int c = 0; c < cells; ++c) pdf_[c] = (cdf_[c + 1] - cdf_[c]) / total / cell_solid_angle_;
  // Blocks for the product with the vertex's BRDF.
  MESOSCAN_CHECK(nphi_ % kCoarsePhi == 0 && nz_ % kCoarseZ == 0);
  block_mass_.assign(kCoarse, 0.0);
  for (int c = 0; c < cells; ++c) block_mass_[Block(c)] += (cdf_[c + 1] - cdf_[c]) / total;
  block_centre_.resize(kCoarse);
  for (int b = 0; b < kCoarse; ++b) {
    const double z = -((b / kCoarsePhi) + 0.5) / kCoarseZ, r = std::sqrt(std::max(0.0, 1 - z * z));
    const double phi = ((b % kCoarsePhi) + 0.5) / kCoarsePhi * kTwoPi;
    block_centre_[b] = Vec3(r * std::cos(phi), r * std::sin(phi), z);
  }
  // Selection: max_select x the guide's probability mass in the hemisphere above each normal.
  select_.assign(kSelTheta * kSelPhi, 0.0f);
  std::vector<Vec3> centre(cells);
  for (int c = 0; c < cells; ++c) {
    const int iz = c / nphi_, ip = c % nphi_;
    const double z = -(iz + 0.5) / nz_, r = std::sqrt(std::max(0.0, 1 - z * z));
    const double phi = (ip + 0.5) / nphi_ * kTwoPi;
    centre[c] = Vec3(r * std::cos(phi), r * std::sin(phi), z);
  }
  ParallelFor(
      kSelTheta,
      [&](int64_t t) {
        const double th = (t + 0.5) / kSelTheta * kPi;
        for (int p = 0; p < kSelPhi; ++p) {
          const double ph = (p + 0.5) / kSelPhi * kTwoPi;
          const Vec3 n(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
          double mass = 0;
          for (int c = 0; c < cells; ++c)
            if (centre[c].dot(n) > 0) mass += cdf_[c + 1] - cdf_[c];
          select_[t * kSelPhi + p] = static_cast<float>(o.max_select * mass / total);
        }
      },
      1);
}

int MirrorGuide::Cell(const Vec3& w) const {
  const int iz = std::clamp(static_cast<int>(-w.z() * nz_), 0, nz_ - 1);
  double phi = std::atan2(w.y(), w.x());
  if (phi < 0) phi += kTwoPi;
  const int ip = std::clamp(static_cast<int>(phi / kTwoPi * nphi_), 0, nphi_ - 1);
  return iz * nphi_ + ip;
}

Vec3 MirrorGuide::Sample(const Vec2& u, double* pdf) const {
  const int cells = nphi_ * nz_;
  const double t = u.x() * cdf_[cells];
  int c = static_cast<int>(std::upper_bound(cdf_.begin(), cdf_.end(), t) - cdf_.begin()) - 1;
  c = std::clamp(c, 0, cells - 1);
  // Every cell has mass (the floor), so the remainder places the point inside the cell.
  const double fx = std::clamp((t - cdf_[c]) / (cdf_[c + 1] - cdf_[c]), 0.0, 1.0);
  const int iz = c / nphi_, ip = c % nphi_;
  // Uniform in (phi, z) inside the cell = uniform in solid angle (Archimedes). Keep z < 0.
  const double z = std::min(-(iz + u.y()) / nz_, -1e-9);
  const double phi = (ip + fx) / nphi_ * kTwoPi;
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  *pdf = pdf_[c];
  return Vec3(r * std::cos(phi), r * std::sin(phi), z);
}

double MirrorGuide::Pdf(const Vec3& w) const {
  if (!(w.z() < 0)) return 0.0;
  return pdf_[Cell(w)];
}

double MirrorGuide::SelectProbability(const Vec3& n) const {
  const double th = std::acos(std::clamp(n.z(), -1.0, 1.0));
  double ph = std::atan2(n.y(), n.x());
  if (ph < 0) ph += kTwoPi;
  const int t = std::clamp(static_cast<int>(th / kPi * kSelTheta), 0, kSelTheta - 1);
  const int p = std::clamp(static_cast<int>(ph / kTwoPi * kSelPhi), 0, kSelPhi - 1);
  return select_[t * kSelPhi + p];
}

int MirrorGuide::Block(int cell) const {
  const int iz = cell / nphi_, ip = cell % nphi_;
  return (iz / (nz_ / kCoarseZ)) * kCoarsePhi + ip / (nphi_ / kCoarsePhi);
}

bool MirrorGuide::Prepare(const Brdf& brdf, const Vec3& s, const Vec3& t, const Vec3& n,
                          const Vec3& wo, Local* local) const {
  local->cdf[0] = 0;
  // A measured table's cheap stand-in for the lobe (MerlBrdf::ProxyLuminance): these weights
  // only shape the proposal (Sample and Pdf use the same ones), so any non-negative stand-in
  // keeps the estimate unbiased; the full lookups here were most of the vertex's table reads.
  const MerlBrdf* merl = brdf.Get<MerlBrdf>();
  for (int b = 0; b < kCoarse; ++b) {
    const Vec3& w = block_centre_[b];
    const Vec3 wi(w.dot(s), w.dot(t), w.dot(n));
    double q = 0;
    // Blocks holding little of the table (under an even share) are left to BRDF
    // sampling: fewer BRDF evaluations per vertex.
    if (wi.z() > 0 && block_mass_[b] > 1.0 / kCoarse) {
      const double y = (merl ? merl->ProxyLuminance(wo, wi) : Luminance(brdf.f(wo, wi))) * wi.z();
      if (y > 0 && std::isfinite(y)) q = block_mass_[b] * y;
    }
    local->cdf[b + 1] = local->cdf[b] + q;
  }
  return local->cdf[kCoarse] > 0;
}

Vec3 MirrorGuide::Sample(const Local& local, const Vec2& u, double* pdf) const {
  // Block by the product weights, then a cell within the block by the table, then uniform.
  const double tb = u.x() * local.cdf[kCoarse];
  int b =
      static_cast<int>(std::upper_bound(local.cdf, local.cdf + kCoarse + 1, tb) - local.cdf) - 1;
  b = std::clamp(b, 0, kCoarse - 1);
  while (b > 0 && !(local.cdf[b + 1] > local.cdf[b])) --b;
  const double fb = std::clamp((tb - local.cdf[b]) / (local.cdf[b + 1] - local.cdf[b]), 0.0, 1.0);
  const int bz = nz_ / kCoarseZ, bp = nphi_ / kCoarsePhi;
  const int z0 = (b / kCoarsePhi) * bz, p0 = (b % kCoarsePhi) * bp;
  const double target = fb * block_mass_[b] * cdf_[nphi_ * nz_];
  double acc = 0;
  int cell = z0 * nphi_ + p0;
  double frac = 0.5;
  for (int iz = z0; iz < z0 + bz; ++iz)
    for (int ip = p0; ip < p0 + bp; ++ip) {
      const int c = iz * nphi_ + ip;
      const double m = cdf_[c + 1] - cdf_[c];
      cell = c;
      if (acc + m >= target) {
        frac = std::clamp((target - acc) / m, 0.0, 1.0);
        iz = z0 + bz;  // done
        break;
      }
      acc += m;
    }
  const int iz = cell / nphi_, ip = cell % nphi_;
  const double z = std::min(-(iz + u.y()) / nz_, -1e-9);
  const double phi = (ip + frac) / nphi_ * kTwoPi;
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  const Vec3 w(r * std::cos(phi), r * std::sin(phi), z);
  *pdf = Pdf(local, w);
  return w;
}

double MirrorGuide::Pdf(const Local& local, const Vec3& w) const {
  if (!(w.z() < 0)) return 0.0;
  const int c = Cell(w), b = Block(c);
  const double qb = local.cdf[b + 1] - local.cdf[b];
  if (!(qb > 0)) return 0.0;
  return qb / local.cdf[kCoarse] * pdf_[c] / block_mass_[b];
}

}  // namespace mesoscan
