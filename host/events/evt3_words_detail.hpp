// The EVT 3.0 word decoder shared by the .raw reader (reader_evt.cpp) and the ROS bag reader's
// event_camera_msgs/EventPacket "evt3" encoding (reader_rosbag.cpp): one 16-bit word at a time,
// its state (time high/low, wrap count, row, vector base) kept between calls and checkpoints.
#pragma once
#include <cstdint>
#include <string>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

struct Evt3State {
  uint64_t time_high = 0, time_low = 0, loop = 0;
  int64_t y = 0, base_x = 0, pol = 0;
  bool have_high = false;
  void save(Checkpoint& c) const {
    c.state[0] = int64_t(time_high), c.state[1] = int64_t(time_low), c.state[2] = int64_t(loop);
    c.state[3] = y, c.state[4] = base_x, c.state[5] = pol, c.state[6] = have_high;
  }
  void load(const Checkpoint& c) {
    time_high = uint64_t(c.state[0]), time_low = uint64_t(c.state[1]), loop = uint64_t(c.state[2]);
    y = c.state[3], base_x = c.state[4], pol = c.state[5], have_high = c.state[6] != 0;
  }
};

inline std::string evt3_hex(uint64_t v, int digits) {
  static const char* d = "0123456789abcdef";
  std::string s(size_t(digits), '0');
  for (int i = digits - 1; i >= 0; --i, v >>= 4) s[size_t(i)] = d[v & 15];
  return "0x" + s;
}

// One EVT 3.0 word at byte `off` (for messages); false when the sink says stop.
inline bool evt3_word(uint16_t w, uint64_t off, Evt3State& st, uint64_t& record, EventSink& sink) {
  const uint32_t type = w >> 12;
  switch (type) {
    case 0x0: st.y = w & 0x7FF; break;  // EVT_ADDR_Y (bit 11: system type)
    case 0x2: {                          // EVT_ADDR_X: one CD event
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      return sink.add(int64_t(st.loop + (st.time_high << 12) + st.time_low), w & 0x7FF, st.y, (w >> 11) & 1);
    }
    case 0x3: st.base_x = w & 0x7FF, st.pol = (w >> 11) & 1; break;  // VECT_BASE_X
    case 0x4:                                                         // VECT_12
    case 0x5: {                                                       // VECT_8
      const int bits = type == 0x4 ? 12 : 8;
      const uint32_t mask = w & ((1u << bits) - 1);
      const int64_t t = int64_t(st.loop + (st.time_high << 12) + st.time_low);
      for (int b = 0; b < bits; ++b) {
        if (!(mask >> b & 1)) continue;
        sink.set_record_index(record++);
        sink.set_byte_offset(int64_t(off));
        if (!sink.add(t, st.base_x + b, st.y, st.pol)) {
          st.base_x += bits;  // the word is consumed whole (a resumed read never restarts inside it)
          return false;
        }
      }
      st.base_x += bits;
      break;
    }
    case 0x6: st.time_low = w & 0xFFF; break;  // EVT_TIME_LOW
    case 0x8: {                                 // EVT_TIME_HIGH
      const uint64_t th = w & 0xFFF;
      // 24-bit time: a time-high that falls by more than half its range is the wrap.
      if (st.have_high && th < st.time_high && st.time_high - th > 2048) st.loop += uint64_t(1) << 24;
      st.time_high = th;
      st.have_high = true;
      break;
    }
    case 0xA: sink.ignored("EXT_TRIGGER"); break;
    case 0x7: sink.ignored("CONTINUED_4"); break;
    case 0xE: sink.ignored("OTHERS"); break;
    case 0xF: sink.ignored("CONTINUED_12"); break;
    default:
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record_lazy(
          [&] { return "unknown EVT 3.0 word type " + evt3_hex(type, 1) + " (word " + evt3_hex(w, 4) + ")"; });
  }
  return true;
}

}  // namespace vkunroll::detail
