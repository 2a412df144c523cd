// The ROS 1 bag 2.0 container (rosbag_detail.hpp): "#ROSBAG V2.0\n", then records, each
// `uint32 header_len, header, uint32 data_len, data`; the header is `uint32 len, name=value`
// fields with a one-byte `op`. Ops: 0x03 bag header, 0x05 chunk (compressed connection and
// message records), 0x04 index data, 0x07 connection, 0x02 message data, 0x06 chunk info.
// Read chunk by chunk: memory is one chunk's compressed and decompressed bytes.
#include <bzlib.h>
#include <lz4frame.h>

#include <cstring>
#include <memory>

#include "vkunroll/host/events/rosbag_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr char kMagic[] = "#ROSBAG V2.0\n";
constexpr size_t kMagicSize = 13;
constexpr uint32_t kMaxHeader = 16u << 20;     // a record header (message definitions are text)
constexpr uint64_t kMaxChunk = uint64_t(256) << 20;  // compressed or decompressed chunk bytes

enum Op : uint8_t { kMessage = 0x02, kBagHeader = 0x03, kIndexData = 0x04, kChunk = 0x05, kChunkInfo = 0x06, kConnection = 0x07 };

inline uint32_t le32(const uint8_t* p) {
  return uint32_t(p[0]) | (uint32_t(p[1]) << 8) | (uint32_t(p[2]) << 16) | (uint32_t(p[3]) << 24);
}
inline uint64_t le64(const uint8_t* p) { return uint64_t(le32(p)) | (uint64_t(le32(p + 4)) << 32); }

// A record header's fields (values are bytes: integers little-endian).
struct Fields {
  std::map<std::string, std::string> f;
  bool has(const char* k) const { return f.count(k) != 0; }
  // The field as an unsigned integer of `bytes` bytes; throws Error naming the record when it is
  // missing or of another size.
  uint64_t uint(const char* k, size_t bytes, const std::string& where) const {
    const auto it = f.find(k);
    if (it == f.end() || it->second.size() != bytes)
      throw DataError(where + ": field '" + k + "' is missing or not " + std::to_string(bytes) + " bytes");
    const auto* p = reinterpret_cast<const uint8_t*>(it->second.data());
    return bytes == 1 ? p[0] : bytes == 4 ? le32(p) : le64(p);
  }
  std::string str(const char* k) const {
    const auto it = f.find(k);
    return it == f.end() ? std::string() : it->second;
  }
};

// Parses `n` bytes of `uint32 len, name=value` fields; false (with `err`) when they do not fit.
bool parse_fields(const uint8_t* p, size_t n, Fields& out, std::string& err) {
  size_t at = 0;
  while (at < n) {
    if (n - at < 4) return err = "a field length is cut short", false;
    const uint32_t len = le32(p + at);
    at += 4;
    if (len > n - at) return err = "a field of " + std::to_string(len) + " bytes runs past the header", false;
    const auto* b = reinterpret_cast<const char*>(p + at);
    const auto* eq = static_cast<const char*>(std::memchr(b, '=', len));
    if (!eq) return err = "a field without '='", false;
    out.f[std::string(b, size_t(eq - b))] = std::string(eq + 1, size_t(b + len - eq - 1));
    at += len;
  }
  return true;
}

// One record's layout in a byte range (the file, or a decompressed chunk).
struct RecordView {
  Fields fields;
  uint8_t op = 0;
  uint64_t data_at = 0, data_len = 0;  // where the data starts, its length as the record says
  uint64_t end = 0;                    // the next record
};

// Reads the record at `off` of a span of `size` bytes through `read` (offset, n -> bytes).
// Returns "" or why it cannot: "truncated: ..." when the span ends inside it.
template <class Read>
std::string read_record(uint64_t off, uint64_t size, Read&& read, RecordView& r, bool want_truncated_data) {
  uint8_t b4[4];
  if (size - off < 4) return "truncated: the record's header length is cut short";
  read(off, b4, 4);
  const uint32_t hl = le32(b4);
  if (hl > kMaxHeader) return "a record header of " + std::to_string(hl) + " bytes (more than 16 MiB: not a record)";
  if (size - off - 4 < hl) return "truncated: the record header (" + std::to_string(hl) + " bytes) is cut short";
  std::vector<uint8_t> h(hl);
  read(off + 4, h.data(), hl);
  std::string err;
  if (!parse_fields(h.data(), hl, r.fields, err)) return "corrupt record header: " + err;
  const auto op = r.fields.f.find("op");
  if (op == r.fields.f.end() || op->second.size() != 1) return "a record header without a one-byte 'op' field";
  r.op = uint8_t(op->second[0]);
  if (size - off - 4 - hl < 4) return "truncated: the record's data length is cut short";
  read(off + 4 + hl, b4, 4);
  r.data_len = le32(b4);
  r.data_at = off + 8 + hl;
  r.end = r.data_at + r.data_len;
  if (r.end > size && !(want_truncated_data && r.op == kChunk))
    return "truncated: the record's data (" + std::to_string(r.data_len) + " bytes) runs past the end";
  return "";
}

std::string hex_op(uint8_t op) {
  static const char* d = "0123456789abcdef";
  return std::string("0x") + d[op >> 4] + d[op & 15];
}

BagConnection connection_of(const RecordView& r, const uint8_t* data, size_t n, const std::string& where) {
  BagConnection c;
  c.id = uint32_t(r.fields.uint("conn", 4, where));
  c.topic = r.fields.str("topic");
  Fields inner;
  std::string err;
  if (!parse_fields(data, n, inner, err)) throw DataError(where + ": corrupt connection header: " + err);
  c.type = inner.str("type");
  c.md5sum = inner.str("md5sum");
  c.definition = inner.str("message_definition");
  if (c.topic.empty()) c.topic = inner.str("topic");
  return c;
}

// The output buffer of a decompressor: grown as the data needs (a hostile `size` field allocates
// nothing it does not fill), never past `size`.
bool grow(std::vector<uint8_t>& out, size_t used, uint64_t size) {
  if (used < out.size()) return true;
  if (out.size() >= size) return false;
  out.resize(size_t(std::min<uint64_t>(size, std::max<size_t>(out.size() * 2, size_t(1) << 16))));
  return true;
}

std::vector<uint8_t> inflate_bz2(const std::vector<uint8_t>& in, uint64_t size, std::string& why) {
  std::vector<uint8_t> out;
  bz_stream z{};
  if (BZ2_bzDecompressInit(&z, 0, 0) != BZ_OK) throw InternalError("bz2: cannot initialise the decompressor");
  z.next_in = reinterpret_cast<char*>(const_cast<uint8_t*>(in.data()));
  z.avail_in = unsigned(in.size());
  size_t used = 0;
  int rc = BZ_OK;
  // Also with all input taken: a full output buffer may leave output inside the decompressor.
  while (rc == BZ_OK && (z.avail_in > 0 || used == out.size()) && grow(out, used, size)) {
    z.next_out = reinterpret_cast<char*>(out.data() + used);
    z.avail_out = unsigned(out.size() - used);
    rc = BZ2_bzDecompress(&z);
    used = out.size() - z.avail_out;
  }
  if (rc != BZ_OK && rc != BZ_STREAM_END) why = "bz2 data error " + std::to_string(rc);
  BZ2_bzDecompressEnd(&z);
  out.resize(used);
  return out;
}

std::vector<uint8_t> inflate_lz4(const std::vector<uint8_t>& in, uint64_t size, std::string& why) {
  std::vector<uint8_t> out;
  LZ4F_dctx* ctx = nullptr;
  if (LZ4F_isError(LZ4F_createDecompressionContext(&ctx, LZ4F_VERSION))) throw InternalError("lz4: cannot create a context");
  std::unique_ptr<LZ4F_dctx, decltype(&LZ4F_freeDecompressionContext)> guard(ctx, LZ4F_freeDecompressionContext);
  size_t in_at = 0, used = 0;
  while ((in_at < in.size() || used == out.size()) && grow(out, used, size)) {
    size_t in_n = in.size() - in_at, out_n = out.size() - used;
    const size_t rc = LZ4F_decompress(ctx, out.data() + used, &out_n, in.data() + in_at, &in_n, nullptr);
    if (LZ4F_isError(rc)) {
      why = std::string("lz4 frame error: ") + LZ4F_getErrorName(rc);
      break;
    }
    in_at += in_n, used += out_n;
    if (rc == 0 || (in_n == 0 && out_n == 0)) break;
  }
  out.resize(used);
  return out;
}

// Decompresses a chunk's data (maybe cut short: then the decompressed prefix). `why` says what went
// wrong when the output is not `size` bytes.
std::vector<uint8_t> decompress_chunk(const std::string& method, const std::vector<uint8_t>& in, uint64_t size,
                                      std::string& why) {
  std::vector<uint8_t> out;
  if (method == "none") out = in;
  else if (method == "bz2") out = inflate_bz2(in, size, why);
  else if (method == "lz4") out = inflate_lz4(in, size, why);
  else why = "unknown chunk compression '" + method + "' (expected none, bz2 or lz4)";
  if (why.empty() && out.size() != size)
    why = "the chunk decompresses to " + std::to_string(out.size()) + " bytes, its header says " + std::to_string(size);
  return out;
}

// The records of one decompressed chunk. `cut` says the chunk's bytes end early (file cut short):
// then a record cut short at the end is that truncation, not a second damage.
bool visit_chunk(const std::vector<uint8_t>& d, uint64_t chunk_off, bool cut, const std::string& name, BagVisitor& v) {
  uint64_t at = 0;
  auto read = [&](uint64_t o, void* dst, size_t n) {
    if (n) std::memcpy(dst, d.data() + o, n);  // an empty header has no buffer
  };
  while (at < d.size()) {
    RecordView r;
    const std::string err = read_record(at, d.size(), read, r, false);
    const std::string where = name + ": chunk at byte " + std::to_string(chunk_off) + ", its byte " + std::to_string(at);
    if (!err.empty()) {
      if (!cut) v.damaged(chunk_off, "chunk at byte " + std::to_string(chunk_off) + ": record at its byte " +
                                         std::to_string(at) + ": " + err + " (corrupt chunk)");
      return true;
    }
    if (r.op == kConnection) {
      v.connection(connection_of(r, d.data() + r.data_at, size_t(r.data_len), where));
    } else if (r.op == kMessage) {
      const uint32_t conn = uint32_t(r.fields.uint("conn", 4, where));
      const uint64_t t = r.fields.uint("time", 8, where);
      const uint64_t ns = uint64_t(uint32_t(t)) * 1000000000ull + (t >> 32);
      if (!v.message(conn, ns, d.data() + r.data_at, size_t(r.data_len), chunk_off)) return false;
    } else {
      v.damaged(chunk_off, "chunk at byte " + std::to_string(chunk_off) + ": record op " + hex_op(r.op) +
                               " inside a chunk (only connections and messages belong there)");
    }
    at = r.end;
  }
  return true;
}

// One chunk record: read its (maybe cut short) data, decompress, visit. False: the visitor stopped.
bool visit_chunk_record(ByteSource& src, uint64_t off, const RecordView& r, BagVisitor& v) {
  const std::string where = src.name() + ": chunk at byte " + std::to_string(off);
  const std::string method = r.fields.str("compression");
  const uint64_t size = r.fields.uint("size", 4, where);
  if (size > kMaxChunk || r.data_len > kMaxChunk)
    throw DataError(where + ": a chunk of " + std::to_string(std::max<uint64_t>(size, r.data_len)) +
                " bytes (more than 256 MiB)");
  const uint64_t have = std::min<uint64_t>(r.data_len, src.size() - std::min(src.size(), r.data_at));
  std::vector<uint8_t> in(static_cast<size_t>(have));
  if (have) in.resize(src.read_at(r.data_at, in.data(), size_t(have)));
  const bool cut = have < r.data_len;
  std::string why;
  const std::vector<uint8_t> d = decompress_chunk(method, in, size, why);
  if (!visit_chunk(d, off, cut || !why.empty(), src.name(), v)) return false;
  if (cut)
    v.damaged(off, "the file ends inside the chunk at byte " + std::to_string(off) + " (" + std::to_string(have) +
                       " of its " + std::to_string(r.data_len) + " bytes; the bag is cut short)");
  else if (!why.empty())
    v.damaged(off, "chunk at byte " + std::to_string(off) + " (" + method + "): " + why);
  return true;
}

}  // namespace

void RosCursor::need(size_t k) const {
  if (k > n - at) throw DataError(*what + ": the message ends early (" + std::to_string(k) + " bytes needed at its byte " +
                              std::to_string(at) + " of " + std::to_string(n) + ")");
}
uint16_t RosCursor::u16() {
  need(2);
  const uint16_t v = uint16_t(p[at] | (p[at + 1] << 8));
  at += 2;
  return v;
}
uint32_t RosCursor::u32() {
  need(4);
  const uint32_t v = le32(p + at);
  at += 4;
  return v;
}
uint64_t RosCursor::u64() {
  need(8);
  const uint64_t v = le64(p + at);
  at += 8;
  return v;
}
std::string RosCursor::string() {
  const uint32_t len = u32();
  need(len);
  std::string s(reinterpret_cast<const char*>(p + at), len);
  at += len;
  return s;
}

void scan_bag_records(ByteSource& src, uint64_t offset, BagVisitor& v) {
  const uint64_t size = src.size();
  auto read = [&](uint64_t o, void* dst, size_t n) {
    if (src.read_at(o, dst, n) != n) throw IoError(src.name() + ": read error at byte " + std::to_string(o));
  };
  for (uint64_t off = offset; off < size;) {
    if (!v.top_record(off)) return;
    RecordView r;
    const std::string err = read_record(off, size, read, r, true);
    if (err.rfind("truncated: ", 0) == 0) {
      v.damaged(off, "record at byte " + std::to_string(off) + ": " + err.substr(11) + " (the bag is cut short)");
      return;
    }
    if (!err.empty()) throw DataError(src.name() + ": record at byte " + std::to_string(off) + ": " + err);
    const std::string where = src.name() + ": record at byte " + std::to_string(off);
    if (r.op == kChunk) {
      if (!visit_chunk_record(src, off, r, v)) return;
    } else if (r.op == kConnection) {
      const auto d = read_range(src, r.data_at, size_t(std::min<uint64_t>(r.data_len, kMaxHeader)));
      v.connection(connection_of(r, d.data(), d.size(), where));
    } else if (r.op == kMessage) {
      if (r.data_len > kMaxChunk) throw DataError(where + ": a message of more than 256 MiB");
      const auto d = read_range(src, r.data_at, size_t(r.data_len));
      const uint64_t t = r.fields.uint("time", 8, where);
      if (!v.message(uint32_t(r.fields.uint("conn", 4, where)), uint64_t(uint32_t(t)) * 1000000000ull + (t >> 32),
                     d.data(), d.size(), off))
        return;
    } else if (r.op != kIndexData && r.op != kChunkInfo && r.op != kBagHeader) {
      v.damaged(off, "record at byte " + std::to_string(off) + ": unknown record op " + hex_op(r.op));
    }
    off = r.end;
  }
}

namespace {

// Collects connections only (the pre-scan of a bag without an index; the index section).
struct ConnectionCollector final : BagVisitor {
  BagInfo& info;
  uint64_t stop_at = UINT64_MAX;  // the index section's scan stops at nothing; the pre-scan at index_pos
  bool damaged_seen = false;
  explicit ConnectionCollector(BagInfo& i) : info(i) {}
  bool top_record(uint64_t offset) override { return offset < stop_at; }
  void connection(const BagConnection& c) override { info.connections[c.id] = c; }
  bool message(uint32_t, uint64_t, const uint8_t*, size_t, uint64_t) override { return true; }
  void damaged(uint64_t, const std::string&) override { damaged_seen = true; }
};

}  // namespace

BagInfo read_bag_info(ByteSource& src) {
  const auto head = read_range(src, 0, kMagicSize);
  if (head.size() < kMagicSize || std::memcmp(head.data(), kMagic, kMagicSize) != 0) {
    if (head.size() >= 9 && std::memcmp(head.data(), "#ROSBAG V", 9) == 0) {
      std::string version(head.begin() + 9, head.end());  // up to the newline (a cut file may have none)
      version = version.substr(0, version.find('\n'));
      throw DataError(src.name() + ": ROS bag version '" + version +
                  "' is not supported (bag format 2.0 is; `rosbag fix` converts older bags)");
    }
    throw DataError(src.name() + ": not a ROS bag (no '#ROSBAG V2.0' line at byte 0)");
  }
  BagInfo info;
  RecordView r;
  auto read = [&](uint64_t o, void* dst, size_t n) { src.read_at(o, dst, n); };
  const std::string err = read_record(kMagicSize, src.size(), read, r, false);
  const std::string where = src.name() + ": bag header record at byte 13";
  if (!err.empty()) throw DataError(where + ": " + err);
  if (r.op != kBagHeader) throw DataError(where + ": op " + hex_op(r.op) + ", expected the bag header (0x03)");
  info.index_pos = r.fields.uint("index_pos", 8, where);
  info.chunk_count = uint32_t(r.fields.uint("chunk_count", 4, where));
  info.data_start = r.end;
  ConnectionCollector index(info);
  if (info.index_pos >= info.data_start && info.index_pos < src.size()) {
    try {
      scan_bag_records(src, info.index_pos, index);
      info.indexed = !index.damaged_seen;
    } catch (const Error&) {
      info.indexed = false;  // a damaged index section: the scan of the chunks below finds the connections
    }
  }
  if (!info.indexed) {
    info.connections.clear();
    ConnectionCollector scan(info);
    if (info.index_pos >= info.data_start) scan.stop_at = info.index_pos;
    scan_bag_records(src, info.data_start, scan);
    info.notes.push_back(
        std::string("the bag has no usable index (") +
        (info.index_pos == 0 ? "index_pos 0: its recorder did not close it" : "index_pos " + std::to_string(info.index_pos) +
                                                                                   " is past the end or damaged: cut short?") +
        "); its connections were found by a scan of every chunk");
  }
  return info;
}

}  // namespace vkunroll::detail
