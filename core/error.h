#pragma once
// Errors and checks (pbrt util/error.h and util/check.h, Ceres style).
//
// Bad input, bad configuration and failed I/O throw mesoscan::Error. Its location is data, not
// text (pbrt's FileLoc): the file, the key inside it, the session frame, or the options field at
// fault, each a field of ErrorSite. The library names options by their field
// ("TileOptions.size_m"), never by a command-line flag: app/ alone maps fields to flags and
// formats the one line the user reads, with a distinct exit code per kind. A broken invariant is
// a bug: MESOSCAN_CHECK throws an Error of kind kInternal (exit 70) with file:line and both
// values.

#include <filesystem>
#include <functional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace mesoscan {

// Process exit codes, one per kind of failure (README "Exit codes").
enum class ErrorKind : int {
  kUsage = 2,      // a bad option value or combination (the caller's configuration)
  kBadInput = 3,   // a file or key the user gave is missing, unreadable or invalid
  kDevice = 4,     // camera, projector or lens-shifter failure
  kInternal = 70,  // a broken invariant: a bug in mesoscan (EX_SOFTWARE)
};

// Where a fault lies. Every field is optional; the formatted line names the option, the file,
// the key and the frame, in that order.
struct ErrorSite {
  std::string file;    // the file at fault, as the caller spelled it ("scan/height.exr")
  std::string key;     // the key inside `file` ("rig.camera.fx", "frames[3].phase")
  int frame = -1;      // the session frame at fault (index into Session::frames), or -1
  std::string option;  // the options field at fault ("FrameLoadOptions.roi")

  static ErrorSite File(const std::filesystem::path& file) { return {file.string(), "", -1, ""}; }
  static ErrorSite Key(const std::filesystem::path& file, std::string key) {
    return {file.string(), std::move(key), -1, ""};
  }
  static ErrorSite Frame(const std::filesystem::path& file, int frame) {
    return {file.string(), "", frame, ""};
  }
  static ErrorSite Option(std::string field) { return {"", "", -1, std::move(field)}; }
};

// An options field named inside a message ("...; set <force> to replace it"): formatted like
// ErrorSite::option, so that app/ shows the flag that sets it.
struct OptionRef {
  std::string field;
};

// A message: text with option references in it, kept apart so that no one edits the text.
class ErrorMessage {
 public:
  template <typename T>
  ErrorMessage& operator<<(const T& v) {
    text_ << v;
    return *this;
  }
  ErrorMessage& operator<<(const OptionRef& ref) {
    Flush();
    parts_.push_back({true, ref.field});
    return *this;
  }
  // {is_option_ref, text or field}, in order.
  std::vector<std::pair<bool, std::string>> Parts() {
    Flush();
    return std::move(parts_);
  }

 private:
  void Flush() {
    if (!text_.str().empty()) parts_.push_back({false, text_.str()});
    text_.str("");
  }
  std::ostringstream text_;
  std::vector<std::pair<bool, std::string>> parts_;
};

// How a formatter names an options field (app/ gives the flag; the library keeps the field).
using OptionNamer = std::function<std::string(const std::string& field)>;

class Error : public std::runtime_error {
 public:
  // A message without a location (or with it still in the text: older call sites).
  explicit Error(std::string message, ErrorKind kind = ErrorKind::kBadInput)
      : Error(kind, {}, {{false, std::move(message)}}) {}
  Error(ErrorKind kind, ErrorSite site, std::vector<std::pair<bool, std::string>> detail)
      : std::runtime_error(Format(site, detail, {})),
        kind_(kind),
        site_(std::move(site)),
        detail_(std::move(detail)) {}

  ErrorKind kind() const { return kind_; }
  int exit_code() const { return static_cast<int>(kind_); }
  const ErrorSite& site() const { return site_; }
  const std::string& file() const { return site_.file; }
  const std::string& key() const { return site_.key; }
  int frame() const { return site_.frame; }
  const std::string& option() const { return site_.option; }

  // The one line: "<option>: <file>: <key>: frame <n>: <detail>", the parts that are set, with
  // every options field named by `name_option` (what() names them by their field).
  std::string Format(const OptionNamer& name_option) const {
    return Format(site_, detail_, name_option);
  }
  // The message without its location, options named by their field.
  std::string Detail() const { return Format({}, detail_, {}); }
  // The same error (kind and message) at `site`: for a caller that knows where an error that
  // carries no location comes from.
  Error At(ErrorSite site) const { return Error(kind_, std::move(site), detail_); }
  // The same error with the path `from` named `to` wherever it appears (the file and the text):
  // for a writer that fills a staging folder and renames it to its final name.
  Error WithPathRenamed(const std::string& from, const std::string& to) const {
    auto rename = [&](std::string text) {
      for (size_t at = text.find(from); !from.empty() && at != std::string::npos;
           at = text.find(from, at + to.size()))
        text.replace(at, from.size(), to);
      return text;
    };
    ErrorSite site = site_;
    site.file = rename(site.file);
    std::vector<std::pair<bool, std::string>> detail = detail_;
    for (auto& [is_option, text] : detail)
      if (!is_option) text = rename(text);
    return Error(kind_, std::move(site), std::move(detail));
  }

 private:
  static std::string Format(const ErrorSite& site,
                            const std::vector<std::pair<bool, std::string>>& detail,
                            const OptionNamer& name_option) {
    auto name = [&](const std::string& field) { return name_option ? name_option(field) : field; };
    std::string line;
    auto add = [&line](const std::string& part) {
      if (part.empty()) return;
      line += part;
      line += ": ";
    };
    if (!site.option.empty()) add(name(site.option));
    add(site.file);
    add(site.key);
    if (site.frame >= 0) add("frame " + std::to_string(site.frame));
    for (const auto& [is_option, text] : detail) line += is_option ? name(text) : text;
    if (detail.empty() && line.size() >= 2) line.resize(line.size() - 2);
    return line;
  }

  ErrorKind kind_;
  ErrorSite site_;
  std::vector<std::pair<bool, std::string>> detail_;
};

// Builds a message with operator<< and throws it:
//   MESOSCAN_THROW(kind, "file: " << x << ...)                      (location in the text)
//   MESOSCAN_THROW_AT(kind, ErrorSite::Key(path, "rig"), "expected ...")  (location as data)
//   MESOSCAN_BAD_OPTION("TileOptions.size_m", "expected > 0, got " << v)  (kUsage)
#define MESOSCAN_THROW_AT(kind, site, stream_expr)                  \
  do {                                                              \
    ::mesoscan::ErrorMessage mesoscan_msg_;                         \
    mesoscan_msg_ << stream_expr;                                   \
    throw ::mesoscan::Error((kind), (site), mesoscan_msg_.Parts()); \
  } while (0)

#define MESOSCAN_THROW(kind, stream_expr) \
  MESOSCAN_THROW_AT(kind, ::mesoscan::ErrorSite{}, stream_expr)

#define MESOSCAN_BAD_INPUT(stream_expr) \
  MESOSCAN_THROW(::mesoscan::ErrorKind::kBadInput, stream_expr)

#define MESOSCAN_BAD_INPUT_AT(site, stream_expr) \
  MESOSCAN_THROW_AT(::mesoscan::ErrorKind::kBadInput, site, stream_expr)

#define MESOSCAN_BAD_OPTION(field, stream_expr)                                          \
  MESOSCAN_THROW_AT(::mesoscan::ErrorKind::kUsage, ::mesoscan::ErrorSite::Option(field), \
                    stream_expr)

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
