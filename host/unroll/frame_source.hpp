// Where an unroll job's frames come from: a sequence folder (the CLI, Python's Sequence) or images
// and events in memory (Python arrays). The job (host/unroll/unroll_job.hpp) asks a source for the
// frames' timing, each image it needs, and each frame's event window; nothing else.
#pragma once
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "vkunroll/base/events.hpp"
#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll {

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // The frames' timing, the sensor's size and the ground-truth instants: what the planner reads
  // (image paths are empty for arrays).
  virtual const Sequence& layout() const = 0;
  // Frame k's image, decoded: BGR float32 in [0, 1], the sensor's size. Errors name the file.
  virtual cv::Mat decode_frame(int k) = 0;
  // Ground truth j's image, as decode_frame.
  virtual cv::Mat decode_ground_truth(int j) = 0;
  // The events of [lo, hi] microseconds, both ends included.
  virtual EventStream events(double lo, double hi) = 0;
  // The frames' encoding gamma the source records (a sequence's meta.json), else 1.
  virtual double recorded_gamma() const = 0;
  // After the last window: decodes what no window read, so the record rules (time order above all)
  // hold over the whole stream and the totals count every record (a sequence's files; no-op else).
  virtual void read_events_to_end() {}
  // Every record the source decoded, counted once (a sequence's files; a live stream's records).
  virtual EventTotals event_totals() const { return layout().event_totals(); }
};

// A loaded sequence folder; images and events are read from its files when asked for.
class SequenceFrameSource : public FrameSource {
 public:
  explicit SequenceFrameSource(const Sequence& seq) : seq_(seq) {}
  const Sequence& layout() const override { return seq_; }
  cv::Mat decode_frame(int k) override;
  cv::Mat decode_ground_truth(int j) override;
  EventStream events(double lo, double hi) override;
  double recorded_gamma() const override;
  void read_events_to_end() override { seq_.read_events_to_end(); }

 private:
  const Sequence& seq_;
};

// Frames, their timings, events sorted by t, and (instant, image) ground truth, held in memory.
// The constructor checks that the counts and sizes agree and that the events are sorted
// (Error naming `what`, e.g. "unroll").
class ArrayFrameSource : public FrameSource {
 public:
  ArrayFrameSource(std::vector<cv::Mat> frames, std::vector<RowTiming> timings, EventStream events,
                   std::vector<std::pair<Rational, cv::Mat>> ground_truth, const std::string& what);
  const Sequence& layout() const override { return layout_; }
  cv::Mat decode_frame(int k) override { return frames_.at(size_t(k)); }
  cv::Mat decode_ground_truth(int j) override { return ground_truth_.at(size_t(j)); }
  EventStream events(double lo, double hi) override;
  double recorded_gamma() const override { return 1.0; }

 private:
  std::vector<cv::Mat> frames_, ground_truth_;
  EventStream events_;
  Sequence layout_;
};

}  // namespace vkunroll
