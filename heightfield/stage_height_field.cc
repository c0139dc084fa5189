#include "heightfield/stage_height_field.h"

#include <limits>

namespace mesoscan {

HeightFieldResult MakeHeightField(const ScanPoints& points, const ResampleOptions& options) {
  HeightFieldResult r;
  r.height = ResampleToGrid(points.xyz, points.confidence, options);
  if (r.height.z.empty()) {  // nothing reconstructed: a 1x1 unknown grid keeps the layout
    r.height.z = ImageF(1, 1, 1, std::numeric_limits<float>::quiet_NaN());
    r.height.confidence = ImageF(1, 1, 1, 0.0f);
  }
  r.normals = r.height.Normals();
  return r;
}

}  // namespace mesoscan
