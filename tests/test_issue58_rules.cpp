// Issue 58's library rules (the front ends' cases: tests/python/test_issue58_args.py): one JSON
// reader that refuses a repeated key, one grammar for exact times, one end rule for images, one
// table of reading options per format, one table of the Vulkan backend's options, special files
// refused before detection opens them, the lists' each-once rule and the crop rule in the library,
// and a failed write that gives the system's reason.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <functional>
#include <iterator>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cli_test_util.hpp"
#include "event_test_util.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/base/json_read.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/events/meta_schema.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/unroll/backend_options.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/kernels/event_tensor.hpp"

using namespace vkunroll;
using evtest::error_of;  // event_test_util.hpp's: the message an Error carries
namespace fs = std::filesystem;

namespace {

bool has(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace

TEST(Issue58, ARepeatedJsonKeyIsRefusedNamingTheKeyAndTheDocument) {
  EXPECT_EQ(parse_json<nlohmann::json>(std::string(R"({"a": 1, "b": {"a": 2}, "c": [{"a": 3}, {"a": 4}]})"), "doc.json")["b"]["a"], 2);
  std::string e = error_of([] { parse_json<nlohmann::json>(std::string(R"({"a": 1, "b": 2, "a": 3})"), "doc.json"); });
  EXPECT_TRUE(has(e, "doc.json") && has(e, "\"a\"") && has(e, "twice") && has(e, "top-level")) << e;
  e = error_of([] { parse_json<nlohmann::json>(std::string(R"({"frames": [{"file": "x", "file": "y"}]})"), "m.json"); });
  EXPECT_TRUE(has(e, "\"file\"") && has(e, "the object frames")) << e;
  e = error_of([] { parse_json<nlohmann::json>(std::string("{not json"), "m.json"); });
  EXPECT_TRUE(has(e, "m.json: not valid JSON")) << e;
  // A safetensors header naming one tensor twice.
  const std::string header = R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}, "w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}})";
  std::vector<uint8_t> bytes(8 + header.size() + 4, 0);
  for (int i = 0; i < 8; ++i) bytes[i] = uint8_t(uint64_t(header.size()) >> (8 * i));
  std::copy(header.begin(), header.end(), bytes.begin() + 8);
  e = error_of([&] { parse_safetensors(bytes, "m.safetensors"); });
  EXPECT_TRUE(has(e, "m.safetensors") && has(e, "\"w\" appears twice")) << e;
}

TEST(Issue58, AnExactTimeIsASingleFraction) {
  for (const char* bad : {"60000/1/1", "1/2/3", "1//2", "/2", "2/"}) {
    const std::string e = error_of([&] { Rational::parse(bad, "t"); });
    EXPECT_FALSE(e.empty()) << bad;
  }
  EXPECT_TRUE(has(error_of([] { Rational::parse("60000/1/1", "t"); }), "a single a/b"));
  EXPECT_EQ(Rational::parse("60000/7", "t"), Rational(60000, 7));
  EXPECT_EQ(Rational::parse("1.5/3", "t"), Rational(1, 2));
}

TEST(Issue58, AnImageCutShortFailsTheEndRule) {
  const fs::path d = clitest::temp_dir("issue58", "images");
  cv::Mat m(48, 64, CV_8UC3);
  cv::randu(m, 0, 255);
  for (const char* ext : {".jpg", ".png"}) {
    const fs::path whole = d / (std::string("whole") + ext), cut = d / (std::string("cut") + ext);
    ASSERT_TRUE(cv::imwrite(whole.string(), m));
    EXPECT_EQ(image_end_problem(whole.string()), "") << ext;
    std::ifstream in(whole, std::ios::binary);
    const std::string data((std::istreambuf_iterator<char>(in)), {});
    std::ofstream(cut, std::ios::binary) << data.substr(0, data.size() / 2);
    EXPECT_TRUE(has(image_end_problem(cut.string()), "truncated")) << ext;
    const std::string e = error_of([&] { read_frame_image(cut.string(), 64, 48); });
    EXPECT_TRUE(has(e, cut.string()) && has(e, "truncated")) << e;
    EXPECT_EQ(read_frame_image(whole.string(), 64, 48).cols, 64);
  }
}

TEST(Issue58, ReadingOptionsApplyToTheirFormatsOnly) {
  const std::string h5 = evtest::tmp("issue58.h5"), txt = evtest::tmp("issue58.txt");
  EventStream ev;
  ev.width = 16, ev.height = 12;
  ev.push(5, 1, 1, 1);
  write_events_hdf5(h5, ev);
  std::ofstream(txt) << "5 1 1 1\n";
  EventReadOptions o;
  o.text_time_unit = "ms";
  evtest::expect_error(h5, o, {"time_unit", "'ms'", "issue58.h5", "text and CSV files only"});
  o = {};
  o.text_columns = "xytp";
  evtest::expect_error(h5, o, {"columns", "issue58.h5"});
  o.text_columns = "txyp";  // the default order: not an option given
  EXPECT_EQ(read_events(h5, o).size(), 1u);
  o = {};
  o.array_time_unit = "ms";
  o.width = 16, o.height = 12;
  evtest::expect_error(txt, o, {"array_time_unit", "issue58.txt"});
  o = {};
  o.text_time_unit = "us", o.text_columns = "txyp", o.width = 16, o.height = 12;
  EXPECT_EQ(read_events(txt, o).size(), 1u);
  o = {};
  o.array_time_unit = "us";
  EXPECT_EQ(read_events(h5, o).size(), 1u);
}

TEST(Issue58, SpecialFilesAreRefusedBeforeDetectionOpensThem) {
  const fs::path fifo = clitest::temp_dir("issue58", "fifo") / "ff";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const Stopwatch clock;
  const std::string e = error_of([&] { detect_event_format(fifo.string()); });  // opening it would block for ever
  EXPECT_TRUE(has(e, "a FIFO") && has(e, fifo.string())) << e;
  EXPECT_LT(clock.seconds(), 10.0);
  EXPECT_TRUE(has(error_of([] { detect_event_format("/dev/null"); }), "a character device"));
}

TEST(Issue58, VulkanOnlyOptionsAreRefusedOnTheCpuBackend) {
  SessionOptions s;
  s.backend = BackendKind::cpu;
  EXPECT_NO_THROW(check_session_options_apply(s));
  const std::vector<std::pair<std::function<void(SessionOptions&)>, const char*>> cases = {
      {[](SessionOptions& o) { o.precision = Precision::fp16; }, "precision"},
      {[](SessionOptions& o) { o.device = "0"; }, "device"},
      {[](SessionOptions& o) { o.conv_choice = ConvChoice::gpu; }, "conv_choice"},
      {[](SessionOptions& o) { o.profile_ops = true; }, "profile"},
      {[](SessionOptions& o) { o.trace = true; }, "trace"}};
  for (const auto& [set, field] : cases) {
    SessionOptions o = s;
    set(o);
    try {
      check_session_options_apply(o);
      ADD_FAILURE() << field << " was accepted with the cpu backend";
    } catch (const OptionError& e) {
      EXPECT_EQ(e.field(), field);
      EXPECT_TRUE(has(e.what(), "backend")) << e.what();
    }
    o.backend = BackendKind::vulkan;
    EXPECT_NO_THROW(check_session_options_apply(o)) << field;
  }
}

TEST(Issue58, ListsAndCropsFollowTheLibrarysRuleWhoeverBuiltThem) {
  UnrollOptions o;
  o.sequence = "seq", o.out_dir = "out";
  o.times = {TargetTimes::Kind::normalized, {Rational(1, 2), Rational(1, 2)}};
  std::string e = error_of([&] { validate_unroll_options(o); });
  EXPECT_TRUE(has(e, "times") && has(e, "listed twice")) << e;
  o.times = {TargetTimes::Kind::absolute_us, {Rational(10), Rational(20), Rational(10)}};
  EXPECT_TRUE(has(error_of([&] { validate_unroll_options(o); }), "listed twice"));
  o.times = {TargetTimes::Kind::normalized, {Rational(1, 2)}};
  o.frames = {0, 2, 0};
  EXPECT_TRUE(has(error_of([&] { validate_unroll_options(o); }), "frame 0 is listed twice"));
  EXPECT_TRUE(has(error_of([] { parse_value_list("0.5,1/2", "times"); }), "listed twice in '0.5,1/2'"));
  for (const std::vector<long long>& bad : std::vector<std::vector<long long>>{{0, 0, 0, 0}, {0, 0, 4, 0}, {-1, 0, 4, 4}, {0, 0, 4}})
    EXPECT_THROW(user_crop(bad, "crop"), OptionError);
  const SensorCrop c = user_crop({1, 2, 3, 4}, "crop");
  EXPECT_EQ(c.x0 + c.y0 + c.width + c.height, 10);
}

TEST(Issue58, AFailedWriteGivesTheSystemsReason) {
  EventStream ev;
  ev.width = 16, ev.height = 12;
  for (int i = 0; i < 200000; ++i) ev.push(i, uint16_t(i % 16), uint16_t(i % 12), 1);
  std::string e = error_of([&] { write_events_text("/dev/full", ev); });
  EXPECT_TRUE(has(e, "/dev/full") && has(e, "No space left on device")) << e;
  e = error_of([&] { write_events_hdf5("/nonexistent-folder-issue58/e.h5", ev); });
  EXPECT_TRUE(has(e, "e.h5") && has(e, "No such file or directory")) << e;
  EXPECT_FALSE(has(e, "?")) << e;
}
