// AEDAT 3.1 (.aedat, libcaer / cAER): '#' header lines from "#!AER-DAT3.1" to "#!END-HEADER", then
// packets: a 28-byte little-endian header {int16 eventType, int16 eventSource, int32 eventSize,
// eventTSOffset, eventTSOverflow, eventCapacity, eventNumber, eventValid} and eventCapacity x
// eventSize bytes of events. Polarity events (type 1, 8 bytes): uint32 data (bit 0 valid, bit 1
// polarity, bits 2-16 y, bits 17-31 x; origin top left), int32 timestamp; t = overflow << 31 | ts.
// Other packet types are counted and skipped; invalidated events are counted. See docs/events.md.
#include <algorithm>
#include <cctype>
#include <cstring>
#include <map>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr uint64_t kMaxPacket = uint64_t(256) << 20;  // bytes of one packet (guards hostile input)

inline uint32_t le32u(const uint8_t* p) {
  return uint32_t(p[0]) | (uint32_t(p[1]) << 8) | (uint32_t(p[2]) << 16) | (uint32_t(p[3]) << 24);
}
inline int32_t le32s(const uint8_t* p) { return int32_t(le32u(p)); }

struct Aedat3Header {
  uint64_t data_offset = 0;
  int source = -1;  // the event source read (the first '#Source' line); -1: every source
  std::string source_name;
  int width = 0, height = 0;
};

Aedat3Header parse_aedat3_header(ByteSource& src) {
  const std::string& file = src.name();
  const auto magic = read_range(src, 0, 12);
  if (magic.size() >= 12 && std::memcmp(magic.data(), "#!AER-DAT3.0", 12) == 0)
    throw DataError(file + ": AEDAT 3.0 is not supported (no end-of-header line, origin at the lower left); convert it to "
                       "AEDAT 3.1 or 4.0 with iniVation's DV");
  if (magic.size() < 12 || std::memcmp(magic.data(), "#!AER-DAT3.1", 12) != 0)
    throw DataError(file + ": not an AEDAT 3.1 file (missing '#!AER-DAT3.1' at the start)");
  Aedat3Header h;
  uint64_t off = 0;
  HeaderLines lines(src);
  std::string line;
  for (;;) {
    uint64_t next = 0;
    uint8_t c = 0;
    if (src.read_at(off, &c, 1) != 1 || c != '#' || !lines.line(off, line, next))
      throw DataError(file + ": the AEDAT 3.1 header has no '#!END-HEADER' line (it ends at byte " + std::to_string(off) +
                  "; truncated or not AEDAT 3.1)");
    off = next;
    if (line == "#!END-HEADER") break;
    // "#Source <ID>: <DESCRIPTION>"; "#-Source" lines are sources of an earlier recording.
    if (line.rfind("#Source ", 0) == 0 && h.source < 0) {
      const size_t colon = line.find(':');
      int id = 0;
      bool digits = colon != std::string::npos && colon > 8 && colon - 8 <= 5;
      for (size_t i = 8; digits && i < colon; ++i) {
        if (line[i] < '0' || line[i] > '9') digits = false;
        else id = id * 10 + (line[i] - '0');
      }
      if (!digits) continue;
      h.source = id;
      const size_t v = line.find_first_not_of(' ', colon + 1);
      h.source_name = v == std::string::npos ? "" : line.substr(v);
      sensor_size_from_device_name(h.source_name, h.width, h.height);
    }
  }
  h.data_offset = off;
  return h;
}

struct PacketHeader {
  int16_t type = 0, source = 0;
  int32_t size = 0, ts_offset = 0, ts_overflow = 0, capacity = 0, number = 0, valid = 0;
};

const char* packet_kind(int type) {
  static const char* kKinds[] = {"SPECIAL", "POLARITY", "FRAME", "IMU6", "IMU9", "SAMPLE", "EAR",
                                 "CONFIG", "POINT1D", "POINT2D", "POINT3D", "POINT4D", "SPIKE"};
  return type >= 0 && type < 13 ? kKinds[type] : nullptr;
}

// The polarity events of one packet whose first `avail` payload bytes are in `p`; false when the
// sink says stop.
bool polarity_packet(const PacketHeader& ph, const uint8_t* p, uint64_t avail, uint64_t off, uint64_t& record,
                     EventSink& sink) {
  const uint64_t n = std::min<uint64_t>(uint64_t(ph.number), avail / 8);
  for (uint64_t i = 0; i < n; ++i) {
    const uint32_t data = le32u(p + 8 * i);
    const int32_t ts = le32s(p + 8 * i + 4);
    if (!(data & 1)) {
      sink.ignored("invalid polarity events (valid bit 0)");
      continue;
    }
    sink.set_record_index(record++);
    sink.set_byte_offset(int64_t(off + 28 + 8 * i));
    bool go;
    if (ts < 0 || ph.ts_overflow < 0)
      go = sink.bad_time([&] {
        return "timestamp " + std::to_string(ts) + " with overflow " + std::to_string(ph.ts_overflow) +
               " is negative (AEDAT 3.1 times are overflow << 31 | a 31-bit timestamp)";
      });
    else
      go = sink.add((int64_t(ph.ts_overflow) << 31) | ts, (data >> 17) & 0x7FFF, (data >> 2) & 0x7FFF, (data >> 1) & 1);
    if (!go) {
      record += n - 1 - i;  // the rest of the packet is not decoded; a resumed read starts at a packet
      return false;
    }
  }
  return true;
}

// "" when the header's fields agree with each other, else what is wrong.
std::string packet_header_problem(const PacketHeader& ph) {
  if (ph.size <= 0 || ph.capacity < 0 || ph.number < 0 || ph.valid < 0)
    return "event size " + std::to_string(ph.size) + ", capacity " + std::to_string(ph.capacity) + ", number " +
           std::to_string(ph.number) + ", valid " + std::to_string(ph.valid) + " (expected size > 0, counts >= 0)";
  if (ph.number > ph.capacity || ph.valid > ph.number)
    return "eventNumber " + std::to_string(ph.number) + " / eventValid " + std::to_string(ph.valid) +
           " exceed eventCapacity " + std::to_string(ph.capacity) + " (expected valid <= number <= capacity)";
  if (ph.ts_offset < 0 || ph.ts_offset > ph.size - 4)
    return "eventTSOffset " + std::to_string(ph.ts_offset) + " does not fit an event of " + std::to_string(ph.size) + " bytes";
  if (ph.type == 1 && (ph.size != 8 || ph.ts_offset != 4))
    return "polarity packet with eventSize " + std::to_string(ph.size) + " and eventTSOffset " +
           std::to_string(ph.ts_offset) + " (expected 8 and 4)";
  if (uint64_t(ph.capacity) * uint64_t(ph.size) > kMaxPacket) return "packet larger than 256 MiB";
  return "";
}

PacketHeader decode_packet_header(const uint8_t* b) {
  PacketHeader ph;
  ph.type = int16_t(b[0] | (b[1] << 8));
  ph.source = int16_t(b[2] | (b[3] << 8));
  ph.size = le32s(b + 4), ph.ts_offset = le32s(b + 8), ph.ts_overflow = le32s(b + 12);
  ph.capacity = le32s(b + 16), ph.number = le32s(b + 20), ph.valid = le32s(b + 24);
  return ph;
}

// One packet at `off`: its events into the sink or counted. Returns the offset after it, or 0 when
// the packet chain ends here (a truncated or corrupt packet, reported) or the sink says stop.
uint64_t read_packet(ByteSource& src, EventSink& sink, const Aedat3Header& h, uint64_t off, uint64_t& record,
                     std::vector<uint8_t>& buf) {
  const uint64_t size = src.size();
  uint8_t b[28];
  const size_t got = src.read_at(off, b, 28);
  auto stop = [&](const std::string& why) {
    sink.set_record_index(record++);
    sink.set_byte_offset(int64_t(off));
    sink.unknown_record(why);
    return uint64_t(0);
  };
  if (got < 28)
    return stop("the file ends inside a 28-byte packet header (" + std::to_string(got) + " bytes; truncated AEDAT 3.1 file)");
  const PacketHeader ph = decode_packet_header(b);
  if (const std::string why = packet_header_problem(ph); !why.empty())
    return stop("corrupt AEDAT 3.1 packet header (type " + std::to_string(ph.type) + "): " + why);
  const uint64_t payload = uint64_t(ph.capacity) * uint64_t(ph.size);
  const uint64_t avail = std::min<uint64_t>(payload, size - off - 28);
  const char* kind = packet_kind(ph.type);
  if (ph.type != 1 || (h.source >= 0 && ph.source != h.source)) {
    const std::string what = kind ? std::string(kind) + " events" : "events of packet type " + std::to_string(ph.type);
    sink.ignored(ph.type == 1 ? what + " of source " + std::to_string(ph.source) : what, uint64_t(ph.number));
  } else {
    buf.resize(size_t(avail));
    if (avail && src.read_at(off + 28, buf.data(), buf.size()) != buf.size())
      throw IoError(src.name() + ": read error in the packet at byte " + std::to_string(off));
    if (!polarity_packet(ph, buf.data(), avail, off, record, sink)) return 0;
  }
  if (avail < payload)
    return stop("packet of " + std::to_string(payload) + " bytes (" + std::to_string(ph.capacity) + " x " +
                std::to_string(ph.size) + ") runs past the end of the file: " + std::to_string(payload - avail) +
                " bytes missing (truncated AEDAT 3.1 file)");
  return off + 28 + payload;
}

}  // namespace

void read_aedat3(ByteSource& src, EventSink& sink) {
  const Aedat3Header h = parse_aedat3_header(src);
  if (h.width > 0) sink.set_file_geometry(h.width, h.height, "the AEDAT 3.1 header line '#Source " +
                                                                 std::to_string(h.source) + ": " + h.source_name + "'");
  sink.note("AEDAT 3.1 packets start at byte " + std::to_string(h.data_offset) +
            (h.source >= 0 ? "; polarity events of source " + std::to_string(h.source) + " are read"
                           : "; no '#Source' line: polarity events of every source are read"));
  uint64_t record = 0;
  uint64_t off = packet_start(sink, h.data_offset, record);
  auto checkpoint = [&](uint64_t offset) { return packet_checkpoint(offset, record); };
  uint64_t next = off;  // a checkpoint at the first packet, then every ~32 KiB of packets
  std::vector<uint8_t> buf;
  const uint64_t size = src.size();
  while (off < size && !sink.done()) {
    if (off >= next) {
      if (!sink.boundary(checkpoint(off))) return;
      next = sink.next_checkpoint(off, h.data_offset);
    }
    const uint64_t after = read_packet(src, sink, h, off, record, buf);
    if (after == 0) {
      if (sink.done()) return;
      off = size;  // the packet chain cannot be followed past a bad or cut packet
      break;
    }
    off = after;
  }
  if (!sink.done()) sink.end_of_data(checkpoint(off));
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
