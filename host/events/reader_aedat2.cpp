// jAER AEDAT 2.0 (.aedat): '#' header lines (the first "#!AER-DAT2.0"), then big-endian 8-byte
// records {int32 address, int32 timestamp in us}. The address is read with jAER's DAVIS layout
// (eu.seebetter.ini.chips.DavisChip): bit 31 APS/IMU, bits 22-30 y, 12-21 x, 11 polarity, 10
// special. DVS events are kept; APS ADC samples, IMU words and special events are counted and
// skipped. jAER's DAVIS extractor flips x (x = width-1 - address x) and puts (0, 0) at the lower
// left; the reader turns both into the top-left image convention. See docs/events.md.
#include <algorithm>
#include <cctype>
#include <cstring>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr size_t kBlock = 1 << 20;
constexpr uint32_t kApsOrImu = 0x80000000u, kImuType = 0x00000C00u, kSpecial = 0x00000400u;

inline uint32_t be32(const uint8_t* p) {
  return (uint32_t(p[0]) << 24) | (uint32_t(p[1]) << 16) | (uint32_t(p[2]) << 8) | uint32_t(p[3]);
}

struct Aedat2Header {
  uint64_t data_offset = 0;
  int width = 0, height = 0;
  std::string chip;  // the header line that named the chip
};

Aedat2Header parse_aedat2_header(ByteSource& src) {
  Aedat2Header h;
  const auto magic = read_range(src, 0, 12);
  if (magic.size() < 12 || std::memcmp(magic.data(), "#!AER-DAT2.0", 12) != 0)
    throw DataError(src.name() + ": not an AEDAT 2.0 file (missing '#!AER-DAT2.0' at the start)");
  uint64_t off = 0;
  const uint64_t size = src.size();
  HeaderLines lines(src);
  std::string line;
  while (off < size) {
    uint8_t c = 0;
    // A data record may begin with '#' (0x23) too; jAER's "# End Of ASCII Header" line removes the doubt.
    if (src.read_at(off, &c, 1) != 1 || c != '#') break;
    uint64_t next = 0;
    if (!lines.line(off, line, next))
      throw DataError(src.name() + ": AEDAT 2.0 header line at byte " + std::to_string(off) +
                  " has no end (no newline within 64 KiB or before the end of the file)");
    off = next;
    std::string low = line;
    for (auto& ch : low) ch = char(std::tolower(static_cast<unsigned char>(ch)));
    if (low.find("aechip:") != std::string::npos || low.find("hardwareinterface:") != std::string::npos) {
      std::string n;
      for (char ch : low)
        if (std::isalnum(static_cast<unsigned char>(ch))) n += ch;
      if (n.find("dvs128") != std::string::npos && n.find("davis") == std::string::npos)
        throw DataError(src.name() + ": AEDAT 2.0 header line '" + line +
                    "' names a DVS128, whose 16-bit address layout is not read (only jAER's DAVIS layout is)");
      int w = 0, hh = 0;
      if ((h.width == 0 || low.find("aechip:") != std::string::npos) && sensor_size_from_device_name(line, w, hh))
        h.width = w, h.height = hh, h.chip = line;
    }
    if (low.rfind("# end of ascii header", 0) == 0) break;
  }
  h.data_offset = off;
  return h;
}

// One record; false when the sink says stop.
inline bool aedat2_record(uint32_t addr, uint32_t ts, uint64_t off, Wrap32Clock& st, uint64_t& record, EventSink& sink) {
  const int64_t t = st.time(ts);  // every record moves the clock, the skipped ones too
  if (addr & kApsOrImu) {
    if ((addr & kImuType) == kImuType) sink.ignored("IMU sample words (7 per IMU6 sample)");
    else sink.ignored("APS ADC samples (frame pixels, not read)");
    return true;
  }
  if (addr & kSpecial) {
    sink.ignored("special events (external input)");
    return true;
  }
  const int64_t ax = (addr >> 12) & 0x3FF, ay = (addr >> 22) & 0x1FF;
  sink.set_record_index(record++);
  sink.set_byte_offset(int64_t(off));
  return sink.add(t, sink.width() - 1 - ax, sink.height() - 1 - ay, (addr >> 11) & 1);
}

}  // namespace

void read_aedat2(ByteSource& src, EventSink& sink) {
  const Aedat2Header h = parse_aedat2_header(src);
  if (h.width > 0) sink.set_file_geometry(h.width, h.height, "the AEDAT 2.0 header line '" + h.chip + "'");
  if (!sink.geometry_known())
    throw DataError(src.name() + ": the AEDAT 2.0 header names no DAVIS chip (no '# AEChip:' or '# HardwareInterface:' line "
                             "with DAVIS346, 240, 640, 128 or 208); the sensor size is needed to undo jAER's flipped "
                             "x and y: pass " + opt("width") + " and " + opt("height") + " (EventReadOptions::width/height)");
  sink.note("AEDAT 2.0 records start at byte " + std::to_string(h.data_offset) +
            "; DAVIS layout, x = width-1 - address x, y = height-1 - address y (jAER's origin is the lower left)");
  Wrap32Clock st;
  uint64_t record = 0, off = start_words(sink, h.data_offset, st, record);
  if (!sink.boundary(checkpoint_at(off, record, st))) return;
  uint64_t next = sink.next_checkpoint(off, h.data_offset);
  const uint64_t size = src.size();
  sink.expect_records((size - std::min(size, off)) / 8);
  std::vector<uint8_t> buf(size_t(std::min<uint64_t>(kBlock, size > off ? size - off : 0)));
  while (off < size && !sink.done()) {
    const size_t got = src.read_at(off, buf.data(), size_t(std::min<uint64_t>(kBlock, size - off)));
    const size_t whole = got / 8 * 8;
    if (whole == 0) {
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record("the file ends inside an 8-byte AEDAT 2.0 record (" + std::to_string(got) +
                          " trailing bytes; truncated file)");
      off += got;
      break;
    }
    for (size_t i = 0; i < whole; i += 8) {
      if (off + i >= next) {
        if (!sink.boundary(checkpoint_at(off + i, record, st))) return;
        next = sink.next_checkpoint(off + i, h.data_offset);
      }
      if (!aedat2_record(be32(buf.data() + i), be32(buf.data() + i + 4), off + i, st, record, sink)) return;
    }
    off += whole;
  }
  if (!sink.done()) sink.end_of_data(checkpoint_at(off, record, st));
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
