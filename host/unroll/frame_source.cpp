#include "vkunroll/host/unroll/frame_source.hpp"

#include <algorithm>
#include <cmath>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

cv::Mat SequenceFrameSource::decode_frame(int k) {
  return read_frame_image(seq_.frames.at(size_t(k)).image, seq_.width, seq_.height);
}

cv::Mat SequenceFrameSource::decode_ground_truth(int j) {
  return read_frame_image(seq_.ground_truth.at(size_t(j)).image, seq_.width, seq_.height);
}

EventStream SequenceFrameSource::events(double lo, double hi) { return read_window(seq_, lo, hi); }

double SequenceFrameSource::recorded_gamma() const { return read_meta_gamma(seq_); }

ArrayFrameSource::ArrayFrameSource(std::vector<cv::Mat> frames, std::vector<RowTiming> timings, EventStream events,
                                   std::vector<std::pair<Rational, cv::Mat>> ground_truth, const std::string& what)
    : frames_(std::move(frames)), events_(std::move(events)) {
  if (frames_.empty()) throw DataError(what + ": no frames");
  if (timings.size() != frames_.size())
    throw DataError(what + ": " + std::to_string(frames_.size()) + " frames but " + std::to_string(timings.size()) +
                    " timings (one per frame)");
  const cv::Size size = frames_.front().size();
  auto check = [&](const cv::Mat& m, const std::string& name) {
    if (m.type() != CV_32FC3 || m.size() != size)
      throw DataError(what + ": " + name + " must be a " + std::to_string(size.width) + "x" + std::to_string(size.height) +
                      " three-channel float image like frame 0");
  };
  for (size_t k = 0; k < frames_.size(); ++k) check(frames_[k], "frame " + std::to_string(k));
  if (!std::is_sorted(events_.t.begin(), events_.t.end()))
    throw DataError(what + ": events must be sorted by t (np.sort(events, order='t'))");
  layout_.width = size.width;
  layout_.height = size.height;
  for (RowTiming& t : timings) layout_.frames.push_back({"", std::move(t)});
  for (size_t j = 0; j < ground_truth.size(); ++j) {
    check(ground_truth[j].second, "ground truth " + std::to_string(j));
    layout_.ground_truth.push_back({"", ground_truth[j].first});
    ground_truth_.push_back(std::move(ground_truth[j].second));
  }
}

EventStream ArrayFrameSource::events(double lo, double hi) {
  // As a sequence's window: [floor(lo), ceil(hi)] microseconds.
  const auto b = std::lower_bound(events_.t.begin(), events_.t.end(), static_cast<int64_t>(std::floor(lo)));
  const auto e = std::upper_bound(events_.t.begin(), events_.t.end(), static_cast<int64_t>(std::ceil(hi)));
  const size_t i0 = size_t(b - events_.t.begin()), i1 = size_t(e - events_.t.begin());
  EventStream w;
  w.width = events_.width;
  w.height = events_.height;
  w.t.assign(events_.t.begin() + i0, events_.t.begin() + i1);
  w.x.assign(events_.x.begin() + i0, events_.x.begin() + i1);
  w.y.assign(events_.y.begin() + i0, events_.y.begin() + i1);
  w.p.assign(events_.p.begin() + i0, events_.p.begin() + i1);
  return w;
}

}  // namespace vkunroll
