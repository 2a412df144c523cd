// The EVT 2.0 and EVT 2.1 word decoders shared by the .raw reader (reader_evt.cpp) and the live
// stream follower (event_stream_follow.cpp): one word at a time, the time-high state (34-bit time
// and its wrap) kept between calls and checkpoints.
#pragma once
#include <cstdint>
#include <string>

#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/evt3_words_detail.hpp"

namespace vkunroll::detail {

struct Evt2State {
  uint64_t time_high = 0, loop = 0;
  bool have_high = false;
  void save(Checkpoint& c) const { c.state = {int64_t(time_high), int64_t(loop), have_high}; }
  void load(const Checkpoint& c) {
    time_high = uint64_t(c.state[0]), loop = uint64_t(c.state[1]), have_high = c.state[2] != 0;
  }
  // EVT_TIME_HIGH: bits 6..33 of the time; one that falls by more than half its range is the wrap.
  void time_high_word(uint64_t th) {
    if (have_high && th < time_high && time_high - th > (uint64_t(1) << 27)) loop += uint64_t(1) << 34;
    time_high = th;
    have_high = true;
  }
  int64_t time(uint32_t word) const { return int64_t(loop + (time_high << 6) + ((word >> 22) & 0x3F)); }
};

// The word types EVT 2.0 and 2.1 share beside the events: the time high, the ignored ones, and
// an unknown type (`format` and `word_hex` name it in the message).
template <class WordHex>
void evt2_control_word(uint32_t type, uint32_t hi, uint64_t off, Evt2State& st, uint64_t& record, EventSink& sink,
                       const char* format, WordHex word_hex) {
  switch (type) {
    case 0x8: st.time_high_word(hi & 0x0FFFFFFF); break;
    case 0xA: sink.ignored("EXT_TRIGGER"); break;
    case 0xE: sink.ignored("OTHERS"); break;
    case 0xF: sink.ignored("CONTINUED"); break;
    default:
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record_lazy(
          [&] { return "unknown " + std::string(format) + " word type " + evt3_hex(type, 1) + " (word " + word_hex() + ")"; });
  }
}

// One EVT 2.0 word at byte `off` (for messages); false when the sink says stop.
inline bool evt2_word(uint32_t w, uint64_t off, Evt2State& st, uint64_t& record, EventSink& sink) {
  const uint32_t type = w >> 28;
  switch (type) {
    case 0x0:    // CD_OFF
    case 0x1: {  // CD_ON
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      if (!sink.add(st.time(w), (w >> 11) & 0x7FF, w & 0x7FF, type)) return false;
      break;
    }
    default: evt2_control_word(type, w, off, st, record, sink, "EVT 2.0", [&] { return evt3_hex(w, 8); });
  }
  return true;
}

// One EVT 2.1 word (hi: type, time low, x, y or time high; lo: the valid mask); false when the sink
// says stop.
inline bool evt21_word(uint32_t hi, uint32_t lo, uint64_t off, Evt2State& st, uint64_t& record, EventSink& sink) {
  const uint32_t type = hi >> 28;
  switch (type) {
    case 0x0:    // EVT_NEG
    case 0x1: {  // EVT_POS: 32 pixels from x (aligned on 32), one bit each
      if (lo == 0) {
        sink.ignored("EVT_NEG/EVT_POS words with an empty mask");
        break;
      }
      const int64_t t = st.time(hi);
      const int64_t x = (hi >> 11) & 0x7FF, y = hi & 0x7FF;
      for (uint32_t mask = lo; mask; mask &= mask - 1) {
        sink.set_record_index(record++);
        sink.set_byte_offset(int64_t(off));
        // The word is consumed whole (a resumed read never restarts inside it).
        if (!sink.add(t, x + __builtin_ctz(mask), y, type)) return false;
      }
      break;
    }
    default:
      evt2_control_word(type, hi, off, st, record, sink, "EVT 2.1", [&] { return evt3_hex((uint64_t(hi) << 32) | lo, 16); });
  }
  return true;
}

}  // namespace vkunroll::detail
