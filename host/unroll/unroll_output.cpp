#include "vkunroll/host/unroll/unroll_output.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

std::string gs_frame_name(int frame, double t_us) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "f%06d_t%+011.1fus.png", frame, t_us);
  return buf;
}

namespace {
cv::Mat to_bgr8(const cv::Mat& m) {
  cv::Mat f = to_unit_float(m), out;
  f.convertTo(out, CV_8U, 255.0);
  if (out.channels() == 1) cv::cvtColor(out, out, cv::COLOR_GRAY2BGR);
  return out;
}
}  // namespace

UnrollOutput::UnrollOutput(fs::path dir, UnrollOutputOptions options) : dir_(std::move(dir)), options_(options) {
  std::error_code ec;
  fs::create_directories(dir_ / "frames", ec);
  if (ec) throw Error("cannot create the output folder " + (dir_ / "frames").string() + ": " + ec.message());
}

UnrollOutput::~UnrollOutput() {
  if (video_) video_->release();
}

GsFrameRecord UnrollOutput::add(int frame, double t_us, double tau, const cv::Mat& image, const cv::Mat& rs_input,
                                const cv::Mat& gt, const std::string& gt_file, const std::string& name) {
  GsFrameRecord r;
  r.frame = frame;
  r.t_us = t_us;
  r.tau = tau;
  r.file = "frames/" + (name.empty() ? gs_frame_name(frame, t_us) : name);
  cv::Mat unit = to_unit_float(image), png;
  if (options_.bit_depth == 16)
    unit.convertTo(png, CV_16U, 65535.0);
  else
    unit.convertTo(png, CV_8U, 255.0);
  if (!cv::imwrite((dir_ / r.file).string(), png)) throw Error("cannot write " + (dir_ / r.file).string());
  if (!gt.empty()) {
    r.gt_file = gt_file;
    r.psnr = psnr(unit, gt);
    r.ssim = ssim(unit, gt);
    if (!rs_input.empty()) {
      r.rs_psnr = psnr(rs_input, gt);
      r.rs_ssim = ssim(rs_input, gt);
    }
  }
  if (options_.write_video) {
    cv::Mat bgr = to_bgr8(image);
    if (!video_) {
      video_ = std::make_unique<cv::VideoWriter>((dir_ / "gs_video.mp4").string(),
                                                 cv::VideoWriter::fourcc('m', 'p', '4', 'v'), options_.video_fps,
                                                 bgr.size());
      if (!video_->isOpened()) throw Error("OpenCV cannot open an MP4 writer for " + (dir_ / "gs_video.mp4").string());
    }
    video_->write(bgr);
  }
  char label[64];
  std::snprintf(label, sizeof label, "t=%.0fus", t_us);
  add_to_contact(frame, rs_input, image, gt, label);
  records_.push_back(r);
  return r;
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

void UnrollOutput::write_contact_sheet() const {
  if (contact_.empty()) return;
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
  cv::imwrite((dir_ / "contact_sheet.png").string(), sheet);
}

nlohmann::json UnrollOutput::finish(const nlohmann::json& extra) {
  if (video_) {
    video_->release();
    video_.reset();
  }
  write_contact_sheet();
  nlohmann::json frames = nlohmann::json::array();
  double sp = 0, ss = 0, rp = 0, rs = 0;
  int n = 0;
  std::ofstream csv(dir_ / "metrics.csv");
  csv << "frame,t_us,tau,file,gt_file,psnr,ssim,rs_psnr,rs_ssim\n";
  for (const auto& r : records_) {
    nlohmann::json j = {{"frame", r.frame}, {"t_us", r.t_us}, {"tau", r.tau}, {"file", r.file}};
    if (r.psnr) {
      j["gt_file"] = r.gt_file;
      j["psnr"] = std::isinf(*r.psnr) ? 100.0 : *r.psnr;  // identical images: JSON has no infinity
      j["ssim"] = *r.ssim;
      if (r.rs_psnr) {
        j["rs_psnr"] = std::isinf(*r.rs_psnr) ? 100.0 : *r.rs_psnr;
        j["rs_ssim"] = *r.rs_ssim;
        rp += j["rs_psnr"].get<double>();
        rs += *r.rs_ssim;
      }
      sp += j["psnr"].get<double>();
      ss += *r.ssim;
      n++;
      csv << r.frame << "," << r.t_us << "," << r.tau << "," << r.file << "," << r.gt_file << "," << j["psnr"] << ","
          << *r.ssim << "," << (r.rs_psnr ? j["rs_psnr"].dump() : "") << "," << (r.rs_ssim ? std::to_string(*r.rs_ssim) : "")
          << "\n";
    }
    frames.push_back(j);
  }
  nlohmann::json summary = extra;
  summary["gs_frames"] = frames;
  summary["outputs"] = {{"frames", "frames/"}, {"contact_sheet", "contact_sheet.png"}, {"metrics", "metrics.csv"}};
  if (options_.write_video && !records_.empty()) summary["outputs"]["video"] = "gs_video.mp4";
  if (n) {
    summary["metrics"] = {{"count", n}, {"mean_psnr", sp / n}, {"mean_ssim", ss / n},
                          {"rs_mean_psnr", rp / n}, {"rs_mean_ssim", rs / n}};
  }
  std::ofstream(dir_ / "summary.json") << summary.dump(2) << "\n";
  return summary;
}

}  // namespace vkunroll
