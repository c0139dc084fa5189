#pragma once
// Errors and checks (pbrt util/check.h, Ceres style).
//
// Bad input, bad configuration and failed I/O throw mesoscan::Error naming the file and key or
// frame; app/ catches it and prints one line with a distinct exit code. A broken invariant is a
// bug: MESOSCAN_CHECK throws an Error of kind kInternal (exit 70) with file:line and both values.

#include <sstream>
#include <stdexcept>
#include <string>

namespace mesoscan {

// Process exit codes, one per kind of failure (README "Exit codes").
enum class ErrorKind : int {
  kUsage = 2,      // wrong command-line usage
  kBadInput = 3,   // a file or key the user gave is missing, unreadable or invalid
  kDevice = 4,     // camera, projector or lens-shifter failure
  kInternal = 70,  // a broken invariant: a bug in mesoscan (EX_SOFTWARE)
};

class Error : public std::runtime_error {
 public:
  explicit Error(std::string message, ErrorKind kind = ErrorKind::kBadInput)
      : std::runtime_error(std::move(message)), kind_(kind) {}
  ErrorKind kind() const { return kind_; }
  int exit_code() const { return static_cast<int>(kind_); }

 private:
  ErrorKind kind_;
};

// Builds a message with operator<< and throws it: `throw MakeError(kind) << "file: key ..."`
// reads badly, so use MESOSCAN_THROW(kind, "file: " << x << ...).
#define MESOSCAN_THROW(kind, stream_expr)                 \
  do {                                                    \
    std::ostringstream mesoscan_oss_;                     \
    mesoscan_oss_ << stream_expr;                         \
    throw ::mesoscan::Error(mesoscan_oss_.str(), (kind)); \
  } while (0)

#define MESOSCAN_BAD_INPUT(stream_expr) \
  MESOSCAN_THROW(::mesoscan::ErrorKind::kBadInput, stream_expr)

#define MESOSCAN_CHECK(cond)                                                                    \
  do {                                                                                          \
    if (!(cond))                                                                                \
      MESOSCAN_THROW(                                                                           \
          ::mesoscan::ErrorKind::kInternal,                                                     \
          "internal error: " << __FILE__ << ":" << __LINE__ << ": CHECK(" #cond << ") failed"); \
  } while (0)

#define MESOSCAN_CHECK_OP(a, op, b)                                                  \
  do {                                                                               \
    const auto& mesoscan_a_ = (a);                                                   \
    const auto& mesoscan_b_ = (b);                                                   \
    if (!(mesoscan_a_ op mesoscan_b_))                                               \
      MESOSCAN_THROW(::mesoscan::ErrorKind::kInternal,                               \
                     "internal error: " << __FILE__ << ":" << __LINE__               \
                                        << ": CHECK(" #a " " #op " " #b ") failed: " \
                                        << mesoscan_a_ << " vs " << mesoscan_b_);    \
  } while (0)

#define MESOSCAN_CHECK_EQ(a, b) MESOSCAN_CHECK_OP(a, ==, b)
#define MESOSCAN_CHECK_NE(a, b) MESOSCAN_CHECK_OP(a, !=, b)
#define MESOSCAN_CHECK_LT(a, b) MESOSCAN_CHECK_OP(a, <, b)
#define MESOSCAN_CHECK_LE(a, b) MESOSCAN_CHECK_OP(a, <=, b)
#define MESOSCAN_CHECK_GT(a, b) MESOSCAN_CHECK_OP(a, >, b)
#define MESOSCAN_CHECK_GE(a, b) MESOSCAN_CHECK_OP(a, >=, b)

// DCHECK: compiled out of hot loops in release builds.
#ifdef NDEBUG
#define MESOSCAN_DCHECK(cond) \
  do {                        \
  } while (false && (cond))
#else
#define MESOSCAN_DCHECK(cond) MESOSCAN_CHECK(cond)
#endif

}  // namespace mesoscan
