#include "brdf/merl.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <fstream>

#include "brdf/brdf.h"
#include "brdf/brdf_test_util.h"
#include "core/error.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;
using testing::ChiSquareTest;
using testing::kSampleScale;
using testing::RandomUpperDirection;

const Rgb kCopperEta(0.200, 0.924, 1.102), kCopperK(3.912, 2.452, 2.142);

fs::path TempDir(const std::string& name) { return TestTempDir("brdf_test", name); }

class MerlTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    ggx_ = new GgxBrdf<double>(GgxBrdf<double>::Conductor(0.3, kCopperEta, kCopperK));
    dir_ = new fs::path(TempDir("merl"));
    const auto table =
        MerlBrdf::Tabulate([](const Vec3& wo, const Vec3& wi) { return Rgb(ggx_->f(wo, wi)); });
    table->Write(*dir_ / "ggx.binary");
    loaded_ = MerlBrdf::Load(*dir_ / "ggx.binary");
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
    delete ggx_;
    loaded_.reset();
  }
  // A copy of the written file with `edit` applied to its bytes.
  static fs::path EditedCopy(const std::string& name,
                             const std::function<void(std::vector<char>&)>& edit) {
    std::ifstream in(*dir_ / "ggx.binary", std::ios::binary);
    std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    edit(bytes);
    const fs::path p = *dir_ / name;
    std::ofstream(p, std::ios::binary).write(bytes.data(), bytes.size());
    return p;
  }
  static void SetEntry(std::vector<char>& bytes, size_t index, double v) {
    std::memcpy(bytes.data() + 12 + index * sizeof(double), &v, sizeof(double));
  }
  // Expects Load to throw Error(kBadInput) whose one-line message contains `needle`.
  static void ExpectBadInput(const fs::path& p, const std::string& needle) {
    try {
      MerlBrdf::Load(p);
      ADD_FAILURE() << "no error for " << p;
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(p.filename().string()), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    }
  }

  static inline GgxBrdf<double>* ggx_ = nullptr;
  static inline fs::path* dir_ = nullptr;
  static inline std::shared_ptr<const MerlBrdf> loaded_;
};

TEST_F(MerlTest, FileHasTheMerlLayout) {
  EXPECT_EQ(fs::file_size(*dir_ / "ggx.binary"), 34992012u);
  std::ifstream in(*dir_ / "ggx.binary", std::ios::binary);
  int32_t dims[3];
  in.read(reinterpret_cast<char*>(dims), sizeof(dims));
  EXPECT_EQ(dims[0], 90);
  EXPECT_EQ(dims[1], 90);
  EXPECT_EQ(dims[2], 180);
  // The first red entry is f at theta_h = theta_d = 0 (normal incidence), divided by 1/1500.
  double first;
  in.read(reinterpret_cast<char*>(&first), sizeof(first));
  const Vec3 n(0, 0, 1);
  EXPECT_NEAR(first / 1500.0, ggx_->f(n, n)[0], 1e-6 * ggx_->f(n, n)[0]);
}

TEST_F(MerlTest, RoundTripAgreesWithAnalyticGgxWithinOnePercent) {
  std::mt19937 rng(11);
  double worst = 0;
  int n = 0;
  for (int i = 0; i < 20000; ++i) {
    // Directions up to 78 degrees, so no trilinear stencil reaches below the horizon.
    const Vec3 wo = RandomUpperDirection(rng, 0.2), wi = RandomUpperDirection(rng, 0.2);
    const Rgb ref = ggx_->f(wo, wi), got = loaded_->f(wo, wi);
    for (int c = 0; c < 3; ++c) {
      const double rel = std::abs(got[c] - ref[c]) / ref[c];
      worst = std::max(worst, rel);
      EXPECT_LT(rel, 0.01) << "channel " << c << " wo " << wo.transpose() << " wi "
                           << wi.transpose() << " ref " << ref[c] << " got " << got[c];
      ++n;
    }
    if (::testing::Test::HasFailure()) break;
  }
  RecordProperty("worst_relative_error", std::to_string(worst));
  std::printf("MERL round trip: worst relative error %.4f%% over %d values\n", 100 * worst, n);
}

TEST_F(MerlTest, NearestLookupIsTheReferenceIndexing) {
  MerlOptions nearest;
  nearest.interpolation = MerlInterpolation::kNearest;
  const auto t = MerlBrdf::Load(*dir_ / "ggx.binary", nearest);
  // theta_h just below node 40's upper edge reads node 40 (index = floor(90 sqrt(th / (pi/2))));
  const double th = std::pow(40.99 / 90, 2) * kPi / 2, td = 10.5 * kPi / 180, pd = 20.5 * kPi / 180;
  EXPECT_TRUE((t->Lookup(th, td, pd) == t->Node(40, 10, 20)).all());
  // phi_d < 0 maps to phi_d + pi (reciprocity).
  EXPECT_TRUE((t->Lookup(th, td, pd - kPi) == t->Node(40, 10, 20)).all());
  // Linear interpolation hits the nodes exactly.
  const double th_node = std::pow(40.0 / 90, 2) * kPi / 2;
  const Rgb a = loaded_->Lookup(th_node, 10 * kPi / 180, 20 * kPi / 180), b = t->Node(40, 10, 20);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], 1e-6 * b[c]);
}

TEST_F(MerlTest, HalfDiffAnglesInvertTheConstruction) {
  std::mt19937 rng(4);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 wo = RandomUpperDirection(rng), wi = RandomUpperDirection(rng);
    double th, td, pd;
    HalfDiffAngles(wi, wo, &th, &td, &pd);
    const Vec3 h = (wi + wo).normalized();
    EXPECT_NEAR(std::cos(th), h.z(), 1e-9);
    EXPECT_NEAR(std::cos(td), wi.dot(h), 1e-9);
    double th2, td2, pd2;
    HalfDiffAngles(wo, wi, &th2, &td2, &pd2);
    EXPECT_NEAR(th, th2, 1e-9);
    EXPECT_NEAR(td, td2, 1e-9);
    EXPECT_NEAR(std::remainder(pd - pd2 - kPi, 2 * kPi), 0.0,
                1e-7);  // swapped: phi_d + pi
  }
}

TEST_F(MerlTest, ChiSquareFurnaceReciprocity) {
  const std::vector<double> thetas = {5, 45, 80};
  uint32_t seed = 100;
  for (double deg : thetas) {
    const auto r = ChiSquareTest(*loaded_, SphericalDirection(deg * kPi / 180, 1.0),
                                 20000 * kSampleScale, static_cast<int>(thetas.size()), seed++);
    EXPECT_GT(r.p_value, r.significance) << "theta_o " << deg;
    EXPECT_FALSE(r.sample_outside_support);
    const double sigma = std::sqrt(r.success_fraction * (1 - r.success_fraction) / r.samples);
    EXPECT_NEAR(r.pdf_integral, r.success_fraction, 5 * sigma + 2e-3) << "theta_o " << deg;
    EXPECT_LE(r.pdf_integral, 1.0 + 2e-3);
    std::printf("MERL theta_o %.0f: p %.3g, pdf integral %.4f, samples kept %.4f\n", deg, r.p_value,
                r.pdf_integral, r.success_fraction);
  }
  std::mt19937 rng(9);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 a = RandomUpperDirection(rng), b = RandomUpperDirection(rng);
    const Rgb fab = loaded_->f(a, b), fba = loaded_->f(b, a);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(fab[c], fba[c], 1e-6 * (1 + fab[c]));
  }
}

// White furnace of the tabulated copper GGX at every elevation 0..89.5 deg: albedo <= 1 + z SE per
// channel (plain Monte Carlo with the table's own sampling, SE = sd / sqrt(n); z: one-sided 1%
// family-wise over the 186 comparisons, 3.9). The copper table conserves energy, so the clamp
// stays off and the file's values are untouched.
TEST_F(MerlTest, WhiteFurnaceForEveryWo) {
  const auto thetas = testing::FurnaceElevationsDeg();
  const double z = testing::NormalUpperQuantile(0.01 / (thetas.size() * 3));
  const auto r = testing::SweepFurnace(*loaded_, thetas, 1000 * kSampleScale, 700);
  EXPECT_LE(r.worst_z, z) << r.worst_albedo << " +- " << r.worst_se << " at theta_o "
                          << r.worst_theta_deg;
  std::printf(
      "MERL copper: max albedo %.4f (SE %.4f) at theta_o %.2f, (albedo-1)/SE %.2f <= %.2f\n",
      r.worst_albedo, r.worst_se, r.worst_theta_deg, r.worst_z, z);
  EXPECT_FALSE(loaded_->energy().exceeds);
  EXPECT_FALSE(loaded_->energy().active);
  EXPECT_LT(loaded_->energy().MaxAlbedo(), 1.0);
}

// A user's table that reflects more than it receives (Lambertian, albedo 1.3 / 1.2 / 1.1: known
// exactly) is clamped at load: the original figures are kept, every channel ends at albedo 0.997
// (f = 0.997 / pi), the furnace holds at every wo and f stays reciprocal. A Lambertian table keeps
// the test ASan-fast; the clamp does not depend on the shape of f.
TEST_F(MerlTest, EnergyClampOfAnOverBrightTable) {
  const Rgb albedo(1.3, 1.2, 1.1);
  const auto t = MerlBrdf::Tabulate(
      [&](const Vec3& wo, const Vec3& wi) { return LambertBrdf(albedo).f(wo, wi); });
  const EnergyClamp& e = t->energy();
  ASSERT_TRUE(e.exceeds);
  EXPECT_TRUE(e.active);
  // Original figures: the exact albedo, up to the 96^2 quadrature (0.3%) and the table's
  // below-horizon nodes at grazing elevations.
  for (size_t i = 0; i < e.theta.size(); ++i) {
    if (e.theta[i] >= 80 * kPi / 180) continue;
    for (int c = 0; c < 3; ++c) ASSERT_NEAR(e.albedo[i][c], albedo[c], 0.005 * albedo[c]) << i;
  }
  EXPECT_NE(e.Summary().find("energy clamped: 61 of 61 elevations"), std::string::npos)
      << e.Summary();
  std::printf("%s\n", e.Summary().c_str());
  std::mt19937 rng(5);
  for (int i = 0; i < 300; ++i) {
    const Vec3 a = RandomUpperDirection(rng, 0.3), b = RandomUpperDirection(rng, 0.3);
    const Rgb fab = t->f(a, b), fba = t->f(b, a);
    for (int c = 0; c < 3; ++c) {
      ASSERT_NEAR(fab[c], fba[c], 1e-6 * (1 + fab[c]));
      ASSERT_NEAR(fab[c], 0.997 * kInvPi, 0.005 * kInvPi) << "channel " << c;
    }
  }
  const auto thetas = testing::FurnaceElevationsDeg();
  const double z = testing::NormalUpperQuantile(0.01 / (thetas.size() * 3));
  const auto r = testing::SweepFurnace(*t, thetas, 500 * kSampleScale, 900);
  EXPECT_LE(r.worst_z, z) << r.worst_albedo << " +- " << r.worst_se << " at theta_o "
                          << r.worst_theta_deg;
  EXPECT_GT(r.worst_albedo, 0.98) << "clamped to 0.997, not darkened further";
  std::printf("MERL over-bright, clamped: max albedo %.4f (SE %.4f) at theta_o %.2f\n",
              r.worst_albedo, r.worst_se, r.worst_theta_deg);
}

TEST_F(MerlTest, LoadBrdfDetectsMerl) {
  const Brdf b = LoadBrdf(*dir_ / "ggx.binary");
  EXPECT_EQ(std::string(b.Name()), "merl");
  EXPECT_TRUE(b.Is<MerlBrdf>());
  EXPECT_FALSE(b.Is<LambertBrdf>());
}

TEST_F(MerlTest, BadInputIsOneClearError) {
  ExpectBadInput(EditedCopy("truncated.binary", [](auto& b) { b.resize(b.size() / 2); }),
                 "truncated");
  ExpectBadInput(EditedCopy("tiny.binary", [](auto& b) { b.resize(7); }), "truncated");
  ExpectBadInput(EditedCopy("dims.binary",
                            [](auto& b) {
                              const int32_t d = 91;
                              std::memcpy(b.data(), &d, 4);
                            }),
                 "dimensions 91 x 90 x 180");
  ExpectBadInput(EditedCopy("nan.binary", [](auto& b) { SetEntry(b, 12345, NAN); }),
                 "entry 12345 of channel 0");
  ExpectBadInput(
      EditedCopy("inf.binary", [](auto& b) { SetEntry(b, MerlBrdf::kEntries + 7, INFINITY); }),
      "entry 7 of channel 1");
  const fs::path negative =
      EditedCopy("negative.binary", [](auto& b) { SetEntry(b, 2 * MerlBrdf::kEntries + 3, -1); });
  ExpectBadInput(negative, "negative");
  ExpectBadInput(EditedCopy("long.binary", [](auto& b) { b.push_back(0); }), "bytes, expected");
  ExpectBadInput(*dir_ / "missing.binary", "cannot open");
  // Unmeasured entries are accepted on request and read as 0.
  MerlOptions accept;
  accept.accept_invalid_entries = true;
  const auto t = MerlBrdf::Load(negative, accept);
  EXPECT_EQ(t->invalid_entries(), 1u);
  EXPECT_EQ(t->Node(0, 0, 3)[2], 0.0);
}

}  // namespace
}  // namespace mesoscan
