#pragma once
// Isotropic tabulated BRDFs in the MERL layout (Matusik et al. 2003, "A Data-Driven Reflectance
// Model"): 90 x 90 x 180 samples over (theta_h, theta_d, phi_d) of the Rusinkiewicz half/difference
// parameterisation, theta_h indexed non-linearly (index = 90 sqrt(theta_h / (pi/2))), phi_d over
// [0, pi) by reciprocity.
//
// File (.binary): three int32 dims (90, 90, 180), then 3 x 1,458,000 doubles: all red, all green,
// all blue, each scaled by 1/1500, 1.15/1500, 1.66/1500 (the reader multiplies); negative entries
// mark unmeasured samples.
//
// MerlBrdf is also the project's own "tabulated" BRDF: Tabulate() samples any analytic model at the
// table's nodes and Write() stores it in the MERL layout, so the measured path can be exercised
// without external data. Importance sampling uses a per-wo table of f * cos over the half vector (a
// Warp2D, the same exact bilinear warp as the RGL reader), so Pdf() is exact for Sample().

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "brdf/common.h"
#include "brdf/energy.h"
#include "brdf/warp2d.h"

namespace mesoscan {

enum class MerlInterpolation {
  kNearest,  // the reference MERL lookup: truncate each index (BRDFRead.cpp)
  kLinear,   // trilinear between the same nodes (table entry i sits at index i
             // exactly)
};

struct MerlOptions {
  // How f() reads the table between nodes.
  MerlInterpolation interpolation = MerlInterpolation::kLinear;
  // Unmeasured entries (negative in the file) are an error unless this is true; then they read as 0
  // and a warning names how many there were.
  bool accept_invalid_entries = false;
  // Importance-sampling table: half-vector grid (theta x phi nodes, >= 2 each) per tabulated
  // outgoing elevation (>= 2). Larger resolves sharper highlights, costs memory and load time.
  int sampling_theta_nodes = 64;
  int sampling_phi_nodes = 64;
  int sampling_wo_nodes = 24;
  // Energy clamp (brdf/energy.h): where the table's directional albedo exceeds 1 in a channel, f is
  // scaled by min(s(theta_o), s(theta_i)) with s = min(1, 0.997 / albedo), which keeps f reciprocal
  // and bounds the albedo by 1. One warning line names the file. false keeps the values as they
  // are. LoadBrdf passes it on to RGL files too.
  bool energy_clamp = true;

  // Throws Error(kBadInput) naming the field when out of range.
  void Check() const;
};

class MerlBrdf {
 public:
  static constexpr const char* Name() { return "merl"; }
  static constexpr int kThetaH = 90, kThetaD = 90, kPhiD = 180;
  static constexpr size_t kEntries = size_t{kThetaH} * kThetaD * kPhiD;  // per channel
  static constexpr size_t kFileBytes = 12 + 3 * kEntries * sizeof(double);
  static constexpr double kScale[3] = {1.0 / 1500, 1.15 / 1500, 1.66 / 1500};

  // Reads a .binary file; throws Error(kBadInput) naming the file and what is wrong (size,
  // dimensions, NaN/Inf, negative entries unless accepted).
  static std::shared_ptr<const MerlBrdf> Load(const std::filesystem::path& path,
                                              const MerlOptions& options = {});
  // Samples an analytic BRDF f(wo, wi) (no cosine) at every node. Nodes whose directions fall below
  // the horizon keep the model's value at the closest valid configuration (clamped elevation), so
  // interpolation near grazing angles stays smooth.
  static std::shared_ptr<const MerlBrdf> Tabulate(
      const std::function<Rgb(const Vec3& wo, const Vec3& wi)>& model,
      const MerlOptions& options = {});
  // Writes the table in the MERL layout (scaled), atomically.
  void Write(const std::filesystem::path& path) const;

  Rgb f(const Vec3& wo, const Vec3& wi) const;
  std::optional<BrdfSample> Sample(const Vec3& wo, const Vec2& u) const;
  double Pdf(const Vec3& wo, const Vec3& wi) const;

  // A cheap stand-in for Luminance(f(wo, wi)) where only the shape matters (a sampler's proposal
  // weights, e.g. MirrorGuide::Prepare): the nearest node of a luminance table at half the
  // resolution in theta_d and phi_d (1.5 MB, so it stays in a core's cache, where the full RGB
  // table's 17.5 MB does not), without the energy clamp. >= 0; 0 below the horizon.
  double ProxyLuminance(const Vec3& wo, const Vec3& wi) const;

  // Table value at half/difference angles (radians), with the configured interpolation.
  Rgb Lookup(double theta_h, double theta_d, double phi_d) const;
  // Raw node value (unscaled units: 1/sr).
  Rgb Node(int i_theta_h, int i_theta_d, int i_phi_d) const;
  const MerlOptions& options() const { return options_; }
  size_t invalid_entries() const { return invalid_entries_; }
  // Albedo per outgoing elevation before the clamp, and the clamp applied.
  const EnergyClamp& energy() const { return energy_; }

 private:
  MerlBrdf() = default;
  void BuildSamplingTable();
  void BuildProxy();
  // Estimates the albedo on a grid of elevations and sets energy_ (logs when it exceeds 1;
  // `source` names the file or "tabulated model").
  void BuildEnergyClamp(const std::string& source);
  Rgb RawF(const Vec3& wo, const Vec3& wi) const;

  MerlOptions options_;
  std::vector<float> rgb_;  // [theta_h][theta_d][phi_d][channel] (RGB interleaved), 1/sr
  size_t invalid_entries_ = 0;
  std::vector<float> proxy_;  // [theta_h][theta_d / 2][phi_d / 2]: mean luminance of 4 nodes
  Warp2D sampling_;           // density over (u_theta_m, u_phi_m) per wo elevation
  EnergyClamp energy_;
};

// Rusinkiewicz half/difference angles of a direction pair (MERL BRDFRead.cpp convention).
void HalfDiffAngles(const Vec3& wi, const Vec3& wo, double* theta_h, double* theta_d,
                    double* phi_d);

}  // namespace mesoscan
