#pragma once
// Annotations drawn on the preview's display images (8-bit sRGB, 3 channels) with OpenCV's
// Hershey fonts (no font files): labels over a side by side, and a scale bar.

#include <string>

#include "core/image.h"

namespace mesoscan {

// `left` and `right` (same height, 3 channels) next to each other, 4 white pixels apart, under a
// white strip holding each one's label (centred over it, shrunk to fit). The images' pixels are
// copied unchanged below the strip: LabelStripHeight(height) rows.
ImageU8 LabelledSideBySide(const ImageU8& left, const ImageU8& right, const std::string& left_label,
                           const std::string& right_label);
int LabelStripHeight(int image_height);

// A scale bar in the lower left corner: a white bar with a dark outline whose length is the
// round length (1, 2 or 5 x 10^k metres) nearest a fifth of the image width at `pixels_per_metre`,
// labelled ("5 mm"). Returns the bar's length in metres (0: nothing drawn, the bar would be
// under 8 pixels or wider than the image).
double DrawScaleBar(ImageU8* image, double pixels_per_metre);

// "5 mm", "200 um", "1 cm"...: a round length for the bar's label.
std::string LengthLabel(double metres);

}  // namespace mesoscan
