// Issue 52's offline rules (the table in docs/reliability.md, "Issue 52: the rules and the cases they
// cover"): time order over the whole stream, one grammar for exact times, hard links are the same
// image, a topic only for bags, the file's sensor size against the sequence's said, and the output
// rule for single files.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "../fuzz/fuzz_follow.hpp"
#include "cli_test_util.hpp"
#include "event_test_util.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/unroll/output_file.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

// A generic 16x12 sequence of 3 frames 1000 us apart whose events.txt is `events`.
fs::path sequence_with(const std::string& name, const std::string& events, nlohmann::json meta = {}) {
  const fs::path d = clitest::temp_dir("issue52", name);
  fs::create_directories(d / "rs");
  for (int k = 0; k < 3; ++k) {
    cv::Mat m(12, 16, CV_8UC3, cv::Scalar(10 + 60 * k, 20, 30));
    cv::imwrite((d / "rs" / (std::to_string(k) + ".png")).string(), m);
  }
  std::ofstream(d / "events.txt") << events;
  if (meta.is_null())
    meta = nlohmann::json::parse(R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 500, "events": "events.txt",
      "frames": [{"file": "rs/0.png", "t0_us": 0}, {"file": "rs/1.png", "t0_us": 1000}, {"file": "rs/2.png", "t0_us": 2000}]})");
  std::ofstream(d / "meta.json") << meta.dump(1);
  return d;
}

// Events in two halves: the later half first (a file whose halves were swapped).
std::string swapped_halves() {
  std::string late, early;
  for (int i = 0; i < 40; ++i) late += std::to_string(2000 + 20 * i) + " " + std::to_string(i % 16) + " " + std::to_string(i % 12) + " 1\n";
  for (int i = 0; i < 40; ++i) early += std::to_string(10 + 20 * i) + " " + std::to_string(i % 16) + " " + std::to_string(i % 12) + " 0\n";
  return late + early;
}

}  // namespace

// The windows of frames 0-1 stop before the backward jump; the rest of the file is read after the
// last window, so unroll refuses the file (--on-bad error) or counts the drops (--on-bad drop).
TEST(EventRules, TimeOrderIsCheckedOverTheWholeStream) {
  const fs::path d = sequence_with("swapped", swapped_halves());
  const Sequence seq = load_sequence(d.string());
  EXPECT_EQ(seq.read_events(0, 1500).size(), 0u);  // the window read stops at the first later event
  try {
    seq.read_events_to_end();
    ADD_FAILURE() << "the backward jump was not found";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("events.txt"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("record 40"), std::string::npos) << e.what();
  }
  const std::string out = d.string() + "-out";
  fs::remove_all(out);
  auto r = clitest::cli("unroll " + d.string() + " --mode physics --contrast 0.2 --no-video --quiet --frames 0:1 --out " + out);
  EXPECT_EQ(r.rc, 65) << r.out;
  EXPECT_TRUE(clitest::has(r, "record 40")) << r.out;
  EXPECT_FALSE(fs::exists(out));
  r = clitest::cli("unroll " + d.string() + " --mode physics --contrast 0.2 --no-video --quiet --frames 0:1 --on-bad drop --out " + out);
  EXPECT_EQ(r.rc, 0) << r.out;
  EXPECT_TRUE(clitest::has(r, "--on-bad drop: 40 of 80")) << r.out;
}

TEST(MetaSchema, ExactTimesHaveOneGrammar) {
  for (const char* bad : {"60 000", "6 0 0 0 0", "73000 / 259", "1e 3", "--5"})
    EXPECT_THROW(Rational::parse(bad, "t"), Error) << bad;
  EXPECT_EQ(Rational::parse(" 60000 ", "t"), Rational(60000));
  EXPECT_EQ(Rational::parse("73000/259", "t"), Rational(73000, 259));
  nlohmann::json meta = nlohmann::json::parse(R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 500,
    "events": "events.txt", "frames": [{"file": "rs/0.png", "t0_us": 0}, {"file": "rs/1.png", "t0_us": "1 000"},
    {"file": "rs/2.png", "t0_us": 2000}]})");
  const fs::path d = sequence_with("spaced", "10 1 1 1\n", meta);
  try {
    load_sequence(d.string());
    ADD_FAILURE() << "'1 000' was read as a time";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("frames[1].t0_us"), std::string::npos) << e.what();
  }
}

// distinct-frame-files compares files, not names: a hard link to another frame is the same image.
TEST(MetaSchema, AHardLinkToAnotherFrameIsTheSameImage) {
  const fs::path d = sequence_with("hardlink", "10 1 1 1\n");
  fs::remove(d / "rs" / "2.png");
  fs::create_hard_link(d / "rs" / "1.png", d / "rs" / "2.png");
  try {
    load_sequence(d.string());
    ADD_FAILURE() << "a hard-linked frame was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("distinct-frame-files"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("frames[2].file"), std::string::npos) << e.what();
  }
}

TEST(EventRules, ATopicIsRefusedForAFileThatIsNotABag) {
  const std::string h5 = evtest::tmp("topic.h5");
  EventStream ev;
  ev.width = 16, ev.height = 12;
  ev.push(5, 1, 1, 1);
  write_events_hdf5(h5, ev);
  EventReadOptions o;
  o.events_topic = "/dvs/events";
  evtest::expect_error(h5, o, {"events topic '/dvs/events'", "topic.h5", "not a ROS bag"});
  const fs::path d = sequence_with("topic", "10 1 1 1\n");
  const auto r = clitest::cli("unroll " + d.string() + " --mode physics --contrast 0.2 --events-topic /dvs/events --out " +
                              d.string() + "-out");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(clitest::has(r, "not a ROS bag")) << r.out;
}

// A file that declares another sensor size than the sequence's: the read says it, unroll warns.
TEST(EventRules, AFileSizeOtherThanTheSequencesIsSaid) {
  const fs::path d = sequence_with("size", "");
  fs::remove_all(d.string() + "-out");
  fs::remove(d / "events.txt");
  EventStream ev;
  ev.width = 8, ev.height = 6;
  ev.push(5, 1, 1, 1);
  write_events_hdf5((d / "events.h5").string(), ev);
  nlohmann::json meta = nlohmann::json::parse(std::ifstream(d / "meta.json"));
  meta["events"] = "events.h5";
  std::ofstream(d / "meta.json") << meta.dump(1);
  const auto r = clitest::cli("unroll " + d.string() + " --mode physics --contrast 0.2 --no-video --quiet --out " +
                              d.string() + "-out");
  EXPECT_EQ(r.rc, 0) << r.out;
  EXPECT_TRUE(clitest::has(r, "sensor size 8x6")) << r.out;
  EXPECT_TRUE(clitest::has(r, "differs from the size given")) << r.out;
}

// A single output file: refused when it exists unless asked, and then only when vkunroll wrote it.
TEST(OutputRule, AFileIsReplacedOnlyWhenAskedAndOnlyWhenVkunrollWroteIt) {
  const std::string mine = evtest::tmp("notes.txt"), ours = evtest::tmp("ours.h5"), text = evtest::tmp("ours.txt");
  evtest::write_file(mine, "the user's notes\n");
  EventStream ev;
  ev.width = 4, ev.height = 4;
  ev.push(1, 1, 1, 1);
  write_events_hdf5(ours, ev);
  write_events_text(text, ev);
  EXPECT_TRUE(written_by_vkunroll(ours));
  EXPECT_TRUE(written_by_vkunroll(text));
  EXPECT_FALSE(written_by_vkunroll(mine));
  // Refusals are OptionErrors naming the field (the CLI spells it --out, Python its keyword).
  EXPECT_THROW(check_output_file_rule(mine, output_path("voxelize.out"), ExistingOutput::refuse), OptionError);
  EXPECT_THROW(check_output_file_rule(mine, output_path("voxelize.out"), ExistingOutput::overwrite), OptionError);
  EXPECT_THROW(check_output_file_rule(ours, output_path("voxelize.out"), ExistingOutput::refuse), OptionError);
  EXPECT_NO_THROW(check_output_file_rule(ours, output_path("voxelize.out"), ExistingOutput::overwrite));
  EXPECT_THROW(check_output_file_rule(ours, output_path("voxelize.out"), ExistingOutput::overwrite, {{"inputs", ours}}), OptionError);
  try {
    check_output_file_rule(mine, output_path("voxelize.out"), ExistingOutput::refuse);
  } catch (const OptionError& e) {
    EXPECT_EQ(e.field(), "out");
    EXPECT_EQ(e.kind(), ErrorKind::usage);
    EXPECT_NE(e.text().find(opt("overwrite")), std::string::npos) << e.text();
  }
  const auto r = clitest::cli("voxelize " + sequence_with("vox", "10 1 1 1\n").string() + " --frames 0 --times-us 5000000 --out " +
                              evtest::tmp("far.safetensors") + " --cpu");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(clitest::has(r, "outside the recording")) << r.out;
}

// The live decoder's differential check (fuzz/fuzz_follow.hpp: online, chunk by chunk, against the
// offline reader) over its own corpus and the EVT readers' corpora: the same events and drops, or
// both refuse.
TEST(EventRules, TheLiveDecoderMatchesTheOfflineReaderOnTheCorpus) {
  const fs::path root = fs::path(VKUNROLL_SOURCE_DIR) / "tests" / "fuzz_corpus";
  size_t files = 0;
  for (const char* dir : {"follow", "evt3", "evt2", "evt21"}) {
    for (const auto& entry : fs::directory_iterator(root / dir)) {
      const std::vector<uint8_t> bytes = evtest::read_bytes(entry.path().string());
      ++files;
      EXPECT_TRUE(fuzz::follow_matches_offline(bytes.data(), bytes.size())) << entry.path();
    }
  }
  EXPECT_GE(files, 30u);
}
