#pragma once
// The projector coordinates of a calibration view through the reconstruction's codec seam
// (heightfield/codec.h): for a board session whose patterns include a planned codec (Gray code
// alone, or one sine period ordered by a complementary Gray code), each projector axis is planned
// as reconstruction plans its decoding axis (heightfield/stage_plan.h MakeReconstructPlan on the
// session's frames along that axis, white and black), its frames classified, phase-shifted where
// there is a sine set, decoded by the planned codecs, and read through the absolute codec the
// combine stage would use (the Gray code, or the sine period it orders: OrderedCodec). A pixel
// has a coordinate where that codec holds it (every bit read; a code edge, one bit unknown
// between two neighbouring blocks, only where a sine period orders the code) at a confidence of at
// least `min_confidence`; no coordinate is guessed.
//
// Calibration reads each Gray-code bit against its own inverse (the pixel's threshold, robust to
// the board's albedo and to the defocus of a tilted board): a set without inverse frames, Gray
// codes of two kinds along one axis, or axes coded differently (a Gray code along x, sines alone
// along y) are refused with one line naming session.json's `frames` key. Pixels saturated in a
// frame are read too where no sine set is involved (a binary code survives clipping; OpenCV's
// decoder reads them alike).

#include <memory>
#include <string>
#include <vector>

#include "session/session.h"

namespace mesoscan {

// True if any frame at shift 0 shows a planned codec's pattern (Gray code).
bool HasCodedFrames(const Session& session);

class CodedBoardFrames {
 public:
  // Plans both axes and loads their frames. Throws Error(kBadInput) naming session.json's
  // `frames` key (see above) or an unreadable frame.
  explicit CodedBoardFrames(const Session& session);
  ~CodedBoardFrames();
  CodedBoardFrames(const CodedBoardFrames&) = delete;
  CodedBoardFrames& operator=(const CodedBoardFrames&) = delete;

  // The board's texture for the corner detector, width x height: the white frame, else the mean
  // of the sine set along x.
  std::vector<float> Texture() const;
  // The projector (u, v) at camera pixels `pixels` (index y * width + x); NaN where the codec of
  // either axis gives none at confidence >= min_confidence.
  void Decode(const std::vector<uint32_t>& pixels, double min_confidence, std::vector<float>* u,
              std::vector<float>* v) const;
  int eight_bit_frames() const;
  // "graycode" or "sine+graycode": the codec of both axes (for the report).
  const std::string& codec() const;

 private:
  struct Axis;
  std::unique_ptr<Axis> axis_[2];
  int width_ = 0, height_ = 0;
};

}  // namespace mesoscan
