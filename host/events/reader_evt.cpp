// Prophesee files: '%' header lines, then EVT 2.0 (32-bit words), EVT 2.1 (64-bit words: 32-pixel
// masks), EVT 3.0 (16-bit stateful words, 24-bit time that wraps) in .raw, or fixed 8-byte CD records in .dat. Streamed in 1 MiB blocks;
// reading stops at the end of the time window. Indexed reads (EventFileReader) resume at decoder
// checkpoints; a one-off .dat window starts by binary search.
#include <algorithm>
#include <cctype>
#include <cstring>

#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/evt2_words_detail.hpp"
#include "vkunroll/host/events/evt3_words_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr size_t kBlock = 1 << 20;

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// Sensor size from a plugin name or sensor generation (Prophesee's HAL plugins).
bool size_from_sensor(const std::string& name, int& w, int& h) {
  const std::string n = lower(name);
  if (n.find("gen41") != std::string::npos || n.find("imx636") != std::string::npos ||
      n.find("gen4_") != std::string::npos || n == "4.1" || n == "4.0" || n == "4") {
    w = 1280, h = 720;
    return true;
  }
  if (n.find("gen31") != std::string::npos || n.find("gen3_") != std::string::npos || n == "3.1" || n == "3.0" || n == "3") {
    w = 640, h = 480;
    return true;
  }
  if (n.find("imx8") != std::string::npos || n.find("genx320") != std::string::npos || n == "320") {
    w = 320, h = 320;
    return true;
  }
  return false;
}

// Where for_each_block ended: the offset after the last whole word handed over, whether the callback
// stopped it, and the bytes of a partial word at the end of the data (a truncated file).
struct BlockEnd {
  uint64_t offset = 0;
  bool stopped = false;
  size_t trailing = 0;
};

// Reads `unit`-byte words from [begin, size) in 1 MiB blocks; fn(ptr, count, byte_offset) returns
// false to stop.
template <class Fn>
BlockEnd for_each_block(ByteSource& src, EventSink& sink, uint64_t begin, size_t unit, Fn fn) {
  BlockEnd end{begin, false, 0};
  const uint64_t size = src.size();
  std::vector<uint8_t> buf(size_t(std::min<uint64_t>(kBlock, size > begin ? size - begin : 0)));
  while (end.offset < size) {
    if (sink.done()) {
      end.stopped = true;
      return end;
    }
    const size_t want = size_t(std::min<uint64_t>(kBlock, size - end.offset));
    const size_t got = src.read_at(end.offset, buf.data(), want);
    if (got == 0) break;
    const size_t whole = got / unit * unit;
    if (whole && !fn(buf.data(), whole / unit, end.offset)) {
      end.stopped = true;
      return end;
    }
    if (whole == 0) {
      end.trailing = got;  // fewer than one word left
      return end;
    }
    end.offset += whole;
  }
  end.stopped = sink.done();
  return end;
}

// The end of a streamed word format: a partial word is a truncated file (error or dropped), then
// the index learns where the data ends.
void finish_words(EventSink& sink, const BlockEnd& end, uint64_t& record, const char* what, Checkpoint last) {
  if (end.stopped) return;
  if (end.trailing) {
    sink.set_record_index(record++);
    sink.set_byte_offset(int64_t(end.offset));
    sink.unknown_record(std::string("the file ends inside a ") + what + " (" + std::to_string(end.trailing) +
                        " trailing bytes; truncated file)");
    last.offset = end.offset + end.trailing;
    last.record = record;
  }
  sink.end_of_data(last);
}

// The word loop of every streamed reader here: `unit`-byte words from `start`, a checkpoint of the
// decoder state `st` wherever the sink asks for one, decode(word, byte offset) per word (false: stop).
template <class State, class Decode>
BlockEnd for_each_word(ByteSource& src, EventSink& sink, uint64_t start, size_t unit, uint64_t data_offset,
                       const uint64_t& record, const State& st, Decode decode) {
  uint64_t next = sink.next_checkpoint(start, data_offset);
  return for_each_block(src, sink, start, unit, [&](const uint8_t* p, size_t n, uint64_t off) {
    for (size_t i = 0; i < n; ++i) {
      const uint64_t at = off + unit * i;
      if (at >= next) {
        if (!sink.boundary(checkpoint_at(at, record, st))) return false;
        next = sink.next_checkpoint(at, data_offset);
      }
      if (!decode(p + unit * i, at)) return false;
    }
    return true;
  });
}

inline uint16_t le16(const uint8_t* p) { return uint16_t(p[0] | (p[1] << 8)); }
inline uint32_t le32(const uint8_t* p) { return uint32_t(p[0]) | (uint32_t(p[1]) << 8) | (uint32_t(p[2]) << 16) | (uint32_t(p[3]) << 24); }

}  // namespace

bool is_prophesee_header_end(std::string_view line) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  if (line.empty() || line.front() != '%') return false;
  line.remove_prefix(1);
  while (!line.empty() && line.front() == ' ') line.remove_prefix(1);
  return line == "end";
}

PropheseeHeader parse_prophesee_header(ByteSource& src) {
  PropheseeHeader h;
  uint64_t off = 0;
  const uint64_t size = src.size();
  std::vector<uint8_t> buf;
  while (off < size) {
    uint8_t c = 0;
    if (src.read_at(off, &c, 1) != 1 || c != '%') break;
    // one header line (at most 64 KiB), read in growing steps
    auto nl = buf.end();
    for (size_t want = 256;; want *= 4) {
      buf = read_range(src, off, want);
      nl = std::find(buf.begin(), buf.end(), uint8_t('\n'));
      if (nl != buf.end() || buf.size() < want || want >= (1 << 16)) break;
    }
    if (nl == buf.end() && buf.size() == (1 << 16))
      throw DataError(src.name() + ": Prophesee header line at byte " + std::to_string(off) + " is longer than 64 KiB");
    std::string line(buf.begin(), nl);
    off += line.size() + (nl != buf.end() ? 1 : 0);
    if (is_prophesee_header_end(line)) break;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::string body = line.substr(1);
    while (!body.empty() && body.front() == ' ') body.erase(body.begin());
    const auto sp = body.find(' ');
    std::string key = body.substr(0, sp), value = sp == std::string::npos ? "" : body.substr(sp + 1);
    while (!value.empty() && value.back() == ' ') value.pop_back();
    h.lines.emplace_back(key, value);
  }
  h.data_offset = off;
  auto to_int = [](const std::string& s) {
    int v = 0;
    for (char ch : s) {
      if (ch < '0' || ch > '9' || v > 1000000) return 0;
      v = v * 10 + (ch - '0');
    }
    return v;
  };
  int w_key = 0, h_key = 0;
  std::string plugin, generation, evt_line, format_line;
  for (const auto& [k, v] : h.lines) {
    const std::string key = lower(k);
    if (key == "format") {
      // "EVT3;height=720;width=1280" or "EVT21;..."
      const std::string fv = lower(v);
      if (fv.rfind("evt3", 0) == 0) h.evt = "3.0";
      else if (fv.rfind("evt21", 0) == 0) h.evt = "2.1";
      else if (fv.rfind("evt2", 0) == 0) h.evt = "2.0";
      if (fv.rfind("evt", 0) == 0) format_line = v;
      int fw = 0, fh = 0;
      size_t p = 0;
      while ((p = fv.find(';', p)) != std::string::npos) {
        ++p;
        const size_t e = fv.find(';', p);
        const std::string kv = fv.substr(p, e == std::string::npos ? std::string::npos : e - p);
        if (kv.rfind("width=", 0) == 0) fw = to_int(kv.substr(6));
        if (kv.rfind("height=", 0) == 0) fh = to_int(kv.substr(7));
        if (kv == "endianness=legacy") h.evt21_legacy = true;
      }
      if (fw > 0 && fh > 0) h.width = fw, h.height = fh, h.geometry_source = "the '% format' line";
    } else if (key == "evt") {
      if (h.evt.empty()) h.evt = v;
      if (evt_line.empty()) evt_line = v;
    } else if (key == "geometry") {
      const auto x = v.find('x');
      if (x != std::string::npos && h.width == 0) {
        const int gw = to_int(v.substr(0, x)), gh = to_int(v.substr(x + 1));
        if (gw > 0 && gh > 0) h.width = gw, h.height = gh, h.geometry_source = "the '% geometry' line";
      }
    } else if (key == "width") {
      w_key = to_int(v);
    } else if (key == "height") {
      h_key = to_int(v);
    } else if (key == "plugin_name") {
      plugin = v;
    } else if (key == "sensor_generation" || key == "generation") {
      generation = v;
    }
  }
  // Two lines naming different encodings leave the data's meaning open: refused, online and offline.
  if (!evt_line.empty() && !format_line.empty() && evt_line != h.evt)
    throw Error(src.name() + ": the '%' header names two encodings, '% evt " + evt_line + "' and '% format " + format_line.substr(0, 40) +
                    "'; which one the data is in cannot be told",
                ErrorKind::data);
  if (h.width == 0 && w_key > 0 && h_key > 0)
    h.width = w_key, h.height = h_key, h.geometry_source = "the '% Width'/'% Height' lines";
  int sw = 0, sh = 0;
  if (h.width == 0 && !plugin.empty() && size_from_sensor(plugin, sw, sh))
    h.width = sw, h.height = sh, h.geometry_source = "the plugin name '" + plugin + "'";
  if (h.width == 0 && !generation.empty() && size_from_sensor(generation, sw, sh))
    h.width = sw, h.height = sh, h.geometry_source = "the sensor generation '" + generation + "'";
  if (h.evt.empty() && !plugin.empty()) {
    // Metavision's defaults: Gen3/3.1 record EVT 2.0, Gen4.1/IMX636/GenX320 record EVT 3.0.
    const std::string pl = lower(plugin);
    if (pl.find("gen3") != std::string::npos) h.evt = "2.0";
    else if (pl.find("gen41") != std::string::npos || pl.find("imx636") != std::string::npos || pl.find("imx8") != std::string::npos)
      h.evt = "3.0";
  }
  return h;
}

namespace {

void apply_header(const PropheseeHeader& h, EventSink& sink, const char* fmt) {
  if (h.width > 0) sink.set_file_geometry(h.width, h.height, h.geometry_source);
  sink.note(std::string(fmt) + " data starts at byte " + std::to_string(h.data_offset) + " after " +
            std::to_string(h.lines.size()) + " header lines");
}



}  // namespace

void read_evt2(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  apply_header(h, sink, "EVT 2.0");
  if (!h.evt.empty() && h.evt != "2.0") sink.note("header says EVT " + h.evt + " but EVT 2.0 was asked for");
  Evt2State st;
  uint64_t record = 0;
  const uint64_t start = start_words(sink, h.data_offset, st, record);
  if (!sink.boundary(checkpoint_at(start, record, st))) return;
  sink.expect_records((src.size() - std::min(src.size(), h.data_offset)) / 4);
  const BlockEnd end = for_each_word(src, sink, start, 4, h.data_offset, record, st, [&](const uint8_t* w, uint64_t at) {
    return evt2_word(le32(w), at, st, record, sink);
  });
  finish_words(sink, end, record, "32-bit EVT 2.0 word", checkpoint_at(end.offset, record, st));
  sink.set_byte_offset(-1);
}


void read_evt21(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  apply_header(h, sink, "EVT 2.1");
  if (!h.evt.empty() && h.evt != "2.1") sink.note("header says EVT " + h.evt + " but EVT 2.1 was asked for");
  const bool legacy = h.evt21_legacy;
  sink.note(legacy ? "EVT 2.1 words as two little-endian 32-bit halves, the high half first (endianness=legacy, IMX636)"
                   : "EVT 2.1 words as little-endian 64-bit words");
  Evt2State st;
  uint64_t record = 0;
  const uint64_t start = start_words(sink, h.data_offset, st, record);
  if (!sink.boundary(checkpoint_at(start, record, st))) return;
  const BlockEnd end = for_each_word(src, sink, start, 8, h.data_offset, record, st, [&](const uint8_t* w, uint64_t at) {
    const uint32_t first = le32(w), second = le32(w + 4);
    return evt21_word(legacy ? first : second, legacy ? second : first, at, st, record, sink);
  });
  finish_words(sink, end, record, "64-bit EVT 2.1 word", checkpoint_at(end.offset, record, st));
  sink.set_byte_offset(-1);
}

void read_evt3(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  apply_header(h, sink, "EVT 3.0");
  if (!h.evt.empty() && h.evt != "3.0") sink.note("header says EVT " + h.evt + " but EVT 3.0 was asked for");
  Evt3State st;
  uint64_t record = 0;
  const uint64_t start = start_words(sink, h.data_offset, st, record);
  if (!sink.boundary(checkpoint_at(start, record, st))) return;
  const BlockEnd end = for_each_word(src, sink, start, 2, h.data_offset, record, st, [&](const uint8_t* w, uint64_t at) {
    return evt3_word(le16(w), at, st, record, sink);
  });
  finish_words(sink, end, record, "16-bit EVT 3.0 word", checkpoint_at(end.offset, record, st));
  sink.set_byte_offset(-1);
}

namespace {

// The byte where .dat records start (after the header and the type/size bytes); 0 when the file
// ends before them (reported to the sink).
uint64_t dat_data_start(ByteSource& src, EventSink& sink, const PropheseeHeader& h) {
  uint64_t data = h.data_offset;
  if (h.lines.empty()) return data;
  // After the header: event type (0x00 TD / 0x0C CD) and event size (8) bytes.
  const auto ts = read_range(src, data, 2);
  if (ts.size() < 2) {
    sink.set_byte_offset(int64_t(data));
    sink.unknown_record("the file ends before the event type/size bytes (truncated .dat)");
    return 0;
  }
  if (ts[1] != 8)
    throw DataError(src.name() + ": .dat event size is " + std::to_string(ts[1]) + " bytes at byte " +
                std::to_string(data + 1) + "; only 8-byte CD/TD records are supported");
  if (ts[0] != 0x00 && ts[0] != 0x0C)
    throw DataError(src.name() + ": .dat event type " + evt3_hex(ts[0], 2) + " at byte " + std::to_string(data) +
                " is not a CD/TD event (0x00 or 0x0c)");
  return data + 2;
}

// Without an index: fixed-size records and 32-bit times without a wrap allow a binary search for
// the window start. Returns the first record to read.
uint64_t dat_window_start(ByteSource& src, EventSink& sink, uint64_t data, uint64_t n) {
  const EventReadOptions& o = sink.options();
  auto ts_at = [&](uint64_t i) {
    uint8_t b[4] = {0, 0, 0, 0};
    src.read_at(data + 8 * i, b, 4);
    return le32(b);
  };
  if (sink.indexing() || !o.t_begin_us || o.on_bad == BadEventPolicy::sort || n <= 1 || ts_at(n - 1) < ts_at(0) ||
      *o.t_begin_us <= 0)
    return 0;
  uint64_t lo = 0, hi = n;
  while (lo < hi) {
    const uint64_t mid = lo + (hi - lo) / 2;
    if (int64_t(ts_at(mid)) < *o.t_begin_us) lo = mid + 1;
    else hi = mid;
  }
  if (lo > 0) {
    sink.report().stopped_early = true;
    sink.note("time window: binary search skipped to record " + std::to_string(lo));
  }
  return lo;
}

}  // namespace

void read_dat(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  if (h.width > 0) sink.set_file_geometry(h.width, h.height, h.geometry_source);
  const uint64_t data = dat_data_start(src, sink, h);
  if (data == 0 && !h.lines.empty()) return;
  sink.note("DAT records start at byte " + std::to_string(data));
  const uint64_t n = (src.size() - std::min(src.size(), data)) / 8;
  Wrap32Clock st;
  uint64_t record = dat_window_start(src, sink, data, n);
  uint64_t start = data + 8 * record;
  if (sink.resume_point()) start = start_words(sink, data, st, record);
  if (!sink.boundary(checkpoint_at(start, record, st))) return;
  sink.expect_records(n - std::min(n, record));
  const BlockEnd end = for_each_word(src, sink, start, 8, data, record, st, [&](const uint8_t* w, uint64_t at) {
    const uint32_t d = le32(w + 4);
    const int64_t t = st.time(le32(w));
    sink.set_record_index(record++);
    sink.set_byte_offset(int64_t(at));
    return sink.add(t, d & 0x3FFF, (d >> 14) & 0x3FFF, (d >> 28) & 1);
  });
  finish_words(sink, end, record, "8-byte .dat record", checkpoint_at(end.offset, record, st));
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
