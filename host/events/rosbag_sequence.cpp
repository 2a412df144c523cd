// write_bag_sequence (rosbag_sequence.hpp): sensor_msgs/Image messages -> rs/NNNNNN.png, meta.json.
// Image: Header header, uint32 height, uint32 width, string encoding, uint8 is_bigendian,
// uint32 step (bytes per row), uint8[] data. Streamed message by message (one frame in memory).
#include "vkunroll/host/events/rosbag_sequence.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/core.hpp>

#include "vkunroll/host/events/rosbag_detail.hpp"

namespace vkunroll {

namespace {

namespace fs = std::filesystem;
using detail::BagConnection;
using detail::BagInfo;

constexpr const char* kImageType = "sensor_msgs/Image";
constexpr const char* kImageMd5 = "060021388200f6f0f447d0fcd9c64743";
constexpr const char* kCameraInfoType = "sensor_msgs/CameraInfo";
constexpr const char* kCameraInfoMd5 = "c9a58c1b0b154e0e6da7578cb991d214";

// The CameraInfo topic beside the frames: the only one, else the one in the frames topic's
// namespace (/dvs/camera_info for /dvs/image_raw); none: no calibration to record.
std::vector<uint32_t> camera_info_connections(const BagInfo& info, const std::string& frames_topic, const std::string& bag,
                                              std::string& topic, std::vector<std::string>& notes) {
  std::vector<std::string> topics;
  for (const auto& [id, c] : info.connections)
    if (c.type == kCameraInfoType && std::find(topics.begin(), topics.end(), c.topic) == topics.end()) topics.push_back(c.topic);
  const std::string ns = frames_topic.substr(0, frames_topic.rfind('/') + 1);
  topic.clear();
  for (const auto& t : topics)
    if (topics.size() == 1 || t.substr(0, t.rfind('/') + 1) == ns) topic = topic.empty() ? t : std::string("?");
  if (topic == "?" || (topic.empty() && !topics.empty())) {
    notes.push_back(bag + ": " + std::to_string(topics.size()) + " sensor_msgs/CameraInfo topics and none alone in " + ns +
                    ": no calibration recorded");
    topic.clear();
  }
  std::vector<uint32_t> conns;
  for (const auto& [id, c] : info.connections) {
    if (topic.empty() || c.topic != topic) continue;
    if (c.md5sum != kCameraInfoMd5)
      throw DataError(bag + ": camera info topic '" + topic + "' has md5 " + c.md5sum + ", not sensor_msgs/CameraInfo's " +
                  kCameraInfoMd5 + " (another version of the message: its fields are unknown)");
    conns.push_back(id);
  }
  return conns;
}

// CameraInfo: Header, uint32 height, width, string distortion_model, float64[] D, float64[9] K,
// R[9], P[12], uint32 binning_x, binning_y, RegionOfInterest roi (4 x uint32, bool do_rectify).
nlohmann::json camera_info_of(const uint8_t* data, size_t size, const std::string& what) {
  detail::RosCursor c{data, size, 0, &what};
  c.u32(), c.u32(), c.u32();
  c.string();
  nlohmann::json j;
  j["height"] = c.u32();
  j["width"] = c.u32();
  j["distortion_model"] = c.string();
  auto f64s = [&](uint32_t n) {
    std::vector<double> v(n);
    c.need(size_t(n) * 8);
    for (auto& x : v) {
      const uint64_t bits = c.u64();
      std::memcpy(&x, &bits, 8);
    }
    return v;
  };
  const uint32_t nd = c.u32();
  if (nd > 64) throw DataError(what + ": " + std::to_string(nd) + " distortion coefficients (at most 64 expected)");
  j["D"] = f64s(nd);
  j["K"] = f64s(9);
  j["R"] = f64s(9);
  j["P"] = f64s(12);
  j["binning_x"] = c.u32();
  j["binning_y"] = c.u32();
  j["roi"] = {{"x_offset", c.u32()}, {"y_offset", c.u32()}, {"height", c.u32()}, {"width", c.u32()}, {"do_rectify", c.u8() != 0}};
  return j;
}

std::vector<uint32_t> frame_connections(const BagInfo& info, const std::string& asked, const std::string& bag,
                                        std::string& topic) {
  std::vector<std::string> images;
  for (const auto& [id, c] : info.connections)
    if (c.type == kImageType && std::find(images.begin(), images.end(), c.topic) == images.end()) images.push_back(c.topic);
  topic = asked;
  if (topic.empty()) {
    std::string list;
    for (const auto& t : images) list += (list.empty() ? "" : ", ") + t;
    if (images.size() != 1)
      throw DataError(bag + ": " + (images.empty() ? std::string("the bag has no sensor_msgs/Image topic")
                                               : "the bag has several image topics (" + list + "); choose one with " + opt("frames_topic")));
    topic = images.front();
  }
  std::vector<uint32_t> conns;
  for (const auto& [id, c] : info.connections) {
    if (c.topic != topic) continue;
    if (c.type != kImageType || c.md5sum != kImageMd5)
      throw DataError(bag + ": frames topic '" + topic + "' has type " + c.type + " (md5 " + c.md5sum + "), expected " +
                  kImageType + " (md5 " + kImageMd5 + ")");
    conns.push_back(id);
  }
  if (conns.empty()) throw DataError(bag + ": the bag has no topic '" + topic + "'");
  return conns;
}

// The image as OpenCV's gray or BGR Mat (8 or 16 bits); throws Error naming the message.
cv::Mat image_of(const uint8_t* data, size_t size, const std::string& what, std::string& encoding, int64_t& stamp_us) {
  detail::RosCursor c{data, size, 0, &what};
  c.u32();
  const uint32_t sec = c.u32(), nsec = c.u32();
  c.string();
  stamp_us = int64_t(sec) * 1000000 + nsec / 1000;
  const uint32_t h = c.u32(), w = c.u32();
  encoding = c.string();
  const bool big = c.u8() != 0;
  const uint32_t step = c.u32(), len = c.u32();
  c.need(len);
  // blue_from: the source channel of OpenCV's blue (red is 2 - blue_from); -1: gray.
  struct Enc { const char* name; int type, blue_from; };
  static const Enc kEnc[] = {{"mono8", CV_8UC1, -1}, {"8UC1", CV_8UC1, -1}, {"mono16", CV_16UC1, -1},
                             {"16UC1", CV_16UC1, -1}, {"bgr8", CV_8UC3, 0}, {"rgb8", CV_8UC3, 2},
                             {"bgra8", CV_8UC4, 0}, {"rgba8", CV_8UC4, 2}};
  const Enc* e = nullptr;
  for (const auto& k : kEnc)
    if (encoding == k.name) e = &k;
  if (!e)
    throw DataError(what + ": image encoding '" + encoding +
                "' is not read (mono8, mono16, 8UC1, 16UC1, bgr8, rgb8, bgra8, rgba8 are; debayer the topic first)");
  const size_t row = size_t(w) * size_t(CV_ELEM_SIZE(e->type));
  if (w == 0 || h == 0 || w > 65536 || h > 65536 || step < row || uint64_t(step) * h > len)
    throw DataError(what + ": image " + std::to_string(w) + "x" + std::to_string(h) + " with step " + std::to_string(step) +
                " does not fit its " + std::to_string(len) + " data bytes");
  cv::Mat m(int(h), int(w), e->type, const_cast<uint8_t*>(c.p + c.at), step);
  cv::Mat out = m.clone();
  if (CV_ELEM_SIZE1(e->type) == 2 && big) {
    for (int y = 0; y < out.rows; ++y)
      for (auto* p = out.ptr<uint16_t>(y); p != out.ptr<uint16_t>(y) + out.cols; ++p) *p = uint16_t(*p >> 8 | *p << 8);
  }
  if (e->blue_from < 0) return out;
  cv::Mat bgr(out.rows, out.cols, CV_8UC3);
  const int from_to[] = {e->blue_from, 0, 1, 1, 2 - e->blue_from, 2};
  cv::mixChannels(&out, 1, &bgr, 1, from_to, 3);
  return bgr;
}

// A time as meta.json holds it: an integer, or an exact fraction as a string ("73000/259").
nlohmann::json exact(const Rational& r) {
  return r.den() == 1 ? nlohmann::json(int64_t(r.num())) : nlohmann::json(r.str());
}

struct FrameWriter final : detail::BagVisitor {
  const std::vector<uint32_t>& conns;
  std::vector<uint32_t> info_conns;  // the CameraInfo topic's (its first message is kept)
  std::string info_topic;
  nlohmann::json camera_info;
  const BagSequenceOptions& o;
  fs::path dir;
  std::string bag, topic;
  BagSequenceReport& rep;
  nlohmann::json frames = nlohmann::json::array();
  Rational last_t0;
  FrameWriter(const std::vector<uint32_t>& c, const BagSequenceOptions& opt, fs::path d, std::string b, std::string t,
              BagSequenceReport& r)
      : conns(c), o(opt), dir(std::move(d)), bag(std::move(b)), topic(std::move(t)), rep(r) {}

  bool top_record(uint64_t) override { return o.max_frames == 0 || rep.frames < o.max_frames; }
  void connection(const detail::BagConnection&) override {}
  void damaged(uint64_t, const std::string& what) override {
    rep.notes.push_back(bag + ": " + what + "; the frames before it were written");
  }
  bool message(uint32_t conn, uint64_t, const uint8_t* data, size_t size, uint64_t chunk_offset) override {
    if (camera_info.is_null() && std::find(info_conns.begin(), info_conns.end(), conn) != info_conns.end()) {
      camera_info = camera_info_of(data, size, bag + ": camera info of topic " + info_topic + " (chunk at byte " +
                                                   std::to_string(chunk_offset) + ")");
      camera_info["topic"] = info_topic;
      return true;
    }
    if (std::find(conns.begin(), conns.end(), conn) == conns.end()) return true;
    if (o.max_frames && rep.frames >= o.max_frames) return false;
    const std::string what = bag + ": image " + std::to_string(rep.frames) + " of topic " + topic + " (chunk at byte " +
                             std::to_string(chunk_offset) + ")";
    std::string encoding;
    int64_t stamp_us = 0;
    const cv::Mat im = image_of(data, size, what, encoding, stamp_us);
    if (rep.frames == 0) rep.width = im.cols, rep.height = im.rows, rep.encoding = encoding;
    if (im.cols != rep.width || im.rows != rep.height)
      throw DataError(what + ": " + std::to_string(im.cols) + "x" + std::to_string(im.rows) + ", the first image is " +
                  std::to_string(rep.width) + "x" + std::to_string(rep.height));
    const Rational t0 = Rational(stamp_us) + o.t0_offset_us;
    if (rep.frames > 0 && !(last_t0 < t0))
      throw DataError(what + ": its stamp " + t0.str() + " us is not after the previous image's " + last_t0.str() + " us");
    last_t0 = t0;
    char name[32];
    std::snprintf(name, sizeof name, "rs/%06llu.png", static_cast<unsigned long long>(rep.frames));
    if (!cv::imwrite((dir / name).string(), im)) throw IoError((dir / name).string() + ": cannot write the image");
    frames.push_back({{"file", name}, {"t0_us", exact(t0)}});
    ++rep.frames;
    return true;
  }
};

}  // namespace

BagSequenceReport write_bag_sequence(const std::string& bag, const std::string& out_dir, const BagSequenceOptions& o) {
  if (!(Rational(0) < o.line_delay_us) || !(Rational(0) < o.exposure_us))
    throw UsageError("the row timing needs a line delay and an exposure above 0 us (a bag does not hold them)");
  detail::FileSource src(bag);
  const BagInfo info = detail::read_bag_info(src);
  BagSequenceReport rep;
  const std::vector<uint32_t> conns = frame_connections(info, o.frames_topic, bag, rep.frames_topic);
  rep.events_topic = detail::bag_event_topic(src, o.events_topic);
  rep.notes = info.notes;
  const fs::path dir(out_dir);
  std::error_code ec;
  fs::create_directories(dir / "rs", ec);
  if (ec) throw IoError((dir / "rs").string() + ": cannot create the folder: " + ec.message());
  FrameWriter w(conns, o, dir, bag, rep.frames_topic, rep);
  w.info_conns = camera_info_connections(info, rep.frames_topic, bag, w.info_topic, rep.notes);
  detail::scan_bag_records(src, info.data_start, w);
  if (rep.frames == 0) throw DataError(bag + ": topic " + rep.frames_topic + " holds no image");
  const nlohmann::json& ci = w.camera_info;
  if (!ci.is_null() && ci["width"].get<uint32_t>() && (ci["width"] != rep.width || ci["height"] != rep.height))
    throw DataError(bag + ": camera info of topic " + w.info_topic + " is for " + ci["width"].dump() + "x" + ci["height"].dump() +
                ", the images of " + rep.frames_topic + " are " + std::to_string(rep.width) + "x" + std::to_string(rep.height));
  if (!w.info_topic.empty() && ci.is_null()) rep.notes.push_back(bag + ": camera info topic " + w.info_topic + " holds no message");
  rep.camera_info_topic = ci.is_null() ? std::string() : w.info_topic;
  nlohmann::json meta = {{"width", rep.width},
                         {"height", rep.height},
                         {"line_delay_us", exact(o.line_delay_us)},
                         {"exposure_us", exact(o.exposure_us)},
                         {"readout", readout_name(o.readout)},
                         {"frames", w.frames},
                         {"events", fs::absolute(bag).lexically_normal().string()},
                         {"events_topic", rep.events_topic},
                         {"source", {{"ros_bag", fs::absolute(bag).lexically_normal().string()},
                                     {"frames_topic", rep.frames_topic},
                                     {"events_topic", rep.events_topic},
                                     {"image_encoding", rep.encoding}}}};
  if (!ci.is_null()) meta["source"]["camera_info"] = ci;  // calibration, recorded (unrolling does not use it)
  const fs::path tmp = dir / "meta.json.tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    errno = 0;
    if (!f) throw IoError(tmp.string() + ": cannot open for writing: " + std::strerror(errno));
    f << meta.dump(2) << "\n";
    if (!f.flush()) throw IoError(tmp.string() + ": error writing: " + std::strerror(errno));  // the system's reason
  }
  fs::rename(tmp, dir / "meta.json", ec);
  if (ec) throw IoError((dir / "meta.json").string() + ": cannot move meta.json into place: " + ec.message());
  return rep;
}

}  // namespace vkunroll
