#include "core/budget.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace mesoscan {

uint64_t MemoryBudgetBytes() {
  static const uint64_t budget = [] {
    if (const char* env = std::getenv("MESOSCAN_MEMORY_BUDGET_MB")) {
      // A number of MB > 0, nothing else (a typo must not silently mean the default); values
      // beyond 2^40 MB (1 EB) mean "no budget" and are held there (no overflow to 0).
      char* end = nullptr;
      const double mb = std::strtod(env, &end);
      while (end && (*end == ' ' || *end == '\t')) ++end;
      if (end == env || *end != '\0' || !(mb > 0) || std::isnan(mb))
        MESOSCAN_THROW(ErrorKind::kUsage,
                       "MESOSCAN_MEMORY_BUDGET_MB: expected a number of MB > 0, "
                       "got '"
                           << env << "'");
      return static_cast<uint64_t>(std::min(mb, 1099511627776.0) * 1048576.0);
    }
    const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    const uint64_t phys = pages > 0 && page > 0 ? static_cast<uint64_t>(pages) * page : 0;
    const uint64_t cap = uint64_t{8} << 30;
    return phys == 0 ? cap : std::min(phys / 2, cap);
  }();
  return budget;
}

void CheckMemoryBudget(const std::string& what, double bytes, ErrorKind kind,
                       const ErrorSite& site) {
  const double budget = static_cast<double>(MemoryBudgetBytes());
  if (bytes <= budget) return;  // NaN fails here too
  MESOSCAN_THROW_AT(kind, site,
                    what << ": needs " << std::llround(std::min(bytes, 1e18) / 1048576.0)
                         << " MB, over the memory budget of " << std::llround(budget / 1048576.0)
                         << " MB (set MESOSCAN_MEMORY_BUDGET_MB to change it)");
}

}  // namespace mesoscan
