// mesoscan brdf info|plot|tabulate: inspect measured BRDFs and write MERL-layout tables.

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>

#include "app/commands.h"
#include "brdf/brdf.h"
#include "brdf/brdf_plot.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/output_dir.h"

namespace mesoscan {
namespace {

std::string Triple(const Rgb& c) {
  char buf[96];
  std::snprintf(buf, sizeof(buf), "(%.3f, %.3f, %.3f)", c[0], c[1], c[2]);
  return buf;
}

MerlOptions MerlOptionsFrom(bool accept_invalid) {
  MerlOptions o;
  o.accept_invalid_entries = accept_invalid;
  return o;
}

// The first bytes of `path` equal `magic` (recognises an earlier output before replacing it).
bool StartsWith(const std::filesystem::path& path, const std::string& magic) {
  std::ifstream in(path, std::ios::binary);
  std::string head(magic.size(), '\0');
  return in.read(head.data(), static_cast<std::streamsize>(head.size())) && head == magic;
}

bool IsPng(const std::filesystem::path& p) { return StartsWith(p, "\x89PNG\r\n\x1a\n"); }

bool IsMerlTable(const std::filesystem::path& p) {
  const int32_t dims[3] = {90, 90, 180};
  return StartsWith(p, std::string(reinterpret_cast<const char*>(dims), sizeof(dims)));
}

}  // namespace

void AddBrdfCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand("brdf", "Inspect measured BRDFs (RGL .bsdf, MERL .binary)");
  cmd->require_subcommand(1);

  // brdf info FILE
  auto* info = cmd->add_subcommand("info", "Format, resolution and albedo range of a BRDF file");
  static std::string info_file;
  static bool info_accept = false;
  info->add_option("file", info_file, "RGL .bsdf or MERL .binary file")->required();
  info->add_flag("--accept-invalid", info_accept,
                 "MERL: read negative (unmeasured) entries as 0 instead of "
                 "refusing the file");
  info->callback([] {
    const Brdf brdf = LoadBrdf(info_file, MerlOptionsFrom(info_accept));
    const BrdfInfo i = DescribeBrdf(brdf);
    std::printf("file:        %s\n", info_file.c_str());
    std::printf("format:      %s\n", i.format.c_str());
    if (!i.description.empty()) std::printf("description: %s\n", i.description.c_str());
    std::printf("resolution:  %s\n", i.resolution.c_str());
    std::printf(
        "albedo:      min %s at theta_o %.0f deg, max %s at theta_o %.0f deg "
        "(RGB directional albedo, theta_o 0..85 deg)\n",
        Triple(i.albedo_min).c_str(), i.albedo_min_theta_deg, Triple(i.albedo_max).c_str(),
        i.albedo_max_theta_deg);
    if (!i.energy.empty()) {
      // "energy clamped: ..." -> "energy:      clamped: ..."
      const std::string e = i.energy.rfind("energy ", 0) == 0 ? i.energy.substr(7) : i.energy;
      std::printf("energy:      %s\n", e.c_str());
    }
  });

  // brdf plot FILE --out x.png
  auto* plot = cmd->add_subcommand("plot", "Polar plots and hemisphere maps of f*cos as a PNG");
  static std::string plot_file, plot_out;
  static BrdfPlotOptions plot_options;
  static bool plot_accept = false, plot_force = false;
  plot->add_option("file", plot_file, "RGL .bsdf or MERL .binary file")->required();
  plot->add_option("--out,-o", plot_out, "Output PNG (8-bit RGB)")->required();
  plot->add_option("--theta", plot_options.theta_o_deg,
                   "Incident elevations in degrees, one column each")
      ->capture_default_str();
  plot->add_option("--panel", plot_options.panel_px, "Column width in pixels (>= 200)")
      ->capture_default_str();
  plot->add_flag("--accept-invalid", plot_accept, "MERL: read negative entries as 0");
  plot->add_flag("--force", plot_force, "Replace an existing --out that is not a PNG");
  plot->callback([] {
    CheckOutputFile({"brdf plot", "--out", plot_out, {plot_file}, plot_force, {}}, IsPng);
    plot_options.Check();
    const Brdf brdf = LoadBrdf(plot_file, MerlOptionsFrom(plot_accept));
    BrdfPlotOptions o = plot_options;
    std::string name = std::filesystem::path(plot_file).filename().string();
    if (const auto* rgl = brdf.Get<RglBrdf>(); rgl && !rgl->description().empty())
      name += ": " + rgl->description();
    o.title = name;
    WritePng8(plot_out, PlotBrdf(brdf, o));
    MESOSCAN_LOG(kInfo) << "wrote " << plot_out;
  });

  // brdf tabulate --alpha A --out x.binary: an analytic GGX in the MERL layout (demo data).
  auto* tab = cmd->add_subcommand("tabulate",
                                  "Write an analytic GGX (optionally over "
                                  "Lambert) as a MERL-layout .binary");
  static std::string tab_out;
  static bool tab_force = false;
  static double tab_alpha = 0.2, tab_eta = 1.5;
  static std::vector<double> tab_diffuse = {0.0, 0.0, 0.0};
  static std::string tab_fresnel = "dielectric";
  static std::vector<double> tab_cond_eta = {0.200, 0.924, 1.102},
                             tab_cond_k = {3.912, 2.452, 2.142};
  tab->add_option("--out,-o", tab_out, "Output .binary file")->required();
  tab->add_option("--alpha", tab_alpha, "GGX roughness in [0.001, 1]")->capture_default_str();
  tab->add_option("--fresnel", tab_fresnel, "dielectric or conductor")
      ->check(CLI::IsMember({"dielectric", "conductor"}))
      ->capture_default_str();
  tab->add_option("--eta", tab_eta, "Dielectric index of refraction")->capture_default_str();
  tab->add_option("--conductor-eta", tab_cond_eta, "Conductor eta (R G B), default copper")
      ->expected(3);
  tab->add_option("--conductor-k", tab_cond_k, "Conductor k (R G B), default copper")->expected(3);
  tab->add_option("--diffuse", tab_diffuse, "Lambertian base albedo (R G B) added to the GGX")
      ->expected(3);
  tab->add_flag("--force", tab_force, "Replace an existing --out that is not a MERL table");
  tab->callback([] {
    CheckOutputFile({"brdf tabulate", "--out", tab_out, {}, tab_force, {}}, IsMerlTable);
    const GgxBrdf<double> ggx =
        tab_fresnel == "conductor"
            ? GgxBrdf<double>::Conductor(tab_alpha,
                                         Rgb(tab_cond_eta[0], tab_cond_eta[1], tab_cond_eta[2]),
                                         Rgb(tab_cond_k[0], tab_cond_k[1], tab_cond_k[2]))
            : GgxBrdf<double>::Dielectric(tab_alpha, tab_eta);
    ggx.Check();
    const LambertBrdf diffuse(Rgb(tab_diffuse[0], tab_diffuse[1], tab_diffuse[2]));
    if ((diffuse.albedo() < 0).any() || (diffuse.albedo() > 1).any())
      MESOSCAN_BAD_INPUT("--diffuse: each albedo must be in [0, 1]");
    const auto table = MerlBrdf::Tabulate(
        [&](const Vec3& wo, const Vec3& wi) { return Rgb(ggx.f(wo, wi) + diffuse.f(wo, wi)); });
    table->Write(tab_out);
    MESOSCAN_LOG(kInfo) << "wrote " << tab_out;
  });
}

}  // namespace mesoscan
