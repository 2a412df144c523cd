// Readers of jAER AEDAT 2.0, AEDAT 3.1 and Prophesee EVT 2.1: files from the encoders in
// event_test_encoders_jaer.hpp (round trips with exact counts and fields, skipped record kinds
// counted, time wraps), EVT 2.1 against the EVT 2.0 decode of the same events, the real
// recordings re-encoded into each format, truncated and corrupt files, windows through the index.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "event_test_encoders_jaer.hpp"
#include "event_test_util.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

const char* kDavis346 = "# HardwareInterface: DAVIS FX3 0002-INI\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346B\r\n";

// Rows of neighbouring events at one time (so EVT 2.1 masks hold several pixels), sorted by t.
EventStream clustered_stream(size_t groups, int w, int h, uint32_t seed, int64_t t0) {
  std::mt19937 rng(seed);
  EventStream ev;
  ev.width = w, ev.height = h;
  int64_t t = t0;
  for (size_t k = 0; k < groups; ++k) {
    t += int64_t(rng() % 9);
    const uint16_t y = uint16_t(rng() % uint32_t(h));
    const int8_t p = (rng() & 1) ? 1 : -1;
    uint16_t x = uint16_t(rng() % uint32_t(w - 40));
    for (int i = 0, n = 1 + int(rng() % 8); i < n; ++i, x = uint16_t(x + 1 + rng() % 3)) ev.push(t, x, y, p);
  }
  return ev;
}

// Windows through one EventFileReader equal the windows of a full read (the index resumes at
// checkpoints with the decoder state of a full scan).
void expect_indexed_windows_match(const std::string& path, const EventStream& all, EventReadOptions o = {}) {
  EventFileReader reader(path, o);
  const int64_t lo = all.t.front(), span = all.t.back() - lo + 1;
  for (int k = 7; k >= 0; --k) {  // backwards first: later windows come from the index
    EventReadOptions w = o;
    w.t_begin_us = lo + span * k / 8;
    w.t_end_us = lo + span * (k + 1) / 8 + span / 16;
    expect_same(read_events(path, w), reader.read(w.t_begin_us, w.t_end_us));
  }
  EXPECT_GT(reader.checkpoints(), 2u) << path;
}

}  // namespace

// ---- AEDAT 2.0 ---------------------------------------------------------------------------------

TEST(EventReadersJaer, Aedat2DavisRoundTripSkipsApsImuSpecialAndUnwrapsTime) {
  // Starts 20 ms before the 32-bit microsecond wrap (71.6 min), so the file's timestamps wrap.
  const EventStream ev = random_stream(30000, 346, 260, 21, (int64_t(1) << 32) - 20000, 2);
  ASSERT_GT(ev.t.back(), int64_t(1) << 32);
  Aedat2Extras extras;
  const std::string path = tmp("davis.aedat");
  write_bytes(path, encode_aedat2(ev, kDavis346, true, &extras));
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "aedat2");
  EXPECT_EQ(detect_event_format(path), "aedat2");
  EXPECT_EQ(rep.records, ev.size());
  EXPECT_EQ(rep.dropped(), 0u);
  EXPECT_EQ(rep.ignored.at("APS ADC samples (frame pixels, not read)"), extras.aps) << rep.summary();
  EXPECT_EQ(rep.ignored.at("IMU sample words (7 per IMU6 sample)"), extras.imu_words);
  EXPECT_EQ(rep.ignored.at("special events (external input)"), extras.special);
  EXPECT_GT(extras.aps, 500u);
  expect_indexed_windows_match(path, ev);
  // scan_events streams the same events in chunks.
  EventStream joined;
  scan_events(path, {}, [&](const EventStream& c) {
    for (size_t i = 0; i < c.size(); ++i) joined.push(c.t[i], c.x[i], c.y[i], c.p[i]);
  }, nullptr, 4096);
  joined.width = 346, joined.height = 260;
  expect_same(ev, joined);
}

TEST(EventReadersJaer, Aedat2HeaderRulesTruncationAndBadAddresses) {
  const EventStream ev = random_stream(200, 240, 180, 22);
  const std::string path = tmp("bad.aedat");
  // No chip named: the size is needed to undo jAER's flips; the options give it.
  write_bytes(path, encode_aedat2(ev, "", false));
  expect_error(path, {}, {"bad.aedat", "names no DAVIS chip", "pass width"});
  EventReadOptions o;
  o.width = 240, o.height = 180;
  expect_same(ev, read_events(path, o));
  // DAVIS240 from the class name; no "End Of ASCII Header" line (the header ends at the first non-'#').
  write_bytes(path, encode_aedat2(ev, "# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C\r\n", false, nullptr, false));
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.width, 240);
  write_bytes(path, encode_aedat2(ev, "# AEChip: ch.unizh.ini.jaer.chip.retina.DVS128\r\n", false));
  expect_error(path, {}, {"bad.aedat", "DVS128"});
  write_bytes(path, text_bytes("#!AER-DAT1.0\r\n"));
  expect_error(path, {}, {"bad.aedat", "AEDAT"});
  // Truncated: 3 bytes of a record (error; with drop, every whole record is kept).
  auto bytes = encode_aedat2(ev, kDavis346, false);
  bytes.erase(bytes.end() - 5, bytes.end());
  write_bytes(path, bytes);
  expect_error(path, {}, {"bad.aedat", "truncated", "3 trailing bytes", "record 199"});
  o = {};
  o.on_bad = BadEventPolicy::drop;
  EXPECT_EQ(read_events(path, o, &rep).size(), ev.size() - 1);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  // An address x beyond the DAVIS346's 346 columns is out of the sensor.
  bytes = encode_aedat2(ev, kDavis346, false);
  put32be(bytes, 400u << 12);
  put32be(bytes, uint32_t(ev.t.back()));
  write_bytes(path, bytes);
  expect_error(path, {}, {"bad.aedat", "record 200", "outside the 346x260 sensor"});
  EXPECT_EQ(read_events(path, o, &rep).size(), ev.size());
  EXPECT_EQ(rep.dropped_out_of_sensor, 1u);
}

// ---- AEDAT 3.1 ---------------------------------------------------------------------------------

TEST(EventReadersJaer, Aedat3PolarityPacketsOverflowInvalidAndOtherTypes) {
  // Starts before the 31-bit timestamp overflow: packets with overflow 0 and 1.
  const EventStream ev = random_stream(20000, 346, 260, 23, (int64_t(1) << 31) - 10000, 2);
  const std::string path = tmp("caer.aedat");
  write_bytes(path, encode_aedat3(ev, "DAVIS346B", 1000, true));
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "aedat3");
  EXPECT_EQ(detect_event_format(path), "aedat3");
  EXPECT_EQ(rep.records, ev.size());
  size_t packets = 0;  // the encoder's polarity packets, one invalidated event each
  for (size_t a = 0, e = 0; a < ev.size(); a = e, ++packets)
    for (e = a; e < ev.size() && e - a < 1000 && (ev.t[e] >> 31) == (ev.t[a] >> 31);) ++e;
  EXPECT_GE(packets, 21u);
  EXPECT_EQ(rep.ignored.at("invalid polarity events (valid bit 0)"), packets) << rep.summary();
  EXPECT_EQ(rep.ignored.at("IMU6 events"), 2u);
  EXPECT_EQ(rep.ignored.at("SPECIAL events"), 1u);
  expect_indexed_windows_match(path, ev);
}

TEST(EventReadersJaer, Aedat3TruncatedCorruptAndBadHeaders) {
  const EventStream ev = random_stream(3000, 128, 128, 24);
  const std::string path = tmp("cut.aedat");
  auto bytes = encode_aedat3(ev, "DVS128", 1000, false);
  const size_t full = bytes.size();
  bytes.erase(bytes.end() - (8 * 300 + 3), bytes.end());  // inside the last polarity packet: 699 whole events
  write_bytes(path, bytes);
  const size_t last_packet = full - 28 - 8 * 1000;
  const std::string at = "(byte " + std::to_string(last_packet) + ")";
  expect_error(path, {}, {"cut.aedat", "truncated AEDAT 3.1 file", at.c_str(), "2403 bytes missing"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EXPECT_EQ(read_events(path, o, &rep).size(), 2699u);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  // A header cut inside the 28 bytes.
  bytes.erase(bytes.begin() + long(last_packet + 10), bytes.end());
  write_bytes(path, bytes);
  expect_error(path, {}, {"cut.aedat", "28-byte packet header"});
  // eventNumber > eventCapacity in the first packet.
  bytes = encode_aedat3(ev, "DVS128", 1000, false);
  const size_t first = std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size()).find("#!END-HEADER\r\n") + 14;
  bytes[first + 20] = 0xFF, bytes[first + 21] = 0x7F;
  write_bytes(path, bytes);
  expect_error(path, {}, {"cut.aedat", "corrupt AEDAT 3.1 packet header", "exceed eventCapacity"});
  write_bytes(path, text_bytes("#!AER-DAT3.1\r\n#Format: RAW\r\n"));
  expect_error(path, {}, {"cut.aedat", "no '#!END-HEADER'"});
  write_bytes(path, text_bytes("#!AER-DAT3.0\r\n#Format: RAW\r\n"));
  expect_error(path, {}, {"cut.aedat", "AEDAT 3.0 is not supported"});
}

// ---- EVT 2.1 -----------------------------------------------------------------------------------

TEST(EventReadersJaer, Evt21EqualsTheEvt2DecodeOfTheSameEventsBothByteOrders) {
  // Starts before the 34-bit time wrap (4 h 46 min) that EVT 2.0 and 2.1 share.
  const EventStream ev = clustered_stream(20000, 1280, 720, 25, (int64_t(1) << 34) - 50000);
  ASSERT_GT(ev.t.back(), int64_t(1) << 34);
  const std::string p2 = tmp("same.evt2.raw"), p21 = tmp("same.evt21.raw");
  write_bytes(p2, encode_evt2(ev, "% evt 2.0\n% format EVT2;height=720;width=1280\n% end\n"));
  const EventStream from_evt2 = read_events(p2);
  for (const bool legacy : {false, true}) {
    SCOPED_TRACE(legacy ? "legacy" : "64-bit");
    const std::string header = std::string("% evt 2.1\n% format EVT21;") + (legacy ? "endianness=legacy;" : "") +
                               "height=720;width=1280\n% end\n";
    const auto bytes = encode_evt21(ev, header, legacy);
    EXPECT_LT(bytes.size(), ev.size() * 8 * 3 / 4);  // masks really hold several pixels
    write_bytes(p21, bytes);
    EventReadReport rep;
    const EventStream from_evt21 = read_events(p21, {}, &rep);
    EXPECT_EQ(rep.format, "evt21");
    EXPECT_EQ(detect_event_format(p21), "evt21");
    expect_same(from_evt2, from_evt21);
    expect_same(ev, from_evt21);
    expect_indexed_windows_match(p21, ev);
  }
  // Read with the wrong byte order, the words are garbage: the check is not vacuous.
  write_bytes(p21, encode_evt21(ev, "% evt 2.1\n% format EVT21;height=720;width=1280\n", true));
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EXPECT_NE(read_events(p21, o).size(), ev.size());
}

TEST(EventReadersJaer, Evt21UnknownWordsTriggersAndTruncation) {
  const EventStream ev = clustered_stream(100, 640, 480, 26, 1000);
  const std::string header = "% evt 2.1\n% geometry 640x480\n";
  auto bytes = encode_evt21(ev, header, false);
  std::vector<uint8_t> extra;
  for (uint32_t hi : {0xA0000001u, 0x50000000u, 0x00000000u}) put32(extra, 0), put32(extra, hi);  // trigger, unknown, empty mask
  bytes.insert(bytes.begin() + long(header.size() + 16), extra.begin(), extra.end());
  const std::string path = tmp("w.raw");
  write_bytes(path, bytes);
  const std::string at = "(byte " + std::to_string(header.size() + 24) + ")";
  expect_error(path, {}, {"w.raw", "unknown EVT 2.1 word type 0x5", at.c_str()});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  expect_same(ev, read_events(path, o, &rep));
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  EXPECT_EQ(rep.ignored.at("EXT_TRIGGER"), 1u);
  EXPECT_EQ(rep.ignored.at("EVT_NEG/EVT_POS words with an empty mask"), 1u);
  auto clean = encode_evt21(ev, header, false);
  clean.erase(clean.end() - 5, clean.end());
  write_bytes(path, clean);
  expect_error(path, {}, {"w.raw", "truncated", "3 trailing bytes"});
  // No encoding named: detection asks for --format and lists evt21.
  write_bytes(path, encode_evt21(ev, "% date today\n", false));
  expect_error(path, {}, {"w.raw", "evt21"});
}

// ---- the real recordings, re-encoded -------------------------------------------------------------

TEST(EventReadersJaer, RealRecordingsReencodedReadBackEqual) {
  const std::string evt3 = vktest::real_recording("evt3_sample.raw");
  const std::string aedat4 = vktest::real_recording("sample.aedat4");
  const EventStream prophesee = read_events(evt3);  // 1280x720: too wide for AEDAT 2.0's 10-bit x
  ASSERT_EQ(prophesee.size(), 219596u);
  const std::string p21 = tmp("real.raw"), p3 = tmp("real3.aedat"), p2 = tmp("real2.aedat");
  write_bytes(p21, encode_evt21(prophesee, "% evt 2.1\n% format EVT21;endianness=legacy;height=720;width=1280\n", true));
  expect_same(prophesee, read_events(p21));
  write_bytes(p3, encode_aedat3(prophesee, "Prophesee 1280x720", 4096, false));
  EventReadOptions o;
  o.width = 1280, o.height = 720;  // the source name is no libcaer device
  expect_same(prophesee, read_events(p3, o));
  EventStream inivation = read_events(aedat4);  // 320x240 DVXplorer Lite
  ASSERT_EQ(inivation.size(), 111954u);
  // Its times are Unix microseconds; AEDAT 2.0 holds 32 bits and EVT 2.1 34 bits (jAER's aedat4to2
  // also starts the times at 0), so the copy starts at 0 as well.
  const int64_t t0 = inivation.t.front();
  for (auto& t : inivation.t) t -= t0;
  write_bytes(p2, encode_aedat2(inivation, "", true));
  o.width = 320, o.height = 240;
  EventReadReport rep;
  expect_same(inivation, read_events(p2, o, &rep));
  EXPECT_EQ(rep.dropped(), 0u);
  write_bytes(p3, encode_aedat3(inivation, "DVXplorer Lite", 4096, true));
  expect_same(inivation, read_events(p3));
  write_bytes(p21, encode_evt21(inivation, "% evt 2.1\n% format EVT21;height=240;width=320\n", false));
  expect_same(inivation, read_events(p21));
}

TEST(EventReadersJaer, CliEventsReadsTheNewFormats) {
  const EventStream ev = random_stream(500, 346, 260, 27);
  const std::string a2 = tmp("cli.aedat"), a3 = tmp("cli3.aedat"), e21 = tmp("cli.raw"), out = tmp("cli_jaer.out");
  write_bytes(a2, encode_aedat2(ev, kDavis346, true));
  write_bytes(a3, encode_aedat3(ev, "DAVIS346B", 100, false));
  write_bytes(e21, encode_evt21(ev, "% evt 2.1\n% format EVT21;height=260;width=346\n", false));
  for (const std::string& f : {a2, a3, e21}) {
    const std::string cmd = std::string(VKUNROLL_CLI_PATH) + " events " + f + " > " + out + " 2>&1";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << f;
    std::ifstream in(out);
    const std::string text((std::istreambuf_iterator<char>(in)), {});
    EXPECT_NE(text.find("events      500"), std::string::npos) << text;
    EXPECT_NE(text.find("sensor      346x260"), std::string::npos) << text;
  }
}
