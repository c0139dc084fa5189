#pragma once
// A rectangle of pixels, and its one command-line syntax. The one type for every region a user
// names: the reconstruction ROI (`reconstruct --roi`, camera pixels), the simulator's camera crop
// (`simulate --crop`, pixels of the rig's camera) and the export / map-set crop (`export --crop`,
// `maps --crop`, pixels of the scan's height grid).

#include <string>

namespace mesoscan {

struct PixelRect {
  int x = 0, y = 0;  // top-left pixel (column, row), >= 0
  int w = 0, h = 0;  // size in pixels; w == 0 or h == 0 means "the whole image"
  bool whole() const { return w == 0 || h == 0; }
  bool operator==(const PixelRect&) const = default;
};

// "X,Y,W,H" (the syntax of every region option), or "WxH+X+Y" (X11 geometry: the spelling the
// simulator's crop has always documented, kept for its scripts). X, Y >= 0, W, H >= 1.
// Throws Error(kUsage) "'<text>': expected X,Y,W,H ..." at the options field `option`
// ("FrameLoadOptions.roi").
PixelRect ParsePixelRect(const std::string& text, const std::string& option);

// "X,Y,W,H", as the option takes it.
std::string ToString(const PixelRect& rect);

}  // namespace mesoscan
