#include "vkunroll/host/events/sequence_writer.hpp"

#include <cstdio>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/json_read.hpp"
#include "vkunroll/host/events/event_writer.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

// A number when float64 holds the time exactly (what sequence-format.md documents), else the
// exact fraction as a string (load_sequence's extension).
nlohmann::json json_time(const Rational& r) {
  if (r.den() == 1 && r.num() >= -(int128_t(1) << 53) && r.num() <= (int128_t(1) << 53)) return static_cast<int64_t>(r.num());
  const double d = r.to_double();
  if (Rational::from_double(d) == r) return d;
  return r.str();
}

void check_image(const SequenceImage& im, int width, int height, const std::string& what) {
  if (im.width != width || im.height != height)
    throw DataError(what + ": image is " + std::to_string(im.width) + "x" + std::to_string(im.height) + ", the sensor is " +
                std::to_string(width) + "x" + std::to_string(height));
  if (im.channels != 1 && im.channels != 3)
    throw DataError(what + ": " + std::to_string(im.channels) + " channels (expected 1 or 3)");
  if (im.bit_depth != 8 && im.bit_depth != 16)
    throw DataError(what + ": bit depth " + std::to_string(im.bit_depth) + " (expected 8 or 16)");
  const size_t n = static_cast<size_t>(width) * height * im.channels;
  const size_t have = im.bit_depth == 8 ? im.u8.size() : im.u16.size();
  if (have != n)
    throw DataError(what + ": " + std::to_string(have) + " values, expected " + std::to_string(n) + " (" + std::to_string(width) +
                "x" + std::to_string(height) + "x" + std::to_string(im.channels) + ")");
}

void check_spec(const std::string& dir, const SequenceWriteSpec& s) {
  if (s.width <= 0 || s.height <= 0 || s.width > 32767 || s.height > 32767)
    throw DataError(dir + ": sensor size " + std::to_string(s.width) + "x" + std::to_string(s.height) +
                " (expected positive, at most 32767)");
  if (s.frames.empty()) throw DataError(dir + ": a sequence needs at least one frame");
  if (s.events_format != "h5" && s.events_format != "txt")
    throw UsageError(dir + ": events format '" + s.events_format + "' (expected h5 or txt)");
  const RowTiming& first = s.frames.front().timing;
  for (size_t k = 0; k < s.frames.size(); ++k) {
    const std::string what = dir + ": frame " + std::to_string(k);
    const RowTiming& t = s.frames[k].timing;
    t.validate(what + " timing");
    if (t.rows != s.height)
      throw DataError(what + ": timing has " + std::to_string(t.rows) + " rows, the sensor " + std::to_string(s.height));
    if (t.line_delay != first.line_delay || t.readout != first.readout)
      throw DataError(what + ": line delay " + t.line_delay.str() + " us, readout " + readout_name(t.readout) +
                  "; the generic layout has one line delay and readout for all frames (frame 0: " + first.line_delay.str() +
                  " us, " + readout_name(first.readout) + ")");
    check_image(s.frames[k].image, s.width, s.height, what);
  }
  for (size_t g = 0; g < s.ground_truth.size(); ++g)
    check_image(s.ground_truth[g].image, s.width, s.height, dir + ": ground truth " + std::to_string(g));
  if (s.events.width != s.width || s.events.height != s.height)
    throw DataError(dir + ": the events' sensor is " + std::to_string(s.events.width) + "x" + std::to_string(s.events.height) +
                ", the frames' " + std::to_string(s.width) + "x" + std::to_string(s.height));
  if (!s.source_json.empty()) {
    const nlohmann::json j = parse_json<nlohmann::json>(s.source_json, dir + ": source");
    if (!j.is_object()) throw DataError(dir + ": source must be a JSON object");
  }
}

void write_png(const fs::path& path, const SequenceImage& im) {
  const int type = im.bit_depth == 8 ? CV_MAKETYPE(CV_8U, im.channels) : CV_MAKETYPE(CV_16U, im.channels);
  const void* data = im.bit_depth == 8 ? static_cast<const void*>(im.u8.data()) : static_cast<const void*>(im.u16.data());
  cv::Mat m(im.height, im.width, type, const_cast<void*>(data));
  cv::Mat out = m;
  if (im.channels == 3) {
    out = m.clone();
    std::vector<cv::Mat> ch;
    cv::split(m, ch);
    std::swap(ch[0], ch[2]);  // RGB -> OpenCV's BGR
    cv::merge(ch, out);
  }
  if (!cv::imwrite(path.string(), out)) throw IoError(path.string() + ": cannot write the image");
}

}  // namespace

void write_generic_sequence(const std::string& dir, const SequenceWriteSpec& s) {
  check_spec(dir, s);
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "rs", ec);
  if (ec) throw IoError(dir + ": cannot create the folder rs/: " + ec.message());
  const fs::path meta_path = fs::path(dir) / "meta.json";
  fs::remove(meta_path, ec);  // an old meta.json must not describe a half-written folder
  if (ec) throw IoError(meta_path.string() + ": cannot remove the old meta.json: " + ec.message());
  if (!s.ground_truth.empty()) {
    fs::create_directories(fs::path(dir) / "gs", ec);
    if (ec) throw IoError(dir + ": cannot create the folder gs/: " + ec.message());
  }
  nlohmann::json frames = nlohmann::json::array(), gt = nlohmann::json::array();
  const RowTiming& first = s.frames.front().timing;
  for (size_t k = 0; k < s.frames.size(); ++k) {
    char name[64];
    std::snprintf(name, sizeof name, "rs/%06zu.png", k);
    write_png(fs::path(dir) / name, s.frames[k].image);
    nlohmann::json f = {{"file", name}, {"t0_us", json_time(s.frames[k].timing.t0)}};
    if (s.frames[k].timing.exposure != first.exposure) f["exposure_us"] = json_time(s.frames[k].timing.exposure);
    frames.push_back(f);
  }
  for (size_t g = 0; g < s.ground_truth.size(); ++g) {
    char name[64];
    std::snprintf(name, sizeof name, "gs/%06zu.png", g);
    write_png(fs::path(dir) / name, s.ground_truth[g].image);
    gt.push_back({{"file", name}, {"t_us", json_time(s.ground_truth[g].t_us)}});
  }
  const std::string events_file = s.events_format == "h5" ? "events.h5" : "events.txt";
  if (s.events_format == "h5") write_events_hdf5((fs::path(dir) / events_file).string(), s.events);
  else write_events_text((fs::path(dir) / events_file).string(), s.events);

  nlohmann::json meta = {{"width", s.width},
                         {"height", s.height},
                         {"line_delay_us", json_time(first.line_delay)},
                         {"exposure_us", json_time(first.exposure)},
                         {"readout", readout_name(first.readout)},
                         {"frames", frames},
                         {"events", events_file}};
  if (!gt.empty()) meta["ground_truth"] = gt;
  if (!s.source_json.empty()) meta["source"] = parse_json<nlohmann::json>(s.source_json, dir + ": source");
  const fs::path tmp = fs::path(dir) / "meta.json.tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    errno = 0;
    if (!f) throw IoError(tmp.string() + ": cannot open for writing: " + std::strerror(errno));
    f << meta.dump(2) << "\n";
    if (!f.flush()) throw IoError(tmp.string() + ": error writing: " + std::strerror(errno));  // the system's reason
  }
  fs::rename(tmp, meta_path, ec);
  if (ec) throw IoError(meta_path.string() + ": cannot move the finished meta.json into place: " + ec.message());
}

}  // namespace vkunroll
