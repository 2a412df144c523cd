// A ROS 1 bag 2.0 writer for the C++ tests and the fuzz seeds (the Python tests write bags with
// Debian's rosbag instead): magic, bag header padded to 4096 bytes, chunks of connection and
// message records (none, lz4 frame or bz2), an index data record after each chunk, and the index
// section (connections, chunk infos) whose position the header gives.
#pragma once
#include <bzlib.h>
#include <lz4frame.h>

#include <cstdint>
#include <string>
#include <vector>

#include "event_test_encoders.hpp"

namespace vkunroll::evtest {

enum class BagMessage { dvs_array, evt3_packet, mono_packet };

struct BagOptions {
  BagMessage kind = BagMessage::dvs_array;
  std::string compression = "none";  // none | lz4 | bz2
  size_t events_per_message = 100;
  size_t messages_per_chunk = 4;
  bool index = true;                 // false: index_pos 0 (a bag its recorder did not close)
  std::string md5;                   // empty: the type's known md5
};

namespace bagdetail {

inline void put64(std::vector<uint8_t>& b, uint64_t v) {
  put32(b, uint32_t(v));
  put32(b, uint32_t(v >> 32));
}
inline void field(std::vector<uint8_t>& h, const std::string& name, const std::vector<uint8_t>& value) {
  put32(h, uint32_t(name.size() + 1 + value.size()));
  h.insert(h.end(), name.begin(), name.end());
  h.push_back('=');
  h.insert(h.end(), value.begin(), value.end());
}
inline std::vector<uint8_t> u32v(uint32_t v) {
  std::vector<uint8_t> b;
  put32(b, v);
  return b;
}
inline std::vector<uint8_t> u64v(uint64_t v) {
  std::vector<uint8_t> b;
  put64(b, v);
  return b;
}
inline std::vector<uint8_t> sv(const std::string& s) { return std::vector<uint8_t>(s.begin(), s.end()); }
inline void record(std::vector<uint8_t>& out, const std::vector<uint8_t>& header, const std::vector<uint8_t>& data) {
  put32(out, uint32_t(header.size()));
  out.insert(out.end(), header.begin(), header.end());
  put32(out, uint32_t(data.size()));
  out.insert(out.end(), data.begin(), data.end());
}
inline void ros_time(std::vector<uint8_t>& b, int64_t t_us) {
  put32(b, uint32_t(t_us / 1000000));
  put32(b, uint32_t(t_us % 1000000 * 1000));
}
inline void ros_header(std::vector<uint8_t>& b, uint32_t seq, int64_t t_us) {
  put32(b, seq);
  ros_time(b, t_us);
  put32(b, 0);  // frame_id ""
}

// One message's serialized bytes for events [i, j).
inline std::vector<uint8_t> message(const EventStream& ev, size_t i, size_t j, uint32_t seq, BagMessage kind) {
  std::vector<uint8_t> b;
  ros_header(b, seq, i < j ? ev.t[i] : 0);
  put32(b, uint32_t(ev.height));
  put32(b, uint32_t(ev.width));
  if (kind == BagMessage::dvs_array) {
    put32(b, uint32_t(j - i));
    for (size_t k = i; k < j; ++k) {
      put16(b, ev.x[k]);
      put16(b, ev.y[k]);
      ros_time(b, ev.t[k]);
      b.push_back(ev.p[k] > 0 ? 1 : 0);
    }
    return b;
  }
  put64(b, seq);
  const bool mono = kind == BagMessage::mono_packet;
  const uint64_t base_ns = mono && i < j ? uint64_t(ev.t[i]) * 1000 : 0;
  put64(b, base_ns);
  const std::string enc = mono ? "mono" : "evt3";
  put32(b, uint32_t(enc.size()));
  b.insert(b.end(), enc.begin(), enc.end());
  b.push_back(0);
  std::vector<uint8_t> words;
  if (mono) {
    for (size_t k = i; k < j; ++k)
      put64(words, (uint64_t(ev.t[k]) * 1000 - base_ns) | uint64_t(ev.x[k]) << 32 | uint64_t(ev.y[k]) << 48 |
                       uint64_t(ev.p[k] > 0) << 63);
  } else {
    EventStream part;
    part.width = ev.width, part.height = ev.height;
    for (size_t k = i; k < j; ++k) part.t.push_back(ev.t[k]), part.x.push_back(ev.x[k]), part.y.push_back(ev.y[k]), part.p.push_back(ev.p[k]);
    words = encode_evt3(part, "", false);  // each packet restates time high/low and row
  }
  put32(b, uint32_t(words.size()));
  b.insert(b.end(), words.begin(), words.end());
  return b;
}

inline std::vector<uint8_t> compress(const std::vector<uint8_t>& in, const std::string& method) {
  if (method == "lz4") {
    std::vector<uint8_t> out(LZ4F_compressFrameBound(in.size(), nullptr));
    out.resize(LZ4F_compressFrame(out.data(), out.size(), in.data(), in.size(), nullptr));
    return out;
  }
  if (method == "bz2") {
    std::vector<uint8_t> out(in.size() + in.size() / 100 + 600);
    unsigned n = unsigned(out.size());
    BZ2_bzBuffToBuffCompress(reinterpret_cast<char*>(out.data()), &n,
                             const_cast<char*>(reinterpret_cast<const char*>(in.data())), unsigned(in.size()), 9, 0, 0);
    out.resize(n);
    return out;
  }
  return in;
}

}  // namespace bagdetail

// A bag with one event topic "/events" holding `ev`.
inline std::vector<uint8_t> encode_rosbag(const EventStream& ev, const BagOptions& o = {}) {
  using namespace bagdetail;
  const char* type = o.kind == BagMessage::dvs_array ? "dvs_msgs/EventArray" : "event_camera_msgs/EventPacket";
  const char* md5 = o.kind == BagMessage::dvs_array ? "5e8beee5a6c107e504c2e78903c224b8" : "8a6101b351a64529ac77bd8b71074e52";
  std::vector<uint8_t> conn_header, conn_data;
  field(conn_header, "op", {0x07});
  field(conn_header, "conn", u32v(0));
  field(conn_header, "topic", sv("/events"));
  field(conn_data, "topic", sv("/events"));
  field(conn_data, "type", sv(type));
  field(conn_data, "md5sum", sv(o.md5.empty() ? md5 : o.md5));
  field(conn_data, "message_definition", sv("(definition)"));
  std::vector<uint8_t> out(sv("#ROSBAG V2.0\n"));
  const size_t header_at = out.size();
  out.resize(out.size() + 4096 + 8);  // the bag header, written at the end
  std::vector<uint8_t> infos;
  uint32_t chunks = 0, seq = 0;
  const size_t per_chunk = o.events_per_message * o.messages_per_chunk;
  for (size_t c0 = 0; c0 < ev.size() || (c0 == 0 && ev.size() == 0); c0 += per_chunk) {
    std::vector<uint8_t> inner, index;
    record(inner, conn_header, conn_data);
    const size_t c1 = std::min(ev.size(), c0 + per_chunk);
    uint32_t count = 0;
    for (size_t i = c0; i < c1 || (i == c0 && c1 == c0); i += o.events_per_message) {
      const size_t j = std::min(c1, i + o.events_per_message);
      std::vector<uint8_t> mh;
      field(mh, "op", {0x02});
      field(mh, "conn", u32v(0));
      const int64_t t = j > i ? ev.t[j - 1] : 0;
      field(mh, "time", u64v(uint64_t(t / 1000000) | uint64_t(t % 1000000 * 1000) << 32));
      put64(index, uint64_t(t / 1000000) | uint64_t(t % 1000000 * 1000) << 32);
      put32(index, uint32_t(inner.size()));
      record(inner, mh, message(ev, i, j, seq++, o.kind));
      ++count;
      if (j == c1) break;
    }
    const uint64_t chunk_pos = out.size();
    std::vector<uint8_t> ch;
    field(ch, "op", {0x05});
    field(ch, "compression", sv(o.compression));
    field(ch, "size", u32v(uint32_t(inner.size())));
    record(out, ch, compress(inner, o.compression));
    std::vector<uint8_t> ih;
    field(ih, "op", {0x04});
    field(ih, "ver", u32v(1));
    field(ih, "conn", u32v(0));
    field(ih, "count", u32v(count));
    record(out, ih, index);
    std::vector<uint8_t> info_h, info_d;
    field(info_h, "op", {0x06});
    field(info_h, "ver", u32v(1));
    field(info_h, "chunk_pos", u64v(chunk_pos));
    field(info_h, "start_time", u64v(0));
    field(info_h, "end_time", u64v(0));
    field(info_h, "count", u32v(1));
    put32(info_d, 0);
    put32(info_d, count);
    record(infos, info_h, info_d);
    ++chunks;
    if (c1 == ev.size()) break;
  }
  const uint64_t index_pos = out.size();
  record(out, conn_header, conn_data);
  out.insert(out.end(), infos.begin(), infos.end());
  std::vector<uint8_t> bh, head;
  field(bh, "op", {0x03});
  field(bh, "index_pos", u64v(o.index ? index_pos : 0));
  field(bh, "conn_count", u32v(1));
  field(bh, "chunk_count", u32v(chunks));
  record(head, bh, std::vector<uint8_t>(4096 + 8 - 8 - bh.size(), ' '));
  std::copy(head.begin(), head.end(), out.begin() + long(header_at));
  return out;
}

}  // namespace vkunroll::evtest
