// The meta.json schema (host/events/meta_schema.cpp), one test per family: field violations,
// warnings, cross-field rules, the generated doc; and the event rules every reader shares (times
// beyond 2^53 us, HDF5 datasets never written). Issue 28, items 2 and 4.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "cli_test_util.hpp"
#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/events/meta_schema.hpp"
#include "vkunroll/host/events/sequence.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

void png(const fs::path& p, int w, int h, int channels = 3) {
  fs::create_directories(p.parent_path());
  cv::Mat m(h, w, channels == 1 ? CV_8UC1 : CV_8UC3, cv::Scalar(10, 20, 30));
  ASSERT_TRUE(cv::imwrite(p.string(), m));
}

// A valid generic sequence: 16x12, 3 colour frames 1000 us apart (readout 11 x 10 us), events.txt.
nlohmann::json base_meta() {
  return nlohmann::json::parse(R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 500,
    "events": "events.txt", "source": {"settings": {"gamma": 2.2}},
    "frames": [{"file": "rs/0.png", "t0_us": 0}, {"file": "rs/1.png", "t0_us": 1000}, {"file": "rs/2.png", "t0_us": 2000}],
    "ground_truth": [{"file": "gs/0.png", "t_us": 500}]})");
}

fs::path make_sequence(const std::string& name, const nlohmann::json& meta) {
  const fs::path d = clitest::temp_dir("meta", name);
  for (int k = 0; k < 3; ++k) png(d / "rs" / (std::to_string(k) + ".png"), 16, 12);
  png(d / "gs" / "0.png", 16, 12);
  std::ofstream(d / "events.txt") << "10 1 1 1\n1500 2 2 0\n";
  std::ofstream(d / "meta.json") << meta.dump(1);
  return d;
}

struct Outcome {
  std::string message;
  ErrorKind kind = ErrorKind::unspecified;
  bool threw = false;
};

Outcome load(const fs::path& d) {
  Outcome o;
  try {
    load_sequence(d.string());
  } catch (const Error& e) {
    o = {e.what(), e.kind(), true};
  }
  return o;
}

void expect_parts(const std::string& msg, std::initializer_list<const char*> parts) {
  for (const char* p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "missing '" << p << "' in: " << msg;
}

}  // namespace

// Every field's type and legal range, as "<meta.json>:<field> = <value>: <rule>", kind data.
TEST(MetaSchema, FieldViolationsNameFileFieldValueAndRule) {
  struct Case {
    const char* pointer;
    nlohmann::json value;
    std::vector<const char*> parts;
  };
  const std::vector<Case> cases = {
      {"/source/settings/gamma", "2.2", {"meta.json:source.settings.gamma = \"2.2\"", "expected number in [0.1, 10]"}},
      {"/source/gamma", 0.0, {"meta.json:source.gamma = 0.0", "[0.1, 10]"}},
      {"/width", 0, {"meta.json:width = 0", "expected integer in [1 px, 32767 px]"}},
      {"/height", 12.5, {"meta.json:height = 12.5", "integer"}},
      {"/line_delay_us", -1, {"meta.json:line_delay_us = -1", "[0 us, 1e+06 us]"}},
      {"/exposure_us", 0, {"meta.json:exposure_us = 0", "(0 us, 2^53 us]"}},
      {"/exposure_us", 1e300, {"meta.json:exposure_us = 1e+300"}},
      {"/readout", "diagonal", {"meta.json:readout = \"diagonal\"", "string, top-down or bottom-up"}},
      {"/frames", nlohmann::json::array(), {"meta.json:frames = []", "[1 items"}},
      {"/frames/1/t0_us", "abc", {"meta.json:frames[1].t0_us = \"abc\"", "time"}},
      {"/frames/1/t0_us", 18446744073709551615ull, {"meta.json:frames[1].t0_us = 18446744073709551615", "2^53"}},
      {"/frames/2/file", 7, {"meta.json:frames[2].file = 7", "non-empty string"}},
      {"/events", "", {"meta.json:events = \"\"", "non-empty string"}},
      {"/ground_truth/0/t_us", "1.5.0", {"meta.json:ground_truth[0].t_us = \"1.5.0\"", "time"}},
      {"/ground_truth/0", 3, {"meta.json:ground_truth[0] = 3", "object"}},
  };
  for (const auto& c : cases) {
    nlohmann::json m = base_meta();
    m[nlohmann::json::json_pointer(c.pointer)] = c.value;
    const Outcome o = load(make_sequence("field", m));
    ASSERT_TRUE(o.threw) << c.pointer;
    EXPECT_EQ(o.kind, ErrorKind::data) << o.message;  // exit 65, never a usage error
    for (const char* p : c.parts) EXPECT_NE(o.message.find(p), std::string::npos) << "missing '" << p << "' in: " << o.message;
  }
  for (const char* missing : {"/width", "/frames/0/t0_us", "/events", "/ground_truth/0/file"}) {
    nlohmann::json m = base_meta();
    const nlohmann::json::json_pointer ptr(missing);
    m[ptr.parent_pointer()].erase(ptr.back());
    const Outcome o = load(make_sequence("missing", m));
    EXPECT_EQ(o.kind, ErrorKind::data) << o.message;
    expect_parts(o.message, {"(missing): a required field"});
  }
}

// Legal but implausible values and unknown fields load, with a warning naming the field.
TEST(MetaSchema, ImplausibleValuesAndUnknownFieldsAreWarnings) {
  EXPECT_TRUE(load_sequence(make_sequence("plain", base_meta()).string()).warnings.empty());
  nlohmann::json m = base_meta();
  m["source"]["settings"]["gamma"] = 0.45;  // 1/2.2 given where 2.2 was meant
  m["exposure_us"] = 2e6;
  m["line_delay"] = 10;  // a typo of line_delay_us
  m["frames"][1]["t0"] = 5;
  const Sequence s = load_sequence(make_sequence("implausible", m).string());
  ASSERT_EQ(s.warnings.size(), 4u);
  std::string all;
  for (const auto& w : s.warnings) all += w + "\n";
  expect_parts(all, {"meta.json:source.settings.gamma = 0.45 is legal but implausible (expected 1 to 3)",
                     "meta.json:exposure_us = 2000000.0 is legal but implausible", "meta.json:line_delay is not a meta.json field",
                     "meta.json:frames[1].t0 is not a meta.json field"});
}

// What vkunroll writes itself gets no warning: the simulator's meta.json (with its ground-truth
// extensions) and the second generator's. An unknown key in every list item is one warning.
TEST(MetaSchema, TheSimulatorsOwnOutputGetsNoWarning) {
  const fs::path d = clitest::temp_dir("meta", "simulated");
  const clitest::CliRun r = clitest::cli("simulate --out " + (d / "seq").string() + " --size 32x24 --frames 3 --quiet");
  ASSERT_EQ(r.rc, 0) << r.out;
  const Sequence s = load_sequence((d / "seq").string());
  EXPECT_TRUE(s.warnings.empty()) << s.warnings.front();
  nlohmann::json m = base_meta();
  for (auto& f : m["frames"]) f["t0"] = 1;
  const Sequence typo = load_sequence(make_sequence("typo_everywhere", m).string());
  ASSERT_EQ(typo.warnings.size(), 1u);
  expect_parts(typo.warnings[0], {"meta.json:frames[0].t0 is not a meta.json field", "(in 3 frames items)"});
}

// Events on another time base (an offset clock here; ns or ms alike) fall outside every frame
// window: the run says where they are against the frames' span, with the numbers.
TEST(MetaSchema, EventsOnAnotherTimeBaseAreSaidWithTheirSpan) {
  const fs::path d = clitest::temp_dir("meta", "timebase");
  ASSERT_EQ(clitest::cli("simulate --out " + (d / "seq").string() + " --size 32x24 --frames 3 --events-format txt --quiet").rc, 0);
  std::ifstream in(d / "seq" / "events.txt");
  std::ostringstream shifted;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    long long t;
    int x, y, p;
    ASSERT_EQ(std::sscanf(line.c_str(), "%lld %d %d %d", &t, &x, &y, &p), 4) << line;
    shifted << t + 1000000000LL << " " << x << " " << y << " " << p << "\n";
  }
  in.close();
  std::ofstream(d / "seq" / "events.txt") << shifted.str();
  const clitest::CliRun r = clitest::cli("unroll " + (d / "seq").string() + " --out " + (d / "out").string() + " --mode physics --contrast 0.2 --quiet");
  EXPECT_EQ(r.rc, 0) << r.out;
  expect_parts(r.out, {"no events: the frame windows of 3 frame(s) hold no event", "outside the frames' span",
                       "check that the events are in microseconds on the frames' time base"});
  const auto summary = nlohmann::json::parse(std::ifstream(d / "out" / "summary.json"));
  EXPECT_NE(summary["warnings"].dump().find("at [10000"), std::string::npos) << summary["warnings"].dump();
  fs::remove_all(d);
}

// The rules across fields, each a named error; a missing file named by meta.json is exit 66.
TEST(MetaSchema, CrossFieldRulesAreNamedErrors) {
  nlohmann::json m = base_meta();
  m["frames"][1]["t0_us"] = 50;  // inside frame 0's readout [0, 110]
  Outcome o = load(make_sequence("overlap", m));
  EXPECT_EQ(o.kind, ErrorKind::data);
  expect_parts(o.message, {"meta.json:frames[1].t0_us = 50", "inside frame 0's readout [0, 110] us", "readout-within-frame-period"});

  m = base_meta();
  m["frames"][2]["file"] = "rs/./1.png";  // the contrast estimate fell to 0.05 on two equal frames
  o = load(make_sequence("same_file", m));
  EXPECT_EQ(o.kind, ErrorKind::data);
  expect_parts(o.message, {"meta.json:frames[2].file", "the same image as frames[1]", "distinct-frame-files"});

  fs::path d = make_sequence("gray", base_meta());
  png(d / "rs" / "1.png", 16, 12, 1);  // its GS frames came out gray
  o = load(d);
  expect_parts(o.message, {"meta.json:frames[1].file", "1 channel (gray)", "frames[0] has 3 channels (colour)", "images-agree"});
  png(d / "rs" / "1.png", 20, 12);
  expect_parts(load(d).message, {"frames[1].file", "20x12", "the sensor is 16x12"});

  m = base_meta();
  m["ground_truth"][0]["t_us"] = 9000;  // the recording is [0, 3000]
  o = load(make_sequence("gt_outside", m));
  EXPECT_EQ(o.kind, ErrorKind::data);
  expect_parts(o.message, {"meta.json:ground_truth[0].t_us = 9000", "outside the recording [0, 3000] us"});

  m = base_meta();
  m["frames"][2]["t0_us"] = 1000;
  expect_parts(load(make_sequence("order", m)).message, {"frames[2].t0_us", "frames-in-time-order"});

  d = make_sequence("no_events", base_meta());
  fs::remove(d / "events.txt");
  o = load(d);
  EXPECT_EQ(o.kind, ErrorKind::input_missing) << o.message;
  const auto r = clitest::cli("voxelize " + d.string() + " --frames 0 --times 0.5 --out " + (d.string() + "-v.safetensors"));
  EXPECT_EQ(r.rc, 66) << r.out;
  EXPECT_TRUE(clitest::has(r, "events.txt")) << r.out;
  fs::remove(d / "rs" / "2.png");
  EXPECT_EQ(load(d).kind, ErrorKind::input_missing);
}

// docs/sequence-format.md's schema section is meta_schema_markdown(), between its markers.
TEST(MetaSchema, DocIsInSyncWithTheTable) {
  const fs::path doc = fs::path(VKUNROLL_SOURCE_DIR) / "docs" / "sequence-format.md";
  std::ifstream in(doc);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const std::string begin = "<!-- meta-schema:begin (generated) -->\n", end = "<!-- meta-schema:end -->";
  const size_t a = text.find(begin), b = text.find(end);
  ASSERT_NE(a, std::string::npos) << doc << " has no " << begin;
  ASSERT_NE(b, std::string::npos) << doc << " has no " << end;
  const std::string current = text.substr(a + begin.size(), b - a - begin.size());
  const std::string generated = meta_schema_markdown();
  if (current != generated) {
    const fs::path out = fs::temp_directory_path() / "meta_schema_section.md";
    std::ofstream(out) << generated;
    ADD_FAILURE() << doc << ": the meta.json schema section differs from the table; paste " << out
                  << " between the markers";
  }
  for (const auto& f : meta_fields()) EXPECT_NE(generated.find(std::string("`") + f.path + "`"), std::string::npos) << f.path;
}

// One time rule in the shared EventSink: |t| <= 2^53 us in text and HDF5 alike (HDF5 took
// INT64_MAX as valid; INT64_MIN overflowed the printed span); and HDF5 datasets never written.
TEST(EventRules, ExtremeTimesAndUnwrittenDatasetsAreRefusedAlike) {
  const std::string txt = evtest::tmp("extreme.txt"), h5 = evtest::tmp("extreme.h5");
  for (const int64_t t : {INT64_MAX, INT64_MIN, (int64_t(1) << 53) + 1}) {
    const int64_t first = t < 0 ? t : 5, second = t < 0 ? 5 : t;  // in time order: only the time rule breaks
    evtest::write_file(txt, std::to_string(first) + " 1 1 1\n" + std::to_string(second) + " 1 1 1\n");
    EventStream ev;
    ev.width = 16;
    ev.height = 12;
    ev.push(first, 1, 1, 1);
    ev.push(second, 1, 1, 1);
    write_events_hdf5(h5, ev);
    const char* record = t < 0 ? "record 0" : "record 1";
    for (const std::string& f : {txt, h5}) {
      evtest::expect_error(f, {}, {record, std::to_string(t).c_str(), "beyond +-2^53 us", "rule: |t| <= 9007199254740992 us"});
      EventReadOptions o;
      o.on_bad = BadEventPolicy::drop;
      EventReadReport rep;
      EXPECT_EQ(read_events(f, o, &rep).size(), 1u) << f;
      EXPECT_EQ(rep.dropped_nan, 1u) << f;
    }
  }
  evtest::write_file(txt, "9007199254740992 1 1 1\n");  // 2^53 itself is legal
  EXPECT_EQ(read_events(txt).size(), 1u);

  // events/{t,x,y,p} created with 10^9 rows, never written: refused at once, not read as zeros.
  const std::string unwritten = evtest::tmp("unwritten.h5");
  {
    hid_t f = H5Fcreate(unwritten.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    const hsize_t n = 1000000000;
    hid_t space = H5Screate_simple(1, &n, nullptr);
    for (const auto& [name, type] : {std::pair{"t", H5T_STD_I64LE}, {"x", H5T_STD_U16LE}, {"y", H5T_STD_U16LE}, {"p", H5T_STD_U8LE}})
      H5Dclose(H5Dcreate2(g, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT));
    H5Sclose(space);
    H5Gclose(g);
    H5Fclose(f);
  }
  ASSERT_LT(fs::file_size(unwritten), 1u << 20);  // no storage: what a reader sees is fill values
  evtest::expect_error(unwritten, {}, {"unwritten.h5", "events/t", "1000000000 rows", "never written", "fill values"});
}
