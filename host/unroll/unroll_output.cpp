#include "vkunroll/host/unroll/unroll_output.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/json_read.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/unroll/sha256.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

constexpr const char* kJournal = "frames.jsonl";
constexpr const char* kVideo = "gs_video.mp4";
constexpr const char* kVideoPartial = ".gs_video.partial.mp4";  // OpenCV picks the container by the extension

cv::Mat to_bgr8(const cv::Mat& m) {
  cv::Mat f = to_unit_float(m), out;
  f.convertTo(out, CV_8U, 255.0);
  if (out.channels() == 1) cv::cvtColor(out, out, cv::COLOR_GRAY2BGR);
  return out;
}

// PSNR of identical images is +infinity; JSON has none: the cap, documented in docs/reliability.md.
double json_psnr(double p) { return std::isinf(p) ? 100.0 : p; }

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw IoError(p.string() + ": cannot open for reading");
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

nlohmann::json record_json(const GsFrameRecord& r) {
  nlohmann::json j = {{"frame", r.frame}, {"t_us", r.t_us}, {"t_us_exact", r.t_exact}, {"tau", r.tau}, {"file", r.file}};
  if (r.psnr) {
    j["gt_file"] = r.gt_file;
    j["psnr"] = json_psnr(*r.psnr);
    j["ssim"] = *r.ssim;
    if (r.rs_psnr) j["rs_psnr"] = json_psnr(*r.rs_psnr), j["rs_ssim"] = *r.rs_ssim;
  }
  if (r.reused) j["reused"] = true;
  if (!r.events_window.empty()) j["events_window"] = r.events_window;
  return j;
}

GsFrameRecord record_from_json(const nlohmann::json& j) {
  GsFrameRecord r;
  r.frame = j.at("frame").get<int>();
  r.t_us = j.at("t_us").get<double>();
  r.t_exact = j.at("t_us_exact").get<std::string>();
  r.tau = j.at("tau").get<double>();
  r.file = j.at("file").get<std::string>();
  if (j.contains("psnr")) {
    r.gt_file = j.at("gt_file").get<std::string>();
    r.psnr = j.at("psnr").get<double>();
    r.ssim = j.at("ssim").get<double>();
    if (j.contains("rs_psnr")) r.rs_psnr = j.at("rs_psnr").get<double>(), r.rs_ssim = j.at("rs_ssim").get<double>();
  }
  return r;
}

}  // namespace

std::string gs_frame_name(int frame, double t_us, const char* extension) {
  char buf[128];
  std::snprintf(buf, sizeof buf, "f%06d_t%+011.1fus%s", frame, t_us, extension);
  return buf;
}

std::string csv_number(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[512];
  const auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed);
  if (r.ec != std::errc()) return std::to_string(v);
  return std::string(buf, r.ptr);
}

UnrollOutput::UnrollOutput(fs::path dir, UnrollOutputOptions options)
    : folder_(std::move(dir), options.existing, output_path("unroll.out")), options_(std::move(options)) {
  if (options_.existing == ExistingOutput::resume) {
    load_journal(folder_.staging());   // a killed run's frames
    load_journal(folder_.final_dir());  // a finished run's frames
  }
}

UnrollOutput::~UnrollOutput() {
  if (video_) video_->release();
}

void UnrollOutput::load_journal(const fs::path& folder) {
  std::ifstream in(folder / kJournal);
  for (std::string line; std::getline(in, line);) {
    try {
      const auto j = parse_json<nlohmann::json>(line, (folder / kJournal).string());
      earlier_[std::to_string(j.at("frame").get<int>()) + "|" + j.at("t_us_exact").get<std::string>()].push_back({j, folder});
    } catch (const std::exception&) {
      // A line cut by a kill: that frame is simply redone.
    }
  }
}

std::string UnrollOutput::file_for(int frame, double t_us, const std::string& name) const {
  const char* ext = frame_format_extension(options_.frame_format);
  if (name.empty()) return "frames/" + gs_frame_name(frame, t_us, ext);
  return "frames/" + fs::path(name).replace_extension(ext).filename().string();
}

std::optional<cv::Mat> UnrollOutput::find_reusable(int frame, const std::string& t_exact, const std::string& name,
                                                   GsFrameRecord* record) {
  const auto it = earlier_.find(std::to_string(frame) + "|" + t_exact);
  if (it == earlier_.end() || options_.resume_key.empty()) return std::nullopt;
  for (const JournalEntry& e : it->second) {
    try {
      const nlohmann::json& j = e.line;
      if (j.at("key").get<std::string>() != options_.resume_key) continue;
      GsFrameRecord r = record_from_json(j.at("record"));
      if (r.file != file_for(frame, r.t_us, name) || files_.count(r.file)) continue;
      const fs::path src = e.source / r.file;
      std::error_code ec;
      if (!fs::is_regular_file(src, ec) || fs::file_size(src, ec) != j.at("bytes").get<uint64_t>()) continue;
      const std::string bytes = read_file(src);
      if (sha256_hex(bytes) != j.at("sha256").get<std::string>()) continue;
      cv::Mat image = decode_frame(bytes, options_.frame_format, src.string());
      folder_.adopt(src, r.file);
      r.reused = true;
      *record = r;
      return image;
    } catch (const IoError&) {
      throw;
    } catch (const std::exception&) {
      // Malformed entry or undecodable file: not valid, the frame is redone.
    }
  }
  return std::nullopt;
}

void UnrollOutput::file_record(const GsFrameRecord& r, const std::string& sha256, size_t bytes, const cv::Mat& image,
                               const cv::Mat& rs_input, const cv::Mat& gt) {
  files_.insert(r.file);
  nlohmann::json rec = record_json(r);
  rec.erase("reused");
  const nlohmann::json line = {{"key", options_.resume_key}, {"frame", r.frame}, {"t_us_exact", r.t_exact},
                               {"bytes", bytes}, {"sha256", sha256}, {"record", rec}};
  journal_.push_back(line.dump());
  folder_.append_line(kJournal, journal_.back());
  if (options_.write_video) video_frame(image);
  char label[64];
  std::snprintf(label, sizeof label, "t=%.0fus", r.t_us);
  add_to_contact(r.frame, rs_input, image, gt, label);
  records_.push_back(r);
}

void UnrollOutput::add_reused(const GsFrameRecord& record, const cv::Mat& image, const cv::Mat& rs_input, const cv::Mat& gt) {
  const fs::path p = folder_.staging() / record.file;
  std::error_code ec;
  file_record(record, sha256_file(p), static_cast<size_t>(fs::file_size(p, ec)), image, rs_input, gt);
  reused_++;
}

GsFrameRecord UnrollOutput::add(int frame, double t_us, const std::string& t_exact, double tau, const cv::Mat& image,
                                const cv::Mat& rs_input, const cv::Mat& gt, const std::string& gt_file,
                                const std::string& name, const std::string& events_window) {
  GsFrameRecord r;
  r.frame = frame;
  r.events_window = events_window;
  r.t_us = t_us;
  r.t_exact = t_exact;
  r.tau = tau;
  r.file = file_for(frame, t_us, name);
  if (files_.count(r.file)) {  // two targets within 0.05 us of each other (or two truths of one name)
    const fs::path f(r.file);
    for (int k = 2; files_.count(r.file); ++k)
      r.file = (f.parent_path() / (f.stem().string() + "_" + std::to_string(k) + f.extension().string())).string();
  }
  const std::string bytes = encode_frame(image, options_.frame_format);
  folder_.write(r.file, bytes);
  score_against_ground_truth(r, image, rs_input, gt, gt_file);
  file_record(r, sha256_hex(bytes), bytes.size(), image, rs_input, gt);
  return r;
}

void UnrollOutput::video_frame(const cv::Mat& image) {
  const cv::Mat bgr = to_bgr8(image);
  if (!video_) {
    const std::string path = (folder_.staging() / kVideoPartial).string();
    const double fps = options_.video_fps.value_or(30.0);
    // H.264 (browsers play it) where OpenCV's FFmpeg has an encoder for it, else MPEG-4 part 2.
    const std::pair<int, const char*> codecs[] = {{cv::VideoWriter::fourcc('a', 'v', 'c', '1'), "avc1 (H.264)"},
                                                  {cv::VideoWriter::fourcc('m', 'p', '4', 'v'), "mp4v (MPEG-4 part 2)"}};
    for (const auto& [fourcc, name] : codecs) {
      video_ = std::make_unique<cv::VideoWriter>(path, cv::CAP_FFMPEG, fourcc, fps, bgr.size());
      if (video_->isOpened()) {
        video_codec_ = name;
        break;
      }
    }
    if (!video_->isOpened()) throw IoError(folder_.shown(kVideo) + ": OpenCV cannot open an MP4 writer (neither avc1 nor mp4v)");
  }
  video_->write(bgr);
  video_frames_++;
}

void UnrollOutput::close_video() {
  if (!video_) return;
  video_->release();
  video_.reset();
  // OpenCV does not report failed writes: read the closed file back (a full disk leaves no index).
  const fs::path partial = folder_.staging() / kVideoPartial;
  cv::VideoCapture check(partial.string(), cv::CAP_FFMPEG);
  const double n = check.isOpened() ? check.get(cv::CAP_PROP_FRAME_COUNT) : -1;
  check.release();
  if (n != static_cast<double>(video_frames_))
    throw IoError(folder_.shown(kVideo) + ": the written video does not read back (" +
                  (n < 0 ? std::string("unreadable") : csv_number(n) + " of " + std::to_string(video_frames_) + " frames") +
                  "): the disk may be full");
  std::error_code ec;
  fs::rename(partial, folder_.staging() / kVideo, ec);
  if (ec) throw IoError(folder_.shown(kVideo) + ": cannot rename the closed video into place (" + ec.message() + ")");
}

void UnrollOutput::add_to_contact(int frame, const cv::Mat& rs, const cv::Mat& result, const cv::Mat& gt,
                                  const std::string& label) {
  if (contact_.empty() || contact_.back().frame != frame) {
    if (static_cast<int>(contact_.size()) >= options_.contact_max_frames) return;
    contact_.push_back({frame, rs.empty() ? cv::Mat() : to_bgr8(rs), {}, {}, {}});
  }
  ContactRow& row = contact_.back();
  if (static_cast<int>(row.results.size()) >= options_.contact_max_targets) return;
  row.results.push_back(to_bgr8(result));
  row.gts.push_back(gt.empty() ? cv::Mat() : to_bgr8(gt));
  row.labels.push_back(label);
}

std::string UnrollOutput::contact_sheet_png() const {
  const cv::Size cell = contact_.front().results.front().size();
  const double scale = std::clamp(320.0 / cell.width, 0.25, 4.0);  // small crops are enlarged to be seen
  const cv::Size thumb(std::max(1, int(cell.width * scale)), std::max(1, int(cell.height * scale)));
  size_t cols = 0;
  bool any_gt = false;
  for (const auto& r : contact_) {
    cols = std::max(cols, r.results.size());
    for (const auto& g : r.gts) any_gt = any_gt || !g.empty();
  }
  const int pad = 4, text = 18;
  const int rows_per_frame = any_gt ? 2 : 1;
  cv::Mat sheet(int(contact_.size()) * rows_per_frame * (thumb.height + text + pad) + pad,
                int(cols + 1) * (thumb.width + pad) + pad, CV_8UC3, cv::Scalar(32, 32, 32));
  auto put = [&](const cv::Mat& img, int row, int col, const std::string& label) {
    const cv::Point at(pad + col * (thumb.width + pad), pad + row * (thumb.height + text + pad));
    if (!img.empty()) {
      cv::Mat t;
      cv::resize(img, t, thumb, 0, 0, cv::INTER_AREA);
      t.copyTo(sheet(cv::Rect(at.x, at.y + text, thumb.width, thumb.height)));
    }
    cv::putText(sheet, label, {at.x, at.y + text - 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, {230, 230, 230}, 1, cv::LINE_AA);
  };
  int row = 0;
  for (const auto& r : contact_) {
    put(r.rs, row, 0, "RS frame " + std::to_string(r.frame));
    for (size_t k = 0; k < r.results.size(); ++k) put(r.results[k], row, int(k + 1), "GS " + r.labels[k]);
    if (any_gt) {
      for (size_t k = 0; k < r.gts.size(); ++k)
        if (!r.gts[k].empty()) put(r.gts[k], row + 1, int(k + 1), "truth " + r.labels[k]);
    }
    row += rows_per_frame;
  }
  std::vector<uchar> buf;
  if (!cv::imencode(".png", sheet, buf)) throw InternalError("OpenCV could not encode the contact sheet");
  return std::string(buf.begin(), buf.end());
}

nlohmann::json UnrollOutput::finish(const nlohmann::json& extra) {
  if (finished_) throw InternalError("unroll output: finish() called twice");
  std::vector<std::string> keep(files_.begin(), files_.end());
  nlohmann::json outputs = {{"frames", "frames/"}, {"frame_format", frame_format_name(options_.frame_format)}};
  close_video();
  if (video_frames_) {
    outputs["video"] = kVideo, outputs["video_codec"] = video_codec_, outputs["video_fps"] = options_.video_fps.value_or(30.0);
    keep.push_back(kVideo);
  }
  if (!contact_.empty()) {
    folder_.write("contact_sheet.png", contact_sheet_png());
    outputs["contact_sheet"] = "contact_sheet.png";
    keep.push_back("contact_sheet.png");
  }
  nlohmann::json frames = nlohmann::json::array();
  std::string csv = "frame,t_us,tau,file,gt_file,psnr,ssim,rs_psnr,rs_ssim\n";
  auto opt = [](const std::optional<double>& v) { return v ? csv_number(json_psnr(*v)) : std::string(); };
  for (const auto& r : records_) {
    csv += std::to_string(r.frame) + "," + csv_number(r.t_us) + "," + csv_number(r.tau) + "," + csv_field(r.file) + "," +
           csv_field(r.gt_file) + "," + opt(r.psnr) + "," + opt(r.ssim) + "," + opt(r.rs_psnr) + "," + opt(r.rs_ssim) + "\n";
    frames.push_back(record_json(r));
  }
  folder_.write("metrics.csv", csv);
  outputs["metrics"] = "metrics.csv";
  keep.push_back("metrics.csv");
  std::string journal;
  for (const auto& l : journal_) journal += l + "\n";
  folder_.write(kJournal, journal);  // compact: exactly this run's frames
  outputs["journal"] = kJournal;
  keep.push_back(kJournal);
  keep.push_back("summary.json");
  folder_.prune(keep);  // a killed run's leftovers that this run did not list

  nlohmann::json summary = extra;
  summary["gs_frames"] = frames;
  summary["outputs"] = outputs;
  const nlohmann::json means = metric_means(records_);
  if (means["count"].get<int>() > 0) summary["metrics"] = means;
  if (options_.existing == ExistingOutput::resume) summary["resume"] = {{"reused", reused_}, {"computed", records_.size() - reused_}};
  summary["output_dir"] = folder_.final_dir().string();
  folder_.write("summary.json", summary.dump(2) + "\n");  // last: everything it lists exists
  folder_.commit();
  finished_ = true;
  return summary;
}

void score_against_ground_truth(GsFrameRecord& r, const cv::Mat& image, const cv::Mat& rs_input, const cv::Mat& gt,
                                const std::string& gt_file) {
  if (gt.empty()) return;
  const cv::Mat unit = to_unit_float(image);
  r.gt_file = gt_file;
  r.psnr = psnr(unit, gt);
  r.ssim = ssim(unit, gt);
  if (!rs_input.empty()) {
    r.rs_psnr = psnr(rs_input, gt);
    r.rs_ssim = ssim(rs_input, gt);
  }
}

nlohmann::json metric_means(const std::vector<GsFrameRecord>& records) {
  double sp = 0, ss = 0, rp = 0, rs = 0;
  int n = 0, n_rs = 0;
  for (const auto& r : records) {
    if (!r.psnr) continue;
    sp += json_psnr(*r.psnr), ss += *r.ssim, n++;
    if (r.rs_psnr) rp += json_psnr(*r.rs_psnr), rs += *r.rs_ssim, n_rs++;
  }
  if (!n) return {{"count", 0}};
  return {{"count", n}, {"mean_psnr", sp / n}, {"mean_ssim", ss / n},
          {"rs_mean_psnr", n_rs ? rp / n_rs : 0.0}, {"rs_mean_ssim", n_rs ? rs / n_rs : 0.0}};
}

}  // namespace vkunroll
