// `unroll --follow` (docs/follow.md): a FrameSource over a live recording. meta.json lists the
// frames' timing up front; each frame's image appears in the folder when the camera writes it, and
// the events come from a pipe or a growing file (EVT 3.0), read by a thread into a bounded ring.
// decode_frame() waits for the image, events() until the stream has passed the window's end; the
// job (UnrollJob) runs unchanged on top. The stream ends at EOF of a pipe or after idle_s without
// news; SIGINT (InterruptFlag) stops the waits: both throw StreamStopped.
#pragma once
#include <atomic>
#include <condition_variable>
#include <exception>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/events/event_stream_follow.hpp"
#include "vkunroll/host/unroll/frame_source.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

// Why the stream stopped before every planned frame was written (not an error: what was written
// is valid and summary.json says stopped).
struct StreamStopped : Error {
  explicit StreamStopped(const std::string& why) : Error(why, ErrorKind::data) {}
};

// SIGINT and SIGTERM set a flag while this lives (a second signal kills as usual).
class InterruptFlag {
 public:
  InterruptFlag();
  ~InterruptFlag();
  static bool raised();
  static const char* signal_name();
};

class FollowFrameSource : public FrameSource {
 public:
  FollowFrameSource(const Sequence& seq, const FollowOptions& options);
  ~FollowFrameSource() override;
  const Sequence& layout() const override { return seq_; }
  cv::Mat decode_frame(int k) override;
  cv::Mat decode_ground_truth(int j) override;
  EventStream events(double lo, double hi) override;
  double recorded_gamma() const override;

  // Events before t_us are no longer needed (every later frame's window starts at or after it).
  void release_before(double t_us);
  // When everything the last frame waited for was there (its image and its events), since the
  // previous call: the start of its latency.
  Clock::time_point take_ready();
  nlohmann::json report() const;

 private:
  void reader_loop();
  void wait_image(const std::string& path, int k);
  void check_stop(const char* waiting_for) const;

  const Sequence& seq_;
  FollowOptions options_;
  EventStreamFollower follower_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  EventStream ring_;            // events [head_, size) are held
  size_t head_ = 0;
  int64_t released_before_ = INT64_MIN;
  uint64_t released_ = 0, peak_ = 0;
  int64_t latest_t_ = INT64_MIN;  // the latest event time read
  bool ended_ = false, quit_ = false, reader_full_ = false;
  std::string end_reason_;
  std::exception_ptr reader_error_;
  Clock::time_point last_news_ = Clock::now();
  std::vector<std::pair<int64_t, Clock::time_point>> arrivals_;  // (latest t, when) per read with data
  Clock::time_point ready_{};
  std::thread reader_;
};

// Between the job and the output's sink: after each frame, the events no later frame needs are
// released, and the frame's latency (ready -> written) is noted.
class FollowSink : public ResultSink {
 public:
  FollowSink(ResultSink& inner, FollowFrameSource& source, const UnrollJob& job);
  std::optional<cv::Mat> reusable(int frame, const UnrollTarget& t) override { return inner_.reusable(frame, t); }
  void add(const GsResult& r) override { inner_.add(r); }
  void frame_finished(int frame, size_t done, size_t total) override;
  // Latency per frame (ms): median, p95, max; frames; GS frames per second from the first frame
  // ready to the last written.
  nlohmann::json report() const;

 private:
  ResultSink& inner_;
  FollowFrameSource& source_;
  std::map<int, double> keep_from_;  // frame -> the earliest event time any later frame needs
  std::vector<double> latency_ms_;
  Clock::time_point first_ready_{}, last_written_{};
  size_t gs_frames_ = 0;
};

}  // namespace vkunroll
