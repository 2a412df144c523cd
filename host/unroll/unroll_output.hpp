// The output folder of `vkunroll unroll`: a file per GS frame (frames/, PNG or .npy), an MP4 of the
// GS video, a contact sheet, metrics.csv, frames.jsonl (the resume journal) and summary.json.
//
// Fault-safe (host/unroll/output_folder.hpp): everything is written into a staging folder and
// renamed into place by finish(), summary.json last of all; a killed or failed run leaves no
// final-named output. With ExistingOutput::resume, GS frames of an earlier or killed run are
// reused when valid: frames.jsonl lists the frame and instant, the run's resume key, the file's
// size and SHA-256, and the file still has exactly those bytes.
#pragma once
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>

#include "vkunroll/host/unroll/frame_files.hpp"
#include "vkunroll/host/unroll/output_folder.hpp"

namespace vkunroll {

struct GsFrameRecord {
  int frame = 0;          // RS frame index the result was unrolled from
  double t_us = 0;        // target instant
  std::string t_exact;    // the same, exact (a rational in microseconds, e.g. "22500" or "45001/2")
  double tau = 0;         // normalized target relative to the frame
  std::string file;       // frame file written, relative to the output folder
  std::string gt_file;    // ground truth compared against (empty: none)
  std::optional<double> psnr, ssim, rs_psnr, rs_ssim;  // result vs GT, RS input vs GT
  bool reused = false;    // taken from an earlier run (--resume)
  std::string events_window;  // "partial": computed from part of its event window (--follow); empty: whole
};

struct UnrollOutputOptions {
  std::optional<double> video_fps;  // empty: 30 (the unroll job sets 10x slow motion of the recording)
  bool write_video = true;
  FrameFormat frame_format = FrameFormat::png8;
  ExistingOutput existing = ExistingOutput::refuse;
  // What makes a GS frame of an earlier run reusable under --resume: a digest of every option
  // that changes pixels (set by the unroll job); frames written under another key are redone.
  std::string resume_key;
  int contact_max_frames = 4;     // rows of the contact sheet
  int contact_max_targets = 6;    // result columns per row
};

class UnrollOutput {
 public:
  UnrollOutput(std::filesystem::path dir, UnrollOutputOptions options = {});
  ~UnrollOutput();

  // The GS frame file name of (frame, t_us) or `name` (ground-truth instants), in this format.
  std::string file_for(int frame, double t_us, const std::string& name) const;

  // Under resume: the earlier run's image for (frame, t_exact), when valid (see the header), with
  // its record; empty otherwise. The file is brought into the new output; add_reused() then files it.
  std::optional<cv::Mat> find_reusable(int frame, const std::string& t_exact, const std::string& name,
                                       GsFrameRecord* record);
  void add_reused(const GsFrameRecord& record, const cv::Mat& image, const cv::Mat& rs_input, const cv::Mat& gt);

  // `image`: float32 BGR (or gray) in [0, 1] (clamped in PNGs). `name` overrides the file name
  // (e.g. the ground-truth file's name). Returns the record, with metrics when `gt` is given.
  GsFrameRecord add(int frame, double t_us, const std::string& t_exact, double tau, const cv::Mat& image,
                    const cv::Mat& rs_input, const cv::Mat& gt = {}, const std::string& gt_file = {},
                    const std::string& name = {}, const std::string& events_window = {});

  // Closes and checks the video, writes contact_sheet.png, metrics.csv, frames.jsonl and, last,
  // summary.json (`extra` merged in), then renames the folder into place. Throws IoError naming
  // the file on any failed write.
  nlohmann::json finish(const nlohmann::json& extra);

  const std::vector<GsFrameRecord>& records() const { return records_; }
  const std::filesystem::path& dir() const { return folder_.final_dir(); }
  const std::filesystem::path& staging() const { return folder_.staging(); }
  size_t reused_count() const { return reused_; }
  bool replaces_existing() const { return folder_.replaces_existing(); }

 private:
  struct ContactRow {
    int frame;
    cv::Mat rs;
    std::vector<cv::Mat> results, gts;
    std::vector<std::string> labels;
  };
  struct JournalEntry {
    nlohmann::json line;
    std::filesystem::path source;  // the folder holding the file
  };
  void load_journal(const std::filesystem::path& folder);
  void video_frame(const cv::Mat& image);
  void close_video();
  void add_to_contact(int frame, const cv::Mat& rs, const cv::Mat& result, const cv::Mat& gt, const std::string& label);
  std::string contact_sheet_png() const;
  void file_record(const GsFrameRecord& r, const std::string& sha256, size_t bytes, const cv::Mat& image,
                   const cv::Mat& rs_input, const cv::Mat& gt);

  OutputFolder folder_;
  UnrollOutputOptions options_;
  std::unique_ptr<cv::VideoWriter> video_;
  std::string video_codec_;
  size_t video_frames_ = 0;
  std::vector<GsFrameRecord> records_;
  std::vector<std::string> journal_;  // this run's lines, in order
  std::set<std::string> files_;       // frame files used by this run
  std::map<std::string, std::vector<JournalEntry>> earlier_;  // "frame|t_exact" -> candidates
  size_t reused_ = 0;
  std::vector<ContactRow> contact_;
  bool finished_ = false;
};

// The record's PSNR/SSIM against `gt` (the image clamped to [0, 1]), and the RS input's; nothing
// without ground truth. The CLI's folder and Python's arrays score alike.
void score_against_ground_truth(GsFrameRecord& r, const cv::Mat& image, const cv::Mat& rs_input, const cv::Mat& gt,
                                const std::string& gt_file);
// The means over the records with ground truth, PSNR capped at 100 dB as in summary.json:
// {"count": n, "mean_psnr", "mean_ssim", "rs_mean_psnr", "rs_mean_ssim"} ({"count": 0} without any).
nlohmann::json metric_means(const std::vector<GsFrameRecord>& records);

// "f000012_t+0001234.5us.png": frame and time in the name, sortable.
std::string gs_frame_name(int frame, double t_us, const char* extension = ".png");

// One number format for metrics.csv: the shortest decimal that reads back as the same double, never
// in exponent form (Unix-microsecond times stay 1700000000000000, not 1.7e+15); inf, -inf, nan as such.
std::string csv_number(double v);

}  // namespace vkunroll
