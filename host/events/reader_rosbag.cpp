// ROS 1 bags: the event topic's messages decoded into the sink. Types are recognised by the
// bag's own connection records (type and md5sum); a connection whose md5 differs from the
// known definition's is refused by name. Decoded: dvs_msgs/EventArray (rpg_dvs_ros),
// prophesee_event_msgs/EventArray, event_camera_msgs/EventPacket with the evt3 (EVT 3.0 words,
// the .raw reader's decoder) and mono (64-bit words) encodings. Streamed chunk by chunk, with
// index checkpoints at chunk records (EventFileReader).
#include <algorithm>
#include <memory>
#include <sstream>

#include "vkunroll/host/events/evt3_words_detail.hpp"
#include "vkunroll/host/events/rosbag_detail.hpp"

namespace vkunroll::detail {

namespace {

enum class BagKind { dvs_array, prophesee_array, event_packet };

struct KnownType {
  const char* type;
  const char* md5;
  BagKind kind;
};
// md5sums as genmsg computes them from the packages' .msg files (both EventArrays have the same
// fields, so the same md5).
constexpr KnownType kEventTypes[] = {
    {"dvs_msgs/EventArray", "5e8beee5a6c107e504c2e78903c224b8", BagKind::dvs_array},
    {"prophesee_event_msgs/EventArray", "5e8beee5a6c107e504c2e78903c224b8", BagKind::prophesee_array},
    {"event_camera_msgs/EventPacket", "8a6101b351a64529ac77bd8b71074e52", BagKind::event_packet},
};

// What a read of one bag decodes: the topic, its connections, the bag's notes (cached in the
// index between windowed reads).
struct BagPlan {
  BagInfo info;
  std::string topic, type;
  BagKind kind = BagKind::dvs_array;
  std::vector<uint32_t> conns;
};

std::string topic_list(const BagInfo& info) {
  std::map<std::string, std::string> topics;
  for (const auto& [id, c] : info.connections) topics[c.topic] = c.type;
  if (topics.empty()) return "none";
  std::string s;
  for (const auto& [t, ty] : topics) s += (s.empty() ? "" : ", ") + t + " (" + ty + ")";
  return s;
}

const KnownType* known_event_type(const std::string& type) {
  for (const auto& k : kEventTypes)
    if (type == k.type) return &k;
  return nullptr;
}

std::string event_types() {
  std::string s;
  for (const auto& k : kEventTypes) s += (s.empty() ? "" : ", ") + std::string(k.type) + " (md5 " + k.md5 + ")";
  return s;
}

// The topic to read: the option's, else the only one of an event type; its type and md5 checked.
std::string choose_topic(const BagInfo& info, const std::string& asked, const std::string& file) {
  if (!asked.empty()) {
    for (const auto& [id, c] : info.connections)
      if (c.topic == asked) return asked;
    throw DataError(file + ": the bag has no topic '" + asked + "' (its topics: " + topic_list(info) + ")");
  }
  std::vector<std::string> found;
  for (const auto& [id, c] : info.connections)
    if (known_event_type(c.type) && std::find(found.begin(), found.end(), c.topic) == found.end()) found.push_back(c.topic);
  if (found.empty())
    throw DataError(file + ": the bag has no event topic (types read: " + event_types() + "; its topics: " + topic_list(info) + ")");
  if (found.size() > 1) {
    std::string s;
    for (const auto& t : found) s += (s.empty() ? "" : ", ") + t;
    throw DataError(file + ": the bag has several event topics (" + s +
                "); choose one with " + opt("events_topic") + " (EventReadOptions::events_topic)");
  }
  return found.front();
}

std::shared_ptr<const BagPlan> plan_bag(ByteSource& src, const EventReadOptions& o) {
  auto plan = std::make_shared<BagPlan>();
  plan->info = read_bag_info(src);
  plan->topic = choose_topic(plan->info, o.events_topic, src.name());
  for (const auto& [id, c] : plan->info.connections) {
    if (c.topic != plan->topic) continue;
    const KnownType* k = known_event_type(c.type);
    if (!k)
      throw DataError(src.name() + ": topic '" + c.topic + "' has type " + c.type + " (md5 " + c.md5sum +
                  "), which is not an event type vkunroll decodes (" + event_types() + ")");
    if (c.md5sum != k->md5)
      throw DataError(src.name() + ": topic '" + c.topic + "' has type " + c.type + " with md5 " + c.md5sum +
                  ", not the known definition's " + k->md5 + " (another version of the message: its fields are unknown)");
    if (!plan->type.empty() && plan->type != c.type)
      throw DataError(src.name() + ": topic '" + c.topic + "' has connections of two types, " + plan->type + " and " + c.type);
    plan->type = c.type;
    plan->kind = k->kind;
    plan->conns.push_back(id);
  }
  return plan;
}

// Reads the topic's messages into the sink; checkpoints at chunk records.
class EventVisitor final : public BagVisitor {
 public:
  EventVisitor(EventSink& sink, const BagPlan& plan) : sink_(sink), plan_(plan) {}

  uint64_t start() {
    const Checkpoint* c = sink_.resume_point();
    if (!c) return plan_.info.data_start;
    evt3_.load(*c);
    record_ = c->record;
    messages_ = c->line;
    set_geometry(int(uint64_t(c->state[7]) >> 32), int(uint32_t(c->state[7])));
    sink_.resume(*c);
    return c->offset;
  }
  void begin(uint64_t start) {
    next_ = sink_.next_checkpoint(start, plan_.info.data_start);
    stopped_ = !sink_.boundary(checkpoint(start));
  }
  bool stopped() const { return stopped_; }
  Checkpoint checkpoint(uint64_t offset) const {
    Checkpoint c;
    c.offset = offset;
    c.record = record_;
    c.line = messages_;  // messages of the topic so far (for messages; not a text line)
    evt3_.save(c);
    c.state[7] = int64_t((uint64_t(uint32_t(width_)) << 32) | uint32_t(height_));
    return c;
  }
  void finish_ignored() {
    for (const auto& [id, n] : other_)
      if (const auto it = plan_.info.connections.find(id); it != plan_.info.connections.end())
        sink_.ignored("messages on " + it->second.topic + " (" + it->second.type + ")", n);
      else
        sink_.ignored("messages of unknown connections", n);
  }

  bool top_record(uint64_t offset) override {
    if (sink_.done()) return !(stopped_ = true);
    if (offset >= next_) {
      if (!sink_.boundary(checkpoint(offset))) return !(stopped_ = true);
      next_ = sink_.next_checkpoint(offset, plan_.info.data_start);
    }
    return true;
  }
  void connection(const BagConnection&) override {}
  bool message(uint32_t conn, uint64_t, const uint8_t* data, size_t size, uint64_t chunk_offset) override {
    if (std::find(plan_.conns.begin(), plan_.conns.end(), conn) == plan_.conns.end()) {
      ++other_[conn];
      return true;
    }
    const bool go = decode(data, size, chunk_offset);
    ++messages_;
    if (!go) stopped_ = true;
    return go;
  }
  void damaged(uint64_t offset, const std::string& what) override {
    sink_.set_record_index(record_++);
    sink_.set_byte_offset(int64_t(offset));
    sink_.unknown_record(what);
  }

 private:
  std::string where(uint64_t chunk_offset) const {
    return "message " + std::to_string(messages_) + " of topic " + plan_.topic + " (chunk at byte " +
           std::to_string(chunk_offset) + ")";
  }
  void set_geometry(int w, int h) {
    if (w <= 0 || h <= 0 || (w == width_ && h == height_)) return;
    if (width_ > 0) {
      sink_.note("topic " + plan_.topic + ": a message says the sensor is " + std::to_string(w) + "x" +
                 std::to_string(h) + ", the first said " + std::to_string(width_) + "x" + std::to_string(height_) +
                 " (the first is kept)");
      return;
    }
    width_ = w, height_ = h;
    sink_.set_file_geometry(w, h, "the width/height of topic " + plan_.topic + "'s messages");
  }
  // A message whose layout is broken: one unknown record (error, or counted under drop).
  void broken(uint64_t chunk_offset, const std::string& why) {
    sink_.set_record_index(record_++);
    sink_.set_byte_offset(int64_t(chunk_offset));
    sink_.unknown_record(where(chunk_offset) + ": " + why);
  }
  bool decode(const uint8_t* data, size_t size, uint64_t chunk_offset);
  bool decode_array(RosCursor& c, uint64_t chunk_offset);
  bool decode_packet(RosCursor& c, uint64_t chunk_offset);

  EventSink& sink_;
  const BagPlan& plan_;
  Evt3State evt3_;
  uint64_t record_ = 0, messages_ = 0, next_ = UINT64_MAX;
  int width_ = 0, height_ = 0;
  bool stopped_ = false;
  std::map<uint32_t, uint64_t> other_;
};

bool EventVisitor::decode(const uint8_t* data, size_t size, uint64_t chunk_offset) {
  const std::string what = sink_.file() + ": " + where(chunk_offset);
  RosCursor c{data, size, 0, &what};
  try {
    c.u32();  // std_msgs/Header: seq, stamp (sec, nsec), frame_id
    c.u64();
    c.string();
  } catch (const Error&) {
    broken(chunk_offset, "its std_msgs/Header is cut short");
    return !sink_.done();
  }
  if (plan_.kind == BagKind::event_packet) return decode_packet(c, chunk_offset);
  return decode_array(c, chunk_offset);
}

// dvs_msgs/EventArray and prophesee_event_msgs/EventArray: height, width, then
// Event[] {uint16 x, uint16 y, time ts (uint32 sec, uint32 nsec), bool polarity}, 13 bytes each.
bool EventVisitor::decode_array(RosCursor& c, uint64_t chunk_offset) {
  if (c.left() < 12) {
    broken(chunk_offset, "it ends before its height, width and event count");
    return !sink_.done();
  }
  const uint32_t h = c.u32(), w = c.u32(), n = c.u32();
  set_geometry(int(std::min<uint32_t>(w, 1u << 30)), int(std::min<uint32_t>(h, 1u << 30)));
  const size_t whole = std::min<size_t>(n, c.left() / 13);
  const uint8_t* p = c.p + c.at;
  sink_.set_byte_offset(int64_t(chunk_offset));
  for (size_t i = 0; i < whole; ++i, p += 13) {
    const uint16_t x = uint16_t(p[0] | (p[1] << 8)), y = uint16_t(p[2] | (p[3] << 8));
    const uint32_t sec = uint32_t(p[4]) | (uint32_t(p[5]) << 8) | (uint32_t(p[6]) << 16) | (uint32_t(p[7]) << 24);
    const uint32_t nsec = uint32_t(p[8]) | (uint32_t(p[9]) << 8) | (uint32_t(p[10]) << 16) | (uint32_t(p[11]) << 24);
    sink_.set_record_index(record_++);
    if (nsec >= 1000000000u) {
      if (!sink_.bad_time([&] { return "event time " + std::to_string(sec) + " s " + std::to_string(nsec) +
                                       " ns: nanoseconds must be below 10^9"; }))
        return false;
      continue;
    }
    if (!sink_.add(int64_t(sec) * 1000000 + nsec / 1000, x, y, p[12])) return false;
  }
  if (whole < n)
    broken(chunk_offset, "it says " + std::to_string(n) + " events but holds " + std::to_string(whole) +
                             " whole ones (" + std::to_string(c.left() - whole * 13) + " bytes left)");
  return !sink_.done();
}

// event_camera_msgs/EventPacket: height, width, seq, time_base, encoding, is_bigendian, uint8[] events.
bool EventVisitor::decode_packet(RosCursor& c, uint64_t chunk_offset) {
  uint32_t h = 0, w = 0, len = 0;
  uint64_t time_base = 0;
  std::string encoding;
  bool big = false;
  try {
    h = c.u32(), w = c.u32();
    c.u64();
    time_base = c.u64();
    encoding = c.string();
    big = c.u8() != 0;
    len = c.u32();
    c.need(len);
  } catch (const Error&) {
    broken(chunk_offset, "its EventPacket fields are cut short");
    return !sink_.done();
  }
  set_geometry(int(std::min<uint32_t>(w, 1u << 30)), int(std::min<uint32_t>(h, 1u << 30)));
  const uint8_t* p = c.p + c.at;
  if (encoding == "evt3" && !big) {
    for (size_t i = 0; i + 1 < len; i += 2)
      if (!evt3_word(uint16_t(p[i] | (p[i + 1] << 8)), chunk_offset, evt3_, record_, sink_)) return false;
    if (len % 2) broken(chunk_offset, "its evt3 bytes end inside a 16-bit word (" + std::to_string(len) + " bytes)");
  } else if (encoding == "mono" && !big) {
    sink_.set_byte_offset(int64_t(chunk_offset));
    for (size_t i = 0; i + 8 <= len; i += 8) {
      uint64_t v = 0;
      for (int b = 7; b >= 0; --b) v = v << 8 | p[i + size_t(b)];
      sink_.set_record_index(record_++);
      const uint64_t dt = v & 0xFFFFFFFFu;
      if (time_base > UINT64_MAX - dt) {
        if (!sink_.bad_time([&] { return std::string("time_base + event time overflows 64 bits"); })) return false;
        continue;
      }
      // mono: ROS nanoseconds time_base + 32-bit offset; x 16 bits, y 15 bits, polarity the top bit.
      if (!sink_.add(int64_t((time_base + dt) / 1000), int64_t(v >> 32 & 0xFFFF), int64_t(v >> 48 & 0x7FFF),
                     int64_t(v >> 63)))
        return false;
    }
    if (len % 8) broken(chunk_offset, "its mono bytes end inside a 64-bit event (" + std::to_string(len) + " bytes)");
  } else {
    broken(chunk_offset, "encoding '" + encoding + "'" + (big ? " (big-endian)" : "") +
                             " is not decoded (evt3 and mono, little-endian, are)");
  }
  return !sink_.done();
}

}  // namespace

std::string bag_event_topic(ByteSource& src, const std::string& asked) {
  EventReadOptions o;
  o.events_topic = asked;
  return plan_bag(src, o)->topic;
}

void read_rosbag(ByteSource& src, EventSink& sink) {
  StreamIndex* index = sink.index();
  std::shared_ptr<const BagPlan> plan;
  if (index && index->header) plan = std::static_pointer_cast<const BagPlan>(index->header);
  if (!plan) {
    plan = plan_bag(src, sink.options());
    if (index) index->header = plan;
  }
  for (const auto& n : plan->info.notes) sink.note(n);
  sink.note("topic " + plan->topic + " (" + plan->type + "); the bag's topics: " + topic_list(plan->info));
  EventVisitor v(sink, *plan);
  const uint64_t start = v.start();
  v.begin(start);
  if (v.stopped()) return;
  scan_bag_records(src, start, v);
  v.finish_ignored();
  if (!v.stopped()) sink.end_of_data(v.checkpoint(src.size()));
  sink.set_byte_offset(-1);
}

}  // namespace vkunroll::detail
