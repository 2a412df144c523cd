// The output folder of `vkunroll unroll`: a PNG per GS frame, an MP4 of the GS video, a contact
// sheet, metrics.csv and summary.json.
#pragma once
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>

namespace vkunroll {

struct GsFrameRecord {
  int frame = 0;          // RS frame index the result was unrolled from
  double t_us = 0;        // target instant
  double tau = 0;         // normalized target relative to the frame
  std::string file;       // PNG written, relative to the output folder
  std::string gt_file;    // ground truth compared against (empty: none)
  std::optional<double> psnr, ssim, rs_psnr, rs_ssim;  // result vs GT, RS input vs GT
};

struct UnrollOutputOptions {
  double video_fps = 30;
  bool write_video = true;
  int bit_depth = 8;              // PNG depth of the GS frames
  int contact_max_frames = 4;     // rows of the contact sheet
  int contact_max_targets = 6;    // result columns per row
};

class UnrollOutput {
 public:
  UnrollOutput(std::filesystem::path dir, UnrollOutputOptions options = {});
  ~UnrollOutput();

  // `image`: float32 BGR (or gray) in [0, 1] (clamped here). `name` overrides the file name
  // (e.g. the ground-truth file's name). Returns the record, with metrics when `gt` is given.
  GsFrameRecord add(int frame, double t_us, double tau, const cv::Mat& image, const cv::Mat& rs_input,
                    const cv::Mat& gt = {}, const std::string& gt_file = {}, const std::string& name = {});

  // Closes the video, writes contact_sheet.png, metrics.csv and summary.json (`extra` merged in).
  nlohmann::json finish(const nlohmann::json& extra);

  const std::vector<GsFrameRecord>& records() const { return records_; }
  const std::filesystem::path& dir() const { return dir_; }

 private:
  struct ContactRow {
    int frame;
    cv::Mat rs;
    std::vector<cv::Mat> results, gts;
    std::vector<std::string> labels;
  };
  void add_to_contact(int frame, const cv::Mat& rs, const cv::Mat& result, const cv::Mat& gt, const std::string& label);
  void write_contact_sheet() const;

  std::filesystem::path dir_;
  UnrollOutputOptions options_;
  std::unique_ptr<cv::VideoWriter> video_;
  std::vector<GsFrameRecord> records_;
  std::vector<ContactRow> contact_;
};

// "f000012_t+0001234.5us.png": frame and time in the name, sortable.
std::string gs_frame_name(int frame, double t_us);

}  // namespace vkunroll
