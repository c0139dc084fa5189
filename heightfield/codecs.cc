#include "heightfield/codecs.h"

namespace mesoscan {

void CodecOptions::Check() const { graycode.Check(); }

Json CodecOptions::ToJson() const {
  return {{"graycode",
           {{"min_bit_snr", graycode.min_bit_snr},
            {"full_bit_snr", graycode.full_bit_snr},
            {"min_bit_contrast", graycode.min_bit_contrast},
            {"min_noise", graycode.min_noise},
            {"edge_points", graycode.edge_points}}}};
}

std::vector<std::shared_ptr<PlannedCodec>> PlanCodecs(const Session& session,
                                                      const CodecOptions& options,
                                                      ReconstructPlan* plan) {
  std::vector<std::shared_ptr<PlannedCodec>> codecs;
  if (auto c = PlanGrayCode(session, options.graycode, plan)) codecs.push_back(std::move(c));
  return codecs;
}

}  // namespace mesoscan
