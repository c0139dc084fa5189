#include "brdf/brdf_plot.h"

#include <gtest/gtest.h>

#include "core/error.h"

namespace mesoscan {
namespace {

// Fraction of pixels inside `rows` x all columns that differ from the background.
double InkFraction(const ImageU8& im, int y0, int y1) {
  size_t ink = 0, all = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = 0; x < im.width(); ++x, ++all)
      ink += im(x, y, 0) != 24 || im(x, y, 1) != 24 || im(x, y, 2) != 24;
  return static_cast<double>(ink) / all;
}

TEST(BrdfPlot, DrawsEveryPanel) {
  BrdfPlotOptions o;
  o.theta_o_deg = {0, 45};
  o.panel_px = 240;
  o.title = "ggx";
  const ImageU8 im = PlotBrdf(Brdf(GgxBrdf<double>::Dielectric(0.2, 1.5)), o);
  EXPECT_EQ(im.channels(), 3);
  EXPECT_EQ(im.width(), 2 * 240);
  // Polar plots and hemisphere maps both put ink on the page.
  EXPECT_GT(InkFraction(im, 34, 34 + 160), 0.02);
  EXPECT_GT(InkFraction(im, 34 + 160, im.height()), 0.2);
  // A reddish Lambertian shows red in its hemisphere map.
  const ImageU8 red = PlotBrdf(Brdf(LambertBrdf(Rgb(0.8, 0.1, 0.1))), o);
  // Away from the markers drawn at the centre (wo at normal incidence).
  const int cx = 120 + 30, cy = 34 + 160 + 24 + (240 - 40) / 2 - 8;
  EXPECT_GT(red(cx, cy, 0), 2 * red(cx, cy, 1))
      << int(red(cx, cy, 0)) << " " << int(red(cx, cy, 1));
}

TEST(BrdfPlot, RejectsBadOptions) {
  BrdfPlotOptions o;
  o.theta_o_deg = {95};
  EXPECT_THROW(PlotBrdf(Brdf(LambertBrdf()), o), Error);
  o.theta_o_deg = {};
  EXPECT_THROW(o.Check(), Error);
}

}  // namespace
}  // namespace mesoscan
