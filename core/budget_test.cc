#include "core/budget.h"

#include <gtest/gtest.h>

#include <cmath>

namespace mesoscan {
namespace {

TEST(Budget, RefusesOverflowAndNaNAtTheGivenKindAndSite) {
  EXPECT_GT(MemoryBudgetBytes(), 0u);
  EXPECT_NO_THROW(CheckMemoryBudget("small", 1e6));
  EXPECT_THROW(CheckMemoryBudget("huge", 1e300), Error);
  EXPECT_THROW(CheckMemoryBudget("nan", std::nan("")), Error);
  EXPECT_THROW(CheckMemoryBudget("inf", INFINITY), Error);
  try {
    CheckMemoryBudget("a 1e9x1e9 image", 1e300, ErrorKind::kUsage, ErrorSite::File("x.png"));
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage);
    EXPECT_EQ(e.file(), "x.png");
    EXPECT_NE(std::string(e.what()).find("x.png: a 1e9x1e9 image: needs"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace mesoscan
