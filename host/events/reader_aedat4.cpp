// iniVation AEDAT 4.0: "#!AER-DAT4.0\r\n", an int32 header size, an IOHeader flatbuffer (compression,
// data-table position, XML info naming each stream's type), then packets (int32 stream id, int32
// size, LZ4-frame or zstd compressed size-prefixed flatbuffers). Event packets ("EVTS") hold
// 16-byte structs {int64 t, int16 x, int16 y, bool polarity}. IMU, trigger and frame streams are
// counted and skipped. A time window uses the file's data table (packet time ranges) to skip
// packets without decompressing them. Flatbuffers are read with explicit bounds checks.
#include <lz4frame.h>
#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <map>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr uint64_t kMaxPacket = uint64_t(256) << 20;  // decompressed bytes per packet (guards hostile input)

// A bounds-checked view of one flatbuffer.
class FlatView {
 public:
  FlatView(const uint8_t* data, size_t size, std::string what) : d_(data), n_(size), what_(std::move(what)) {}

  template <class T>
  T scalar(uint64_t pos) const {
    check(pos, sizeof(T));
    T v;
    std::memcpy(&v, d_ + pos, sizeof(T));
    return v;
  }
  uint64_t root(uint64_t base = 0) const { return base + scalar<uint32_t>(base); }
  // Position of field `index` of the table at `table`, or 0 when absent.
  uint64_t field(uint64_t table, int index) const {
    const int64_t vt = int64_t(table) - int64_t(scalar<int32_t>(table));
    if (vt < 0) fail("vtable before the buffer");
    const uint16_t vt_size = scalar<uint16_t>(uint64_t(vt));
    const uint64_t slot = uint64_t(4 + 2 * index);
    if (slot + 2 > vt_size) return 0;
    const uint16_t off = scalar<uint16_t>(uint64_t(vt) + slot);
    return off ? table + off : 0;
  }
  uint64_t deref(uint64_t pos) const { return pos + scalar<uint32_t>(pos); }
  // Vector at an offset field: (first element position, length); checks elem bytes fit.
  std::pair<uint64_t, uint64_t> vec(uint64_t field_pos, uint64_t elem_size) const {
    const uint64_t v = deref(field_pos);
    const uint64_t len = scalar<uint32_t>(v);
    if (len && elem_size) check(v + 4, len * elem_size);
    return {v + 4, len};
  }
  std::string str(uint64_t field_pos) const {
    const auto [p, len] = vec(field_pos, 1);
    return std::string(reinterpret_cast<const char*>(d_ + p), size_t(len));
  }
  const uint8_t* data() const { return d_; }
  size_t size() const { return n_; }
  void check(uint64_t pos, uint64_t len) const {
    if (pos > n_ || len > n_ - pos) fail("offset " + std::to_string(pos) + "+" + std::to_string(len) + " outside " +
                                         std::to_string(n_) + " bytes");
  }
  [[noreturn]] void fail(const std::string& why) const { throw DataError(what_ + ": corrupt flatbuffer (" + why + ")"); }

 private:
  const uint8_t* d_;
  size_t n_;
  std::string what_;
};

struct StreamInfo {
  std::string type;  // "EVTS", "IMUS", "TRIG", "FRME", ...
  std::string name;
  int width = 0, height = 0;
};

std::string attr(const std::string& xml, const std::string& key) {
  const std::string k = "key=\"" + key + "\"";
  const size_t a = xml.find(k);
  if (a == std::string::npos) return {};
  const size_t gt = xml.find('>', a);
  const size_t lt = gt == std::string::npos ? gt : xml.find('<', gt);
  if (lt == std::string::npos) return {};
  return xml.substr(gt + 1, lt - gt - 1);
}

int to_int(const std::string& s) {
  int v = 0;
  for (char c : s) {
    if (c < '0' || c > '9' || v > 1000000) return 0;
    v = v * 10 + (c - '0');
  }
  return v;
}

// Streams declared in the info XML: <node name="ID" path=".../outInfo/ID/"> ... </node>.
std::map<int, StreamInfo> parse_streams(const std::string& xml) {
  std::map<int, StreamInfo> out;
  std::vector<std::pair<size_t, int>> starts;
  size_t pos = 0;
  while ((pos = xml.find("outInfo/", pos)) != std::string::npos) {
    pos += 8;
    size_t e = pos;
    while (e < xml.size() && xml[e] >= '0' && xml[e] <= '9') ++e;
    if (e > pos && e + 1 < xml.size() && xml[e] == '/' && xml[e + 1] == '"' && e - pos < 9)
      starts.emplace_back(pos, std::stoi(xml.substr(pos, e - pos)));
  }
  for (size_t i = 0; i < starts.size(); ++i) {
    const size_t end = i + 1 < starts.size() ? starts[i + 1].first : xml.size();
    const std::string sec = xml.substr(starts[i].first, end - starts[i].first);
    StreamInfo s;
    s.type = attr(sec, "typeIdentifier");
    s.name = attr(sec, "originalOutputName");
    s.width = to_int(attr(sec, "sizeX"));
    s.height = to_int(attr(sec, "sizeY"));
    if (!out.count(starts[i].second) || out[starts[i].second].type.empty()) out[starts[i].second] = s;
  }
  return out;
}

void decompress(int compression, const std::vector<uint8_t>& in, std::vector<uint8_t>& out, const std::string& where) {
  out.clear();
  if (compression == 0) {
    out = in;
    return;
  }
  if (compression == 1 || compression == 2) {
    LZ4F_dctx* dctx = nullptr;
    if (LZ4F_isError(LZ4F_createDecompressionContext(&dctx, LZ4F_VERSION))) throw InternalError(where + ": LZ4 context");
    struct Free {
      LZ4F_dctx* d;
      ~Free() { LZ4F_freeDecompressionContext(d); }
    } free_ctx{dctx};
    size_t in_pos = 0;
    out.resize(std::max<size_t>(in.size() * 4, 4096));
    size_t out_pos = 0;
    for (;;) {
      size_t src = in.size() - in_pos, dst = out.size() - out_pos;
      const size_t r = LZ4F_decompress(dctx, out.data() + out_pos, &dst, in.data() + in_pos, &src, nullptr);
      if (LZ4F_isError(r)) throw DataError(where + ": LZ4 decompression failed (" + LZ4F_getErrorName(r) + ")");
      in_pos += src;
      out_pos += dst;
      if (r == 0) break;  // frame complete
      if (in_pos >= in.size() && dst == 0) throw DataError(where + ": LZ4 frame is truncated");
      if (out.size() - out_pos < 65536) {
        if (out.size() >= kMaxPacket) throw DataError(where + ": packet decompresses to more than 256 MiB");
        out.resize(std::min<size_t>(out.size() * 2, kMaxPacket));
      }
    }
    out.resize(out_pos);
    return;
  }
  if (compression == 3 || compression == 4) {
    ZSTD_DStream* ds = ZSTD_createDStream();
    struct Free {
      ZSTD_DStream* d;
      ~Free() { ZSTD_freeDStream(d); }
    } free_ds{ds};
    ZSTD_initDStream(ds);
    ZSTD_inBuffer ib{in.data(), in.size(), 0};
    out.resize(std::max<size_t>(in.size() * 4, 4096));
    size_t out_pos = 0;
    for (;;) {
      ZSTD_outBuffer ob{out.data() + out_pos, out.size() - out_pos, 0};
      const size_t r = ZSTD_decompressStream(ds, &ob, &ib);
      if (ZSTD_isError(r)) throw DataError(where + ": zstd decompression failed (" + ZSTD_getErrorName(r) + ")");
      out_pos += ob.pos;
      if (r == 0) break;
      if (ib.pos >= ib.size && ob.pos < ob.size) throw DataError(where + ": zstd frame is truncated");
      if (out.size() - out_pos < 65536) {
        if (out.size() >= kMaxPacket) throw DataError(where + ": packet decompresses to more than 256 MiB");
        out.resize(std::min<size_t>(out.size() * 2, kMaxPacket));
      }
    }
    out.resize(out_pos);
    return;
  }
  throw DataError(where + ": unknown compression type " + std::to_string(compression) +
              " (expected 0 none, 1/2 LZ4, 3/4 zstd)");
}

struct TableEntry {
  int64_t offset = 0, t_begin = 0, t_end = 0;
  int32_t stream = 0;
};

struct AedatHeader {
  int32_t compression = 0;
  int64_t table_pos = -1;
  std::map<int, StreamInfo> streams;
  int event_stream = -1;
  uint64_t data_begin = 0, data_end = 0;
};

AedatHeader parse_aedat_header(ByteSource& src, EventSink& sink) {
  const std::string& file = src.name();
  const auto magic = read_range(src, 0, 18);
  if (magic.size() < 18 || std::memcmp(magic.data(), "#!AER-DAT4.0\r\n", 14) != 0)
    throw DataError(file + ": not an AEDAT 4.0 file (missing '#!AER-DAT4.0' at the start)");
  uint32_t hsize;
  std::memcpy(&hsize, magic.data() + 14, 4);
  if (hsize > (16u << 20) || 18 + uint64_t(hsize) > src.size())
    throw DataError(file + ": AEDAT 4 header size " + std::to_string(hsize) + " does not fit the file (truncated?)");
  const auto hbuf = read_range(src, 18, hsize);
  FlatView hv(hbuf.data(), hbuf.size(), file + ": IOHeader");
  const uint64_t root = hv.root();
  AedatHeader h;
  std::string xml;
  if (uint64_t f = hv.field(root, 0)) h.compression = hv.scalar<int32_t>(f);
  if (uint64_t f = hv.field(root, 1)) h.table_pos = hv.scalar<int64_t>(f);
  if (uint64_t f = hv.field(root, 2)) xml = hv.str(f);
  if (h.compression < 0 || h.compression > 4)
    throw DataError(file + ": AEDAT 4 compression type " + std::to_string(h.compression) + " is unknown");
  static const char* kCompression[] = {"none", "LZ4", "LZ4 high", "zstd", "zstd high"};
  h.streams = parse_streams(xml);
  for (const auto& [id, s] : h.streams)
    if (s.type == "EVTS") {
      if (h.event_stream < 0) h.event_stream = id;
      else sink.note("more than one event stream; reading stream " + std::to_string(h.event_stream) +
                     ", counting stream " + std::to_string(id) + " as ignored");
    }
  if (h.event_stream < 0)
    throw DataError(file + ": the AEDAT 4 info declares no polarity event stream (typeIdentifier EVTS)");
  const StreamInfo& es = h.streams.at(h.event_stream);
  sink.set_file_geometry(es.width, es.height, "the AEDAT 4 info (sizeX/sizeY of stream '" + es.name + "')");
  sink.note("AEDAT 4: compression " + std::string(kCompression[h.compression]) + ", event stream " +
            std::to_string(h.event_stream) + " ('" + es.name + "') of " + std::to_string(h.streams.size()) + " streams");
  h.data_begin = 18 + uint64_t(hsize);
  h.data_end = (h.table_pos > int64_t(h.data_begin) && uint64_t(h.table_pos) <= src.size()) ? uint64_t(h.table_pos)
                                                                                           : src.size();
  return h;
}

// Packet time ranges from the data table (one-off window reads skip packets without decompressing
// them); empty when the table is absent or unusable (a note says so).
std::map<int64_t, TableEntry> read_data_table(ByteSource& src, EventSink& sink, const AedatHeader& h) {
  std::map<int64_t, TableEntry> table;
  if (h.table_pos <= 0 || uint64_t(h.table_pos) >= src.size()) return table;
  const std::string& file = src.name();
  try {
    std::vector<uint8_t> out;
    const auto in = read_range(src, uint64_t(h.table_pos),
                               size_t(std::min<uint64_t>(src.size() - uint64_t(h.table_pos), kMaxPacket)));
    decompress(h.compression, in, out, file + ": data table");
    FlatView tv(out.data(), out.size(), file + ": data table");
    const uint64_t troot = tv.root(4);  // size-prefixed
    if (uint64_t f = tv.field(troot, 0)) {
      const auto [first, len] = tv.vec(f, 4);
      for (uint64_t i = 0; i < len; ++i) {
        const uint64_t e = tv.deref(first + 4 * i);
        TableEntry te;
        if (uint64_t g = tv.field(e, 0)) te.offset = tv.scalar<int64_t>(g);
        if (uint64_t g = tv.field(e, 1)) te.stream = tv.scalar<int32_t>(g);
        if (uint64_t g = tv.field(e, 3)) te.t_begin = tv.scalar<int64_t>(g);
        if (uint64_t g = tv.field(e, 4)) te.t_end = tv.scalar<int64_t>(g);
        table[te.offset] = te;
      }
    }
    sink.note("data table: " + std::to_string(table.size()) + " packets indexed");
  } catch (const Error& e) {
    table.clear();
    sink.note(std::string("data table unusable, reading every packet (") + e.what() + ")");
  }
  return table;
}

// One packet's payload (decompressed into `out`): its events into the sink, or its elements
// counted as ignored. False when the sink says stop.
bool read_packet(ByteSource& src, EventSink& sink, const AedatHeader& h, uint64_t off, int32_t stream, int32_t size,
                 const StreamInfo& info, uint64_t& record, std::vector<uint8_t>& in, std::vector<uint8_t>& out) {
  const std::string where = src.name() + ": packet at byte " + std::to_string(off);
  if (stream != h.event_stream && info.type == "FRME") {
    sink.ignored("FRME packets");
    return true;
  }
  in.resize(size_t(size));
  if (src.read_at(off + 8, in.data(), in.size()) != in.size()) throw IoError(where + ": read error");
  decompress(h.compression, in, out, where);
  FlatView pv(out.data(), out.size(), where);
  pv.check(0, 8);
  const uint32_t prefixed = pv.scalar<uint32_t>(0);
  if (uint64_t(prefixed) + 4 > out.size()) pv.fail("size prefix larger than the packet");
  const uint64_t proot = pv.root(4);
  const uint64_t elements = pv.field(proot, 0);
  if (stream != h.event_stream) {
    uint64_t n = 0;
    if (elements) n = pv.scalar<uint32_t>(pv.deref(elements));
    sink.ignored(info.type + " elements (stream '" + info.name + "')", n);
    return true;
  }
  pv.check(8, 4);  // the file identifier after the size prefix and root offset
  if (std::memcmp(out.data() + 8, "EVTS", 4) != 0) pv.fail("event packet without the EVTS identifier");
  if (!elements) return true;
  const auto [first, n] = pv.vec(elements, 16);
  const uint8_t* e = out.data() + first;
  for (uint64_t i = 0; i < n; ++i, e += 16) {
    int64_t t;
    int16_t x, y;
    std::memcpy(&t, e, 8);
    std::memcpy(&x, e + 8, 2);
    std::memcpy(&y, e + 10, 2);
    sink.set_record_index(record++);
    sink.set_byte_offset(int64_t(off));
    if (!sink.add(t, x, y, e[12])) {
      record += n - 1 - i;  // the rest of the packet is not decoded; a resumed read starts at a packet
      return false;
    }
  }
  return true;
}

}  // namespace

void read_aedat4(ByteSource& src, EventSink& sink) {
  const AedatHeader h = parse_aedat_header(src, sink);
  const EventReadOptions& o = sink.options();
  std::map<int64_t, TableEntry> table;
  if ((o.t_begin_us || o.t_end_us) && o.on_bad != BadEventPolicy::sort && !sink.indexing())
    table = read_data_table(src, sink, h);
  uint64_t record = 0;
  uint64_t off = packet_start(sink, h.data_begin, record);
  auto checkpoint = [&](uint64_t offset) { return packet_checkpoint(offset, record); };
  uint64_t next = off;  // a checkpoint at the first packet, then every ~32 KiB of packets
  std::vector<uint8_t> in, out;
  while (off < h.data_end && !sink.done()) {
    if (off >= next) {
      if (!sink.boundary(checkpoint(off))) return;
      next = sink.next_checkpoint(off, h.data_begin);
    }
    uint8_t ph[8];
    if (src.read_at(off, ph, 8) < 8 || off + 8 > h.data_end) {
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record("the file ends inside a packet header (truncated AEDAT 4 file)");
      off = h.data_end;
      break;
    }
    int32_t stream, size;
    std::memcpy(&stream, ph, 4);
    std::memcpy(&size, ph + 4, 4);
    if (size <= 0 || off + 8 + uint64_t(size) > h.data_end) {
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      if (size > 0 && off + 8 + uint64_t(size) > h.data_end)
        sink.unknown_record("packet of " + std::to_string(size) + " bytes runs past the end of the data (truncated AEDAT 4 file)");
      else
        sink.unknown_record("packet size " + std::to_string(size) + " is invalid (corrupt AEDAT 4 file)");
      off = h.data_end;
      break;  // the packet chain cannot be followed past a bad size
    }
    const uint64_t packet_end = off + 8 + uint64_t(size);
    const auto it = h.streams.find(stream);
    if (it == h.streams.end()) {
      sink.set_record_index(record++);
      sink.set_byte_offset(int64_t(off));
      sink.unknown_record("packet of stream " + std::to_string(stream) + " that the file's info does not declare");
      off = packet_end;
      continue;
    }
    if (!table.empty()) {
      // The table's ByteOffset is that of the packet's payload, after the 8-byte packet header.
      const auto te = table.find(int64_t(off + 8));
      if (te != table.end() && te->second.stream == stream) {
        const bool before = o.t_begin_us && te->second.t_end < *o.t_begin_us;
        const bool after = o.t_end_us && te->second.t_begin >= *o.t_end_us;
        if (before || after) {
          sink.report().stopped_early = true;
          if (after && stream == h.event_stream) break;
          off = packet_end;
          continue;
        }
      }
    }
    if (!read_packet(src, sink, h, off, stream, size, it->second, record, in, out)) return;
    off = packet_end;
  }
  if (!sink.done()) sink.end_of_data(checkpoint(off));
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
