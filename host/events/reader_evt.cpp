// Prophesee files: '%' header lines, then EVT 2.0 (32-bit words), EVT 3.0 (16-bit stateful words,
// 24-bit time that wraps) in .raw, or fixed 8-byte CD records in .dat. Streamed in 1 MiB blocks;
// reading stops at the end of the time window. .dat windows start by binary search.
#include <algorithm>
#include <cctype>
#include <cstring>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr size_t kBlock = 1 << 20;

std::string hex(uint64_t v, int digits) {
  static const char* d = "0123456789abcdef";
  std::string s(size_t(digits), '0');
  for (int i = digits - 1; i >= 0; --i, v >>= 4) s[size_t(i)] = d[v & 15];
  return "0x" + s;
}

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

// Reads blocks of `unit`-byte words from [begin, size); calls fn(ptr, count, byte_offset).
template <class Fn>
void for_each_block(ByteSource& src, EventSink& sink, uint64_t begin, size_t unit, const char* what, Fn fn) {
  uint64_t off = begin;
  const uint64_t size = src.size();
  std::vector<uint8_t> buf(size_t(std::min<uint64_t>(kBlock, size > begin ? size - begin : 0)));
  while (off < size && !sink.done()) {
    const size_t want = size_t(std::min<uint64_t>(kBlock, size - off));
    const size_t got = src.read_at(off, buf.data(), want);
    if (got == 0) break;
    const size_t whole = got / unit * unit;
    if (whole) fn(buf.data(), whole / unit, off);
    if (whole < unit && got < unit) {
      // fewer than one word left: truncated file
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record(std::string("the file ends inside a ") + what + " (" + std::to_string(got) +
                          " trailing bytes; truncated file)");
      return;
    }
    off += whole;
  }
}

inline uint16_t le16(const uint8_t* p) { return uint16_t(p[0] | (p[1] << 8)); }
inline uint32_t le32(const uint8_t* p) { return uint32_t(p[0]) | (uint32_t(p[1]) << 8) | (uint32_t(p[2]) << 16) | (uint32_t(p[3]) << 24); }

}  // namespace

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
      throw Error(src.name() + ": Prophesee header line at byte " + std::to_string(off) + " is longer than 64 KiB");
    std::string line(buf.begin(), nl);
    off += line.size() + (nl != buf.end() ? 1 : 0);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::string body = line.substr(1);
    while (!body.empty() && body.front() == ' ') body.erase(body.begin());
    if (body == "end") break;
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
  std::string plugin, generation;
  for (const auto& [k, v] : h.lines) {
    const std::string key = lower(k);
    if (key == "format") {
      // "EVT3;height=720;width=1280" or "EVT21;..."
      const std::string fv = lower(v);
      if (fv.rfind("evt3", 0) == 0) h.evt = "3.0";
      else if (fv.rfind("evt21", 0) == 0) h.evt = "2.1";
      else if (fv.rfind("evt2", 0) == 0) h.evt = "2.0";
      int fw = 0, fh = 0;
      size_t p = 0;
      while ((p = fv.find(';', p)) != std::string::npos) {
        ++p;
        const size_t e = fv.find(';', p);
        const std::string kv = fv.substr(p, e == std::string::npos ? std::string::npos : e - p);
        if (kv.rfind("width=", 0) == 0) fw = to_int(kv.substr(6));
        if (kv.rfind("height=", 0) == 0) fh = to_int(kv.substr(7));
      }
      if (fw > 0 && fh > 0) h.width = fw, h.height = fh, h.geometry_source = "the '% format' line";
    } else if (key == "evt") {
      if (h.evt.empty()) h.evt = v;
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
  uint64_t time_high = 0, loop = 0, record = 0;
  bool have_high = false;
  sink.expect_records((src.size() - std::min(src.size(), h.data_offset)) / 4);
  for_each_block(src, sink, h.data_offset, 4, "32-bit EVT 2.0 word", [&](const uint8_t* p, size_t n, uint64_t off) {
    for (size_t i = 0; i < n; ++i) {
      const uint32_t w = le32(p + 4 * i);
      const uint32_t type = w >> 28;
      switch (type) {
        case 0x0:
        case 0x1: {
          sink.set_record_index(record++);
          sink.set_byte_offset(int64_t(off + 4 * i));
          const int64_t t = int64_t(loop + (time_high << 6) + ((w >> 22) & 0x3F));
          if (!sink.add(t, (w >> 11) & 0x7FF, w & 0x7FF, type)) return;
          break;
        }
        case 0x8: {
          const uint64_t th = w & 0x0FFFFFFF;
          // 34-bit time: a time-high that falls by more than half its range is the wrap.
          if (have_high && th < time_high && time_high - th > (uint64_t(1) << 27)) loop += uint64_t(1) << 34;
          time_high = th;
          have_high = true;
          break;
        }
        case 0xA: sink.ignored("EXT_TRIGGER"); break;
        case 0xE: sink.ignored("OTHERS"); break;
        case 0xF: sink.ignored("CONTINUED"); break;
        default:
          sink.set_record_index(record++);
          sink.set_byte_offset(int64_t(off + 4 * i));
          sink.unknown_record_lazy([&] { return "unknown EVT 2.0 word type " + hex(type, 1) + " (word " + hex(w, 8) + ")"; });
      }
    }
  });
  sink.set_byte_offset(-1);
}

void read_evt3(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  apply_header(h, sink, "EVT 3.0");
  if (!h.evt.empty() && h.evt != "3.0") sink.note("header says EVT " + h.evt + " but EVT 3.0 was asked for");
  uint64_t time_high = 0, time_low = 0, loop = 0, record = 0;
  int64_t y = 0, base_x = 0, pol = 0;
  bool have_high = false;
  for_each_block(src, sink, h.data_offset, 2, "16-bit EVT 3.0 word", [&](const uint8_t* p, size_t n, uint64_t off) {
    for (size_t i = 0; i < n; ++i) {
      const uint16_t w = le16(p + 2 * i);
      const uint32_t type = w >> 12;
      switch (type) {
        case 0x0: y = w & 0x7FF; break;                 // EVT_ADDR_Y (bit 11: system type)
        case 0x2: {                                      // EVT_ADDR_X: one CD event
          sink.set_record_index(record++);
          sink.set_byte_offset(int64_t(off + 2 * i));
          if (!sink.add(int64_t(loop + (time_high << 12) + time_low), w & 0x7FF, y, (w >> 11) & 1)) return;
          break;
        }
        case 0x3: base_x = w & 0x7FF; pol = (w >> 11) & 1; break;  // VECT_BASE_X
        case 0x4:                                                   // VECT_12
        case 0x5: {                                                 // VECT_8
          const int bits = type == 0x4 ? 12 : 8;
          const uint32_t mask = w & ((1u << bits) - 1);
          const int64_t t = int64_t(loop + (time_high << 12) + time_low);
          for (int b = 0; b < bits; ++b) {
            if (!(mask >> b & 1)) continue;
            sink.set_record_index(record++);
            sink.set_byte_offset(int64_t(off + 2 * i));
            if (!sink.add(t, base_x + b, y, pol)) return;
          }
          base_x += bits;
          break;
        }
        case 0x6: time_low = w & 0xFFF; break;  // EVT_TIME_LOW
        case 0x8: {                              // EVT_TIME_HIGH
          const uint64_t th = w & 0xFFF;
          // 24-bit time: a time-high that falls by more than half its range is the wrap.
          if (have_high && th < time_high && time_high - th > 2048) loop += uint64_t(1) << 24;
          time_high = th;
          have_high = true;
          break;
        }
        case 0xA: sink.ignored("EXT_TRIGGER"); break;
        case 0x7: sink.ignored("CONTINUED_4"); break;
        case 0xE: sink.ignored("OTHERS"); break;
        case 0xF: sink.ignored("CONTINUED_12"); break;
        default:
          sink.set_record_index(record++);
          sink.set_byte_offset(int64_t(off + 2 * i));
          sink.unknown_record_lazy([&] { return "unknown EVT 3.0 word type " + hex(type, 1) + " (word " + hex(w, 4) + ")"; });
      }
    }
  });
  sink.set_byte_offset(-1);
}

void read_dat(ByteSource& src, EventSink& sink) {
  const PropheseeHeader h = parse_prophesee_header(src);
  if (h.width > 0) sink.set_file_geometry(h.width, h.height, h.geometry_source);
  uint64_t data = h.data_offset;
  if (!h.lines.empty()) {
    // After the header: event type (0x00 TD / 0x0C CD) and event size (8) bytes.
    const auto ts = read_range(src, data, 2);
    if (ts.size() < 2) {
      sink.set_byte_offset(int64_t(data));
      sink.unknown_record("the file ends before the event type/size bytes (truncated .dat)");
      return;
    }
    if (ts[1] != 8)
      throw Error(src.name() + ": .dat event size is " + std::to_string(ts[1]) + " bytes at byte " +
                  std::to_string(data + 1) + "; only 8-byte CD/TD records are supported");
    if (ts[0] != 0x00 && ts[0] != 0x0C)
      throw Error(src.name() + ": .dat event type " + hex(ts[0], 2) + " at byte " + std::to_string(data) +
                  " is not a CD/TD event (0x00 or 0x0c)");
    data += 2;
  }
  sink.note("DAT records start at byte " + std::to_string(data));
  const uint64_t n = (src.size() - std::min(src.size(), data)) / 8;
  uint64_t first = 0;
  const EventReadOptions& o = sink.options();
  auto ts_at = [&](uint64_t i) {
    uint8_t b[4] = {0, 0, 0, 0};
    src.read_at(data + 8 * i, b, 4);
    return le32(b);
  };
  if (o.t_begin_us && o.on_bad != BadEventPolicy::sort && n > 1 && ts_at(n - 1) >= ts_at(0) && *o.t_begin_us > 0) {
    // Fixed-size records and 32-bit times without a wrap: binary search for the window start.
    uint64_t lo = 0, hi = n;
    while (lo < hi) {
      const uint64_t mid = lo + (hi - lo) / 2;
      if (int64_t(ts_at(mid)) < *o.t_begin_us) lo = mid + 1;
      else hi = mid;
    }
    first = lo;
    if (first > 0) {
      sink.report().stopped_early = true;
      sink.note("time window: binary search skipped to record " + std::to_string(first));
    }
  }
  sink.expect_records(n - first);
  uint64_t loop = 0, record = first;
  uint32_t prev = 0;
  bool have_prev = false;
  for_each_block(src, sink, data + 8 * first, 8, "8-byte .dat record", [&](const uint8_t* p, size_t cnt, uint64_t off) {
    for (size_t i = 0; i < cnt; ++i) {
      const uint32_t ts = le32(p + 8 * i), d = le32(p + 8 * i + 4);
      // 32-bit microseconds wrap after 71.6 minutes.
      if (have_prev && ts < prev && prev - ts > (1u << 31)) loop += uint64_t(1) << 32;
      prev = ts;
      have_prev = true;
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off + 8 * i));
      if (!sink.add(int64_t(loop + ts), d & 0x3FFF, (d >> 14) & 0x3FFF, (d >> 28) & 1)) return;
    }
  });
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
