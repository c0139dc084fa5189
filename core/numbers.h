#pragma once
// Mathematical constants, one home for the project (std::numbers, C++20).

#include <numbers>

namespace mesoscan {

inline constexpr double kPi = std::numbers::pi;

}  // namespace mesoscan
