// The event-format table (host/events/event_formats.hpp) against every list that reads it or must
// agree with it: detection, the reader files, the fuzz harnesses and corpus, the index fuzzer's
// formats and the CLI's help. (Python's names and docs/events.md's table: tests/python/test_event_formats.py.)
#include <gtest/gtest.h>

#include <filesystem>
#include <set>

#include "cli_test_util.hpp"
#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "rosbag_test_encoder.hpp"
#include "../fuzz/fuzz_index.hpp"
#include "vkunroll/host/events/event_formats.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

std::vector<std::string_view> extensions_of(const EventFormat& f) {
  std::vector<std::string_view> out;
  for (std::string_view e : f.extensions)
    if (!e.empty()) out.push_back(e);
  return out;
}

}  // namespace

TEST(EventFormats, EachRowIsWhole) {
  std::set<std::string_view> names;
  const fs::path root = VKUNROLL_SOURCE_DIR;
  for (const EventFormat& f : event_formats()) {
    SCOPED_TRACE(std::string(f.name));
    EXPECT_TRUE(names.insert(f.name).second) << "a name twice";
    EXPECT_EQ(find_event_format(f.name), &f);
    if (!f.alias.empty()) {
      EXPECT_TRUE(names.insert(f.alias).second) << "an alias taken";
      EXPECT_EQ(find_event_format(f.alias), &f);
    }
    EXPECT_FALSE(f.what.empty());
    EXPECT_FALSE(extensions_of(f).empty());
    for (std::string_view e : extensions_of(f)) EXPECT_EQ(e[0], '.') << e;
    EXPECT_NE(f.read_bytes == nullptr, f.read_image == nullptr) << "exactly one reader";
    EXPECT_TRUE(fs::exists(root / "host/events" / f.reader)) << f.reader;
    // A signature that identifies the file is said in words; a shared extension needs one.
    const bool signed_ = !f.magic[0].empty() || f.percent_header;
    EXPECT_EQ(signed_, !f.signature.empty());
    if (f.signature_required) {
      EXPECT_FALSE(f.magic[0].empty());
    }
    // The fuzzers: the harness and its committed corpus.
    EXPECT_TRUE(fs::exists(root / "fuzz" / ("fuzz_" + std::string(f.fuzzer) + ".cpp"))) << f.fuzzer;
    const fs::path corpus = root / "tests/fuzz_corpus" / f.fuzzer;
    EXPECT_TRUE(fs::is_directory(corpus) && !fs::is_empty(corpus)) << corpus;
  }
  EXPECT_EQ(find_event_format("nope"), nullptr);
  EXPECT_EQ(event_format_names(", ", true), "txt, h5");
}

// The index fuzzer's byte map names exactly the streamed formats of the table.
TEST(EventFormats, IndexFuzzerCoversEveryStreamedFormat) {
  std::set<std::string> streamed, fuzzed(std::begin(fuzz::kIndexFormats), std::end(fuzz::kIndexFormats));
  for (const EventFormat& f : event_formats())
    if (f.streamed) streamed.emplace(f.name);
  EXPECT_EQ(streamed, fuzzed);
  // Every format is reachable from some first byte, under each policy.
  std::set<std::pair<int, int>> cases;
  for (int k = 0; k < 128; ++k) cases.insert(fuzz::index_case(k));
  EXPECT_EQ(cases.size(), size_t(3 * fuzz::kIndexFormatCount));
}

// The bag rows of the index fuzzer (first byte 24 + policy), on a multi-chunk bag with late records.
TEST(EventFormats, IndexMatchesTheFullScanOnABag) {
  EventStream many = random_stream(9000, 64, 48, 4, 1000, 5);
  for (size_t i = 0; i < many.size(); i += 37) many.t[i] -= 3;
  BagOptions bo;
  bo.events_per_message = 50, bo.compression = "lz4";
  const std::vector<uint8_t> bag = encode_rosbag(many, bo);
  for (int policy = 0; policy < 3; ++policy) {
    std::vector<uint8_t> b{uint8_t(24 + policy)};
    b.insert(b.end(), bag.begin(), bag.end());
    b.push_back(uint8_t(17 * policy + 5));
    EXPECT_EQ(fuzz::index_case(b[0]), std::make_pair(8, policy));
    EXPECT_TRUE(fuzz::index_matches_full_scan(b.data(), b.size())) << "policy " << policy;
  }
}

// Detection follows the rows: a signature wins over any extension; an extension tells a format
// without one, but not one whose extension is shared (a signature is required there).
TEST(EventFormats, DetectionFollowsTheTable) {
  for (const EventFormat& f : event_formats()) {
    SCOPED_TRACE(std::string(f.name));
    if (!f.magic[0].empty()) {
      const std::string path = tmp("signed_" + std::string(f.name) + ".bin");
      write_bytes(path, text_bytes(std::string(f.magic[0]) + std::string(64, ' ')));
      EXPECT_EQ(detect_event_format(path), f.name);
    }
    if (!f.evt.empty()) {
      const std::string path = tmp("header_" + std::string(f.name) + ".bin");
      write_bytes(path, text_bytes("% evt " + std::string(f.evt) + "\n% end\n"));
      EXPECT_EQ(detect_event_format(path), f.name);
    }
    for (std::string_view ext : extensions_of(f)) {
      const std::string path = tmp("plain_" + std::string(f.name) + std::string(ext));
      write_bytes(path, text_bytes("0 1 2 1\n"));
      if (f.signature_required) {
        try {
          detect_event_format(path);
          ADD_FAILURE() << ext << ": expected a refusal";
        } catch (const DataError& e) {
          EXPECT_NE(std::string(e.what()).find(f.signature), std::string::npos) << e.what();
        }
      } else if (f.evt.empty()) {
        EXPECT_EQ(detect_event_format(path), f.name) << ext;
      }
    }
  }
  const std::string unknown = tmp("unknown.xyz");
  write_bytes(unknown, text_bytes("hello"));
  try {
    detect_event_format(unknown);
    ADD_FAILURE();
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find(event_format_names()), std::string::npos) << e.what();
  }
}

// An unknown --format is a usage error naming the option and the table's names.
TEST(EventFormats, UnknownFormatIsAUsageError) {
  const std::string path = tmp("fmt.txt");
  write_bytes(path, text_bytes("0 1 2 1\n"));
  EventReadOptions o;
  o.format = "evt9";
  try {
    read_events(path, o);
    ADD_FAILURE();
  } catch (const OptionError& e) {
    EXPECT_EQ(e.kind(), ErrorKind::usage);
    EXPECT_EQ(e.field(), "format");
    EXPECT_NE(std::string(e.what()).find(event_format_names()), std::string::npos) << e.what();
  }
  o.format = "csv";  // an alias reads as its format
  EventReadReport rep;
  EXPECT_EQ(read_events(path, o, &rep).size(), 1u);
  EXPECT_EQ(rep.format, "txt");
}

TEST(EventFormats, CliHelpListsEveryFormat) {
  const clitest::CliRun r = clitest::cli("events --help");
  EXPECT_EQ(r.rc, 0) << r.out;
  for (const EventFormat& f : event_formats()) {
    EXPECT_TRUE(clitest::has(r, std::string(f.what))) << f.name << "\n" << r.out;
    for (std::string_view e : extensions_of(f)) EXPECT_TRUE(clitest::has(r, std::string(e))) << e;
  }
  EXPECT_TRUE(clitest::has(r, event_format_names()));
}
