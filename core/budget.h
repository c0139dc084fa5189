#pragma once
// Memory budget: every size a user or a file controls (image headers, grid pixel sizes, render
// sizes, crops) is checked against it before anything is allocated, so a hostile or careless
// value fails in milliseconds with one line instead of swapping the machine or dying in
// std::bad_alloc. The budget is MESOSCAN_MEMORY_BUDGET_MB if set, else half the physical
// memory, at most 8 GiB.

#include <cstdint>
#include <string>

#include "core/error.h"

namespace mesoscan {

// The budget in bytes (read once per process).
uint64_t MemoryBudgetBytes();

// Throws Error(kind) at `site`, "<what>: needs N MB, over the memory budget of M MB (...)", if
// `bytes` (a double, so products of hostile sizes cannot overflow; NaN and inf fail) exceeds the
// budget.
void CheckMemoryBudget(const std::string& what, double bytes, ErrorKind kind = ErrorKind::kBadInput,
                       const ErrorSite& site = {});

}  // namespace mesoscan
