#include "core/budget.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace mesoscan {

uint64_t MemoryBudgetBytes() {
  static const uint64_t budget = [] {
    if (const char* env = std::getenv("MESOSCAN_MEMORY_BUDGET_MB")) {
      char* end = nullptr;
      const double mb = std::strtod(env, &end);
      if (end != env && mb > 0 && std::isfinite(mb)) return static_cast<uint64_t>(mb * 1048576.0);
    }
    const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    const uint64_t phys = pages > 0 && page > 0 ? static_cast<uint64_t>(pages) * page : 0;
    const uint64_t cap = uint64_t{8} << 30;
    return phys == 0 ? cap : std::min(phys / 2, cap);
  }();
  return budget;
}

void CheckMemoryBudget(const std::string& what, double bytes, ErrorKind kind) {
  const double budget = static_cast<double>(MemoryBudgetBytes());
  if (bytes <= budget) return;  // NaN fails here too
  MESOSCAN_THROW(kind, what << ": needs " << std::llround(std::min(bytes, 1e18) / 1048576.0)
                            << " MB, over the memory budget of " << std::llround(budget / 1048576.0)
                            << " MB (set MESOSCAN_MEMORY_BUDGET_MB to change it)");
}

}  // namespace mesoscan
