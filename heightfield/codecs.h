#pragma once
// The pattern codecs that planning looks for besides phase shifting and the lens shift
// (heightfield/codec.h PlannedCodec), each with its options: adding a codec is its own file, a
// field and a line here, and a line in codecs.cc.

#include <memory>
#include <vector>

#include "core/json.h"
#include "heightfield/codec.h"
#include "heightfield/codec_graycode.h"
#include "session/session.h"

namespace mesoscan {

struct ReconstructPlan;

struct CodecOptions {
  GrayCodeOptions graycode;
  void Check() const;
  Json ToJson() const;
};

// Every planned codec that finds frames of its pattern family along plan->axis in `session`,
// in this order; their frames are appended to plan->frames.
std::vector<std::shared_ptr<PlannedCodec>> PlanCodecs(const Session& session,
                                                      const CodecOptions& options,
                                                      ReconstructPlan* plan);

}  // namespace mesoscan
