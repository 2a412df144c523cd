// ROS 1 bags in C++: every message kind and chunk compression of tests/rosbag_test_encoder.hpp reads
// back exactly; windowed reads through EventFileReader's index equal the full scan's slices; a bag
// without an index reads the same; damaged bags are named errors. (Bags written by Debian's rosbag:
// tests/python/test_bindings_rosbag.py.)
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "rosbag_test_encoder.hpp"
#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll {
namespace {

using evtest::BagMessage;
using evtest::BagOptions;

EventStream read_bag_bytes(const std::vector<uint8_t>& bytes, const EventReadOptions& o, EventReadReport* rep = nullptr) {
  EventReadReport local;
  EventReadReport& r = rep ? *rep : local;
  detail::MemorySource src("test.bag", bytes.data(), bytes.size());
  detail::EventSink sink("test.bag", o, r);
  detail::read_rosbag(src, sink);
  return sink.finish();
}

void expect_same(const EventStream& a, const EventStream& b, size_t lo, size_t hi) {
  ASSERT_EQ(a.size(), hi - lo);
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a.t[i], b.t[lo + i]) << i;
    ASSERT_EQ(a.x[i], b.x[lo + i]) << i;
    ASSERT_EQ(a.y[i], b.y[lo + i]) << i;
    ASSERT_EQ(a.p[i], b.p[lo + i]) << i;
  }
}

struct Case {
  BagMessage kind;
  const char* compression;
};

void PrintTo(const Case& c, std::ostream* os) {  // gtest's name of a case (not its bytes)
  static const char* kinds[] = {"dvs", "evt3", "mono"};
  *os << kinds[int(c.kind)] << " " << c.compression;
}

class RosbagKinds : public ::testing::TestWithParam<Case> {};

TEST_P(RosbagKinds, ReadsBackExactlyAndWindowsEqualTheFullScan) {
  // Absolute Unix microseconds, except EVT 3.0 (a sensor clock of 24 bits that wraps, from 0).
  const int64_t t0 = GetParam().kind == BagMessage::evt3_packet ? 1000 : 1'700'000'000'000'000;
  const EventStream ev = evtest::random_stream(20000, 346, 260, 7, t0);
  BagOptions bo;
  bo.kind = GetParam().kind;
  bo.compression = GetParam().compression;
  bo.events_per_message = 250;
  const auto bytes = evtest::encode_rosbag(ev, bo);
  EventReadReport rep;
  const EventStream all = read_bag_bytes(bytes, {}, &rep);
  expect_same(all, ev, 0, ev.size());
  EXPECT_EQ(all.width, 346);
  EXPECT_EQ(all.height, 260);
  EXPECT_EQ(rep.dropped(), 0u);
  // Windows through the index (checkpoints at chunk records) against the slices of the stream.
  EventFileReader reader = detail::memory_file_reader("test.bag", bytes.data(), bytes.size(), "bag", {});
  EventReadOptions sort;
  sort.on_bad = BadEventPolicy::sort;
  EventFileReader sorted = detail::memory_file_reader("test.bag", bytes.data(), bytes.size(), "bag", sort);
  for (int k = 7; k >= 0; --k) {
    const size_t a = size_t(k) * 2500 + 11, b = std::min(ev.size() - 1, a + 3100);
    const int64_t t_begin = ev.t[a], t1 = ev.t[b];
    const EventStream w = reader.read(t_begin, t1);
    const size_t lo = size_t(std::lower_bound(ev.t.begin(), ev.t.end(), t_begin) - ev.t.begin());
    const size_t hi = size_t(std::lower_bound(ev.t.begin(), ev.t.end(), t1) - ev.t.begin());
    expect_same(w, ev, lo, hi);
    expect_same(sorted.read(t_begin, t1), ev, lo, hi);  // on_bad=sort decodes every segment meeting the window
  }
  // The windows above end before the last event: a last open window reads the rest.
  const size_t last = size_t(std::lower_bound(ev.t.begin(), ev.t.end(), ev.t.back()) - ev.t.begin());
  expect_same(reader.read(ev.t.back(), std::nullopt), ev, last, ev.size());
  EXPECT_GT(reader.checkpoints(), 2u);
  EXPECT_EQ(reader.totals().records, ev.size());
}

std::string case_name(const ::testing::TestParamInfo<Case>& c) {
  static const char* kinds[] = {"dvs", "evt3", "mono"};
  return std::string(kinds[int(c.param.kind)]) + "_" + c.param.compression;
}

INSTANTIATE_TEST_SUITE_P(Bags, RosbagKinds,
                         ::testing::Values(Case{BagMessage::dvs_array, "none"}, Case{BagMessage::dvs_array, "bz2"},
                                           Case{BagMessage::evt3_packet, "lz4"}, Case{BagMessage::mono_packet, "none"}),
                         case_name);

TEST(Rosbag, WithoutIndexReadsTheSameAndSaysSo) {
  const EventStream ev = evtest::random_stream(3000, 64, 48, 3);
  BagOptions bo;
  bo.index = false;
  EventReadReport rep;
  expect_same(read_bag_bytes(evtest::encode_rosbag(ev, bo), {}, &rep), ev, 0, ev.size());
  bool said = false;
  for (const auto& n : rep.notes) said |= n.find("no usable index") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST(Rosbag, DamageIsNamed) {
  const EventStream ev = evtest::random_stream(3000, 64, 48, 4);
  BagOptions bo;
  bo.md5 = "ffffffffffffffffffffffffffffffff";
  try {
    read_bag_bytes(evtest::encode_rosbag(ev, bo), {});
    FAIL() << "no error for a wrong md5";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("test.bag: topic '/events' has type dvs_msgs/EventArray with md5 ffff"), std::string::npos) << m;
  }
  // A chunk whose first record's header length is damaged: named, and under drop the other chunks
  // still read.
  auto bytes = evtest::encode_rosbag(ev, {});
  const size_t chunk = 13 + 4104;  // magic, bag header record
  const size_t data = chunk + 4 + (bytes[chunk] | bytes[chunk + 1] << 8) + 4;
  bytes[data + 3] = 0x7F;
  EXPECT_THROW(read_bag_bytes(bytes, {}), Error);
  EventReadOptions drop;
  drop.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  const EventStream got = read_bag_bytes(bytes, drop, &rep);
  EXPECT_GT(rep.dropped_unknown_word, 0u);
  EXPECT_LT(got.size(), ev.size());
  // Not a bag at all, and a bag of another version.
  std::vector<uint8_t> v12(evtest::text_bytes("#ROSBAG V1.2\n"));
  v12.resize(100);
  EXPECT_THROW(read_bag_bytes(v12, {}), Error);
}

TEST(Rosbag, DetectedByMagicAndExtension) {
  const EventStream ev = evtest::random_stream(500, 64, 48, 5);
  const auto dir = std::filesystem::temp_directory_path() / "vkunroll_rosbag_test";
  std::filesystem::create_directories(dir);
  const auto path = (dir / "events.dat").string();  // a misleading extension: the magic wins
  const auto bytes = evtest::encode_rosbag(ev, {});
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  EXPECT_EQ(detect_event_format(path), "bag");
  EventReadOptions o;
  o.events_topic = "/events";
  expect_same(read_events(path, o), ev, 0, ev.size());
  o.events_topic = "/nope";
  EXPECT_THROW(read_events(path, o), Error);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace vkunroll
