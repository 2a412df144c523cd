// The library speaks its own language (issue 51): below the front ends (host/cli/, python/) a
// message names an option by its field, marked with opt() (base/error.hpp), never by a CLI flag, and
// nothing writes to a console stream (messages go through the log sink, base/log.hpp); one clock
// times everything (base/stopwatch.hpp). The first three tests read the sources.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"

namespace {

namespace fs = std::filesystem;
using namespace vkunroll;

// The source without its comments (string and character literals kept as they are).
std::string without_comments(const std::string& src) {
  std::string out;
  for (size_t i = 0; i < src.size(); ++i) {
    const char c = src[i];
    if (c == '"' || c == '\'') {  // a literal, escapes included
      const size_t start = i++;
      while (i < src.size() && src[i] != c && src[i] != '\n') i += src[i] == '\\' ? 2 : 1;
      out.append(src, start, i - start + 1);
    } else if (c == '/' && i + 1 < src.size() && src[i + 1] == '/') {
      while (i < src.size() && src[i] != '\n') ++i;
      out += '\n';
    } else if (c == '/' && i + 1 < src.size() && src[i + 1] == '*') {
      i = src.find("*/", i + 2);
      if (i == std::string::npos) break;
      ++i;
    } else {
      out += c;
    }
  }
  return out;
}

struct Source {
  std::string path;  // relative to the source tree
  std::string code;  // without comments
};

// Every C++ source of `folders` (host/cli/ left out unless `with_cli`).
std::vector<Source> sources(std::initializer_list<const char*> folders, bool with_cli) {
  const fs::path root = VKUNROLL_SOURCE_DIR;
  std::vector<Source> out;
  for (const char* folder : folders)
    for (const auto& e : fs::recursive_directory_iterator(root / folder)) {
      const fs::path rel = e.path().lexically_relative(root);
      const std::string ext = e.path().extension().string();
      if (!e.is_regular_file() || (ext != ".cpp" && ext != ".hpp") || (!with_cli && rel.string().rfind("host/cli/", 0) == 0))
        continue;
      std::ifstream in(e.path());
      std::stringstream ss;
      ss << in.rdbuf();
      out.push_back({rel.string(), without_comments(ss.str())});
    }
  return out;
}

// The library's layers: base/, runtime/, kernels/, host/ but host/cli/.
std::vector<Source> library_sources() { return sources({"base", "runtime", "kernels", "host"}, false); }

// Each match of `pattern` in `from`, as "file: match".
std::vector<std::string> findings(const std::regex& pattern, const std::vector<std::string>& allowed_files = {},
                                  const std::vector<Source>& from = library_sources()) {
  std::vector<std::string> found;
  for (const Source& s : from) {
    if (std::find(allowed_files.begin(), allowed_files.end(), s.path) != allowed_files.end()) continue;
    for (auto it = std::sregex_iterator(s.code.begin(), s.code.end(), pattern); it != std::sregex_iterator(); ++it)
      found.push_back(s.path + ": " + it->str());
  }
  return found;
}

TEST(LibraryLanguage, NoCliFlagLiteralBelowTheFrontEnds) {
  ASSERT_GT(library_sources().size(), 100u);  // the tree was found
  // A string literal holding "--" and a letter: a flag, which only a front end may spell.
  const std::regex flag(R"("(?:[^"\\\n]|\\.)*--[A-Za-z](?:[^"\\\n]|\\.)*")");
  // The output table is the one place that declares each output's spelling in every front end.
  for (const std::string& f : findings(flag, {"host/unroll/output_paths.cpp"})) ADD_FAILURE() << f << "  (name the option with opt(\"field\"))";
}

TEST(LibraryLanguage, NoConsoleOutputBelowTheFrontEnds) {
  // Writes to stderr / stdout; formatting into buffers (snprintf) and writing files (fprintf(f, ...)) are fine.
  const std::regex console(
      R"(std::(cerr|cout|clog)\b|\bprintf\s*\(|\bputs\s*\(|\bf(printf|puts|write)\s*\([^;]*\b(stderr|stdout)\b)");
  // base/log.cpp holds the default sink: warnings to stderr until a program installs its own.
  for (const std::string& f : findings(console, {"base/log.cpp"})) ADD_FAILURE() << f << "  (log it: base/log.hpp)";
}

TEST(LibraryLanguage, OneClockEverywhere) {
  // Wall time is base/stopwatch.hpp's (Stopwatch, Clock), in every folder.
  const std::vector<Source> all = sources({"base", "runtime", "kernels", "host", "python", "tests", "bench", "fuzz", "examples"}, true);
  // base/stopwatch.hpp names the clock.
  const std::vector<std::string> allowed = {"base/stopwatch.hpp"};
  // (The pattern in two pieces, so that this file does not match itself.)
  for (const std::string& f : findings(std::regex(std::string("std::chrono::steady_") + "clock"), allowed, all))
    ADD_FAILURE() << f << "  (use base/stopwatch.hpp)";
}

TEST(LibraryLanguage, NoDowncastToAConcreteBackend) {
  // What the session and the front ends need of a backend is in the Backend interface; make_backend
  // (host/model/make_backend.hpp) makes every one of them.
  const std::vector<Source> all = sources({"host", "python", "bench", "examples"}, true);
  for (const std::string& f : findings(std::regex(R"(dynamic_cast<[^>]*(Vulkan|Cpu|Planning)Backend)"), {}, all))
    ADD_FAILURE() << f;
}

TEST(LibraryLanguage, AnOptionIsSpelledByEachFrontEnd) {
  const OptionError e("times_us", "1e400", "times must lie within +-2^53 us");
  EXPECT_EQ(e.field(), "times_us");
  EXPECT_EQ(e.value(), "1e400");
  EXPECT_EQ(e.kind(), ErrorKind::usage);
  EXPECT_STREQ(e.what(), "times_us 1e400: times must lie within +-2^53 us");  // the library's own name
  auto flag = [](std::string_view f) {
    std::string s = "--" + std::string(f);
    std::replace(s.begin(), s.end(), '_', '-');
    return s;
  };
  EXPECT_EQ(e.spelled(flag), "--times-us 1e400: times must lie within +-2^53 us");
  // An error that wraps another keeps its marks when it wraps text(), and any error may name options.
  const Error outer("unroll: " + e.text() + "; see " + opt("times"));
  EXPECT_EQ(outer.spelled(flag), "unroll: --times-us 1e400: times must lie within +-2^53 us; see --times");
  EXPECT_STREQ(outer.what(), "unroll: times_us 1e400: times must lie within +-2^53 us; see times");
  // A value holding braces or dashes is text, not a mark.
  EXPECT_EQ(OptionError("out", "/tmp/{a}--b", "exists").spelled(flag), "--out /tmp/{a}--b: exists");
}

TEST(LibraryLanguage, MessagesGoToTheInstalledSinkWithTheirLevel) {
  std::vector<std::pair<LogLevel, std::string>> got;
  const LogSink previous = set_log_sink([&](LogLevel l, std::string_view m) { got.emplace_back(l, std::string(m)); });
  log_info("unroll: event gate radius 2 (" + opt("gate_radius") + ")");
  log_warning("unroll: warning: c is a default");
  set_log_sink(previous);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0].first, LogLevel::info);
  EXPECT_EQ(spell_fields(got[0].second, [](std::string_view f) { return "<" + std::string(f) + ">"; }),
            "unroll: event gate radius 2 (<gate_radius>)");
  EXPECT_EQ(got[1].first, LogLevel::warning);
  EXPECT_STREQ(log_level_name(got[1].first), "warning");
}

}  // namespace
