#include "app/error_line.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>

namespace mesoscan {
namespace {

namespace fs = std::filesystem;

TEST(ErrorLine, NamesOptionsByTheirFlagAndKeepsTheLocationOrder) {
  try {
    MESOSCAN_THROW_AT(ErrorKind::kUsage, ErrorSite::Option("TileOptions.size_m"),
                      "0 mm: expected a size > 0; see " << OptionRef{"MapsOptions.crop"});
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              "TileOptions.size_m: 0 mm: expected a size > 0; see "
              "MapsOptions.crop");
    EXPECT_EQ(FormatErrorLine(e, "maps"), "--tile: 0 mm: expected a size > 0; see --crop");
    EXPECT_EQ(e.exit_code(), 2);
  }
  ErrorSite site = ErrorSite::Key("s/session.json", "rig.camera.K");
  site.frame = 3;
  const Error e(ErrorKind::kBadInput, site, {{false, "singular"}});
  EXPECT_EQ(FormatErrorLine(e, "check"), "s/session.json: rig.camera.K: frame 3: singular");
  EXPECT_EQ(e.At(ErrorSite::File("x.png")).Format({}), "x.png: singular");
  EXPECT_EQ(e.At(ErrorSite::File("x.png")).kind(), ErrorKind::kBadInput);
}

TEST(ErrorLine, AFieldSetByAnotherFlagInOneCommand) {
  EXPECT_EQ(FlagForOption("export", "ExportOptions.formats"), "--format");
  EXPECT_EQ(FlagForOption("reconstruct", "ExportOptions.formats"), "--export");
  EXPECT_EQ(FlagForOption("render", "RenderOptions.unknown_field"), "RenderOptions.unknown_field");
}

// Every source file of the library modules (not app/, tests/, bench/, fuzz/).
std::vector<fs::path> LibrarySources() {
  std::vector<fs::path> files;
  for (const char* module : {"core", "session", "capture", "heightfield", "calibration", "maps",
                             "brdf", "render", "assets", "sim", "compare"})
    for (const auto& entry : fs::directory_iterator(fs::path(MESOSCAN_SOURCE_DIR) / module)) {
      const std::string ext = entry.path().extension().string();
      if (ext == ".cc" || ext == ".h") files.push_back(entry.path());
    }
  return files;
}

// The file's code: its lines without the whole-line comments (which may quote examples).
std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  std::string code, line;
  while (std::getline(in, line)) {
    const size_t first = line.find_first_not_of(" \t");
    if (first != std::string::npos && line.compare(first, 2, "//") == 0) continue;
    code += line;
    code += '\n';
  }
  return code;
}

// The library speaks data: no string literal of a library module starts with a flag's "--"
// (the options are named by their field; app/ maps fields to flags).
TEST(ErrorLine, NoLibraryStringNamesACommandLineFlag) {
  const std::regex flag_literal(R"re("--[a-z])re");
  int files = 0;
  for (const fs::path& file : LibrarySources()) {
    ++files;
    const std::string text = ReadText(file);
    std::smatch m;
    EXPECT_FALSE(std::regex_search(text, m, flag_literal))
        << file.string() << ": " << text.substr(m.position(0), 40);
  }
  EXPECT_GT(files, 50);
}

// Every options field that the library or app/ names in an error has a flag in the table.
TEST(ErrorLine, EveryNamedOptionsFieldHasAFlag) {
  std::vector<fs::path> files = LibrarySources();
  for (const auto& entry : fs::directory_iterator(fs::path(MESOSCAN_SOURCE_DIR) / "app"))
    if (entry.path().extension() == ".cc" && entry.path().filename() != "error_line.cc" &&
        entry.path().filename() != "error_line_test.cc")
      files.push_back(entry.path());
  const std::regex field(R"re("([A-Z][A-Za-z]*(?:Options|Spec)\.[a-z_]+)")re");
  const std::regex sim_field(R"re(SIM_OPTION\("([a-z_]+)")re");
  std::set<std::string> fields;
  for (const fs::path& file : files) {
    const std::string text = ReadText(file);
    for (auto it = std::sregex_iterator(text.begin(), text.end(), field);
         it != std::sregex_iterator(); ++it)
      fields.insert((*it)[1]);
    for (auto it = std::sregex_iterator(text.begin(), text.end(), sim_field);
         it != std::sregex_iterator(); ++it)
      fields.insert("SimulateOptions." + (*it)[1].str());
  }
  EXPECT_GT(fields.size(), 40u);
  for (const std::string& f : fields) {
    const std::string flag = FlagForOption("", f);
    EXPECT_EQ(flag.rfind("--", 0), 0u) << f << " has no flag in app/error_line.cc";
  }
}

}  // namespace
}  // namespace mesoscan
