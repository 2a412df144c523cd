// Encoders for jAER AEDAT 2.0, AEDAT 3.1 and Prophesee EVT 2.1, written from the format
// descriptions (docs/events.md cites them), not from the readers. Used by the reader tests, the
// bench and fuzz/make_seeds.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "event_test_encoders.hpp"

namespace vkunroll::evtest {

inline void put32be(std::vector<uint8_t>& b, uint32_t v) {
  for (int i = 3; i >= 0; --i) b.push_back(uint8_t(v >> (8 * i)));
}

// AEDAT 2.0 with jAER's DAVIS layout: address y = H-1-y at bits 22-30, x = W-1-x at bits 12-21,
// polarity at bit 11 (jAER's DVS x flip and lower-left origin); timestamps are the low 32 bits of
// t. With `extras`, every 50th event is followed by an APS sample, a 7-word IMU sample and a
// special (external input) event at the same time.
struct Aedat2Extras {
  uint64_t aps = 0, imu_words = 0, special = 0;
};
inline std::vector<uint8_t> encode_aedat2(const EventStream& ev, const std::string& chip_line, bool extras,
                                          Aedat2Extras* counts = nullptr, bool end_line = true) {
  std::vector<uint8_t> b = text_bytes("#!AER-DAT2.0\r\n# This is a raw AE data file - do not edit\r\n"
                                      "# Data format is int32 address, int32 timestamp (8 bytes total), repeated for each event\r\n"
                                      "# Timestamps tick is 1 us\r\n" + chip_line);
  if (end_line) {
    const auto end = text_bytes("# End Of ASCII Header\r\n");
    b.insert(b.end(), end.begin(), end.end());
  }
  Aedat2Extras n;
  for (size_t i = 0; i < ev.size(); ++i) {
    const uint32_t ts = uint32_t(uint64_t(ev.t[i]));
    put32be(b, (uint32_t(ev.height - 1 - ev.y[i]) << 22) | (uint32_t(ev.width - 1 - ev.x[i]) << 12) |
                   (uint32_t(ev.p[i] > 0 ? 1 : 0) << 11));
    put32be(b, ts);
    if (!extras || i % 50 != 7) continue;
    put32be(b, 0x80000000u | (5u << 22) | (9u << 12) | (1u << 10) | 513u);  // APS signal read, ADC 513
    put32be(b, ts);
    ++n.aps;
    for (uint32_t k = 0; k < 7; ++k) {  // IMU: bit 31, read cycle 3, sample code k at bits 28-30
      put32be(b, 0x80000C00u | (k << 28) | (0x1234u << 12));
      put32be(b, ts);
      ++n.imu_words;
    }
    put32be(b, 0x00000400u);  // external input special event
    put32be(b, ts);
    ++n.special;
  }
  if (counts) *counts = n;
  return b;
}

// AEDAT 3.1: header with '#Source 1: <source>', polarity packets of up to `per_packet` events (a
// new packet when t >> 31 changes), one IMU6 packet and one SPECIAL packet after the first polarity
// packet, and (with `invalid`) an invalidated event at the end of every polarity packet.
inline void put_packet_header(std::vector<uint8_t>& b, int16_t type, int16_t source, int32_t size, int32_t ts_offset,
                              int32_t overflow, int32_t capacity, int32_t number, int32_t valid) {
  put16(b, uint16_t(type));
  put16(b, uint16_t(source));
  for (int32_t v : {size, ts_offset, overflow, capacity, number, valid}) put32(b, uint32_t(v));
}

inline std::vector<uint8_t> encode_aedat3(const EventStream& ev, const std::string& source, size_t per_packet,
                                          bool invalid) {
  std::vector<uint8_t> b = text_bytes("#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: " + source +
                                      "\r\n#Start-Time: 2026-12-02 20:00:00 (TZ+0000)\r\n#!END-HEADER\r\n");
  bool extra_done = false;
  for (size_t a = 0; a < ev.size();) {
    const int64_t overflow = ev.t[a] >> 31;
    size_t e = a;
    while (e < ev.size() && e - a < per_packet && (ev.t[e] >> 31) == overflow) ++e;
    const int32_t n = int32_t(e - a) + (invalid ? 1 : 0);
    put_packet_header(b, 1, 1, 8, 4, int32_t(overflow), n, n, int32_t(e - a));
    for (size_t i = a; i < e; ++i) {
      put32(b, (uint32_t(ev.x[i]) << 17) | (uint32_t(ev.y[i]) << 2) | (uint32_t(ev.p[i] > 0 ? 1 : 0) << 1) | 1u);
      put32(b, uint32_t(ev.t[i] & 0x7FFFFFFF));
    }
    if (invalid) {
      put32(b, (3u << 17) | (4u << 2) | 0u);  // valid bit 0
      put32(b, uint32_t(ev.t[e - 1] & 0x7FFFFFFF));
    }
    if (!extra_done) {
      put_packet_header(b, 3, 1, 36, 4, int32_t(overflow), 2, 2, 2);  // IMU6: 2 x 36 bytes
      for (int k = 0; k < 2; ++k) {
        put32(b, 1);
        put32(b, uint32_t(ev.t[a] & 0x7FFFFFFF));
        for (int j = 0; j < 7; ++j) put32(b, 0);
      }
      put_packet_header(b, 0, 1, 8, 4, int32_t(overflow), 1, 1, 1);  // SPECIAL: a timestamp reset marker
      put32(b, (1u << 1) | 1u);
      put32(b, uint32_t(ev.t[a] & 0x7FFFFFFF));
      extra_done = true;
    }
    a = e;
  }
  return b;
}

// EVT 2.1: EVT_TIME_HIGH (t >> 6) on change; runs of consecutive events with the same t, y and
// polarity and increasing x inside one 32-aligned block become one EVT_POS/EVT_NEG word with a
// 32-bit mask. `legacy`: each word as its high 32-bit half then its low half (IMX636), else one
// little-endian 64-bit word.
inline std::vector<uint8_t> encode_evt21(const EventStream& ev, const std::string& header, bool legacy) {
  std::vector<uint8_t> b = text_bytes(header);
  auto word = [&](uint32_t hi, uint32_t lo) {
    put32(b, legacy ? hi : lo);
    put32(b, legacy ? lo : hi);
  };
  int64_t th = -1;
  for (size_t i = 0; i < ev.size();) {
    const int64_t h = ev.t[i] >> 6;
    if (h != th) word((0x8u << 28) | uint32_t(h & 0x0FFFFFFF), 0), th = h;
    const uint32_t base = ev.x[i] & ~31u, pol = ev.p[i] > 0 ? 1 : 0;
    uint32_t mask = 1u << (ev.x[i] - base);
    size_t j = i + 1;
    while (j < ev.size() && ev.t[j] == ev.t[i] && ev.y[j] == ev.y[i] && ev.p[j] == ev.p[i] && ev.x[j] > ev.x[j - 1] &&
           (ev.x[j] & ~31u) == base)
      mask |= 1u << (ev.x[j++] - base);
    word((pol << 28) | (uint32_t(ev.t[i] & 63) << 22) | (base << 11) | ev.y[i], mask);
    i = j;
  }
  return b;
}

}  // namespace vkunroll::evtest
