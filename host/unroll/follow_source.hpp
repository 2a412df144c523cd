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
#include <optional>
#include <vector>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/events/event_stream_follow.hpp"
#include "vkunroll/host/events/meta_schema.hpp"
#include "vkunroll/host/unroll/frame_source.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

// Why the stream stopped before every planned frame was written (what was written is valid and is
// committed; summary.json says why). `requested`: SIGINT, SIGTERM or the caller's close() (status
// stopped, exit 0); `stream`: the stream ended or went idle before a frame's image came (status
// partial, exit 3); `failed`: a bad record under --on-bad error, or a read error (status failed,
// exit 65). docs/follow.md, "How it ends".
struct StreamStopped : Error {
  enum class Kind { requested, stream, failed };
  StreamStopped(const std::string& why, Kind k) : Error(why, ErrorKind::data), kind(k) {}
  Kind kind;
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
  // Whether the last window events() gave was whole: the stream passed its end (an event or a time
  // word later than it) before it ended. A partial window is said per GS frame (FollowSink).
  bool last_window_whole() const { return last_window_whole_; }
  // The stream's record counts as the offline totals count them (dropped by reason, ...).
  EventTotals event_totals() const override;
  // When everything the last frame waited for was there (its image and its events), since the
  // previous call: the start of its latency.
  Clock::time_point take_ready();
  nlohmann::json report() const;

 private:
  void reader_loop();
  void read_into_ring();
  void move_backlog();
  void end_stream(const std::string& why);
  void wait_image(const std::string& path, int k);
  void check_image_rules(const std::string& path, int k);
  void check_image_rules_or_throw(const std::string& path, int k);
  void check_stop(const char* waiting_for) const;

  const Sequence& seq_;
  FollowOptions options_;
  EventStreamFollower follower_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  EventStream ring_;            // events [head_, size) are held: at most max_events (a hard cap)
  size_t head_ = 0;
  EventStream backlog_;         // decoded events the full ring could not take yet (the reader waits)
  size_t backlog_at_ = 0;
  int64_t backlog_clock_ = INT64_MIN;  // the stream clock once the backlog is in the ring
  bool last_window_whole_ = true;
  std::optional<ImageHeader> reference_header_;  // the first frame seen (images-agree, online)
  std::string reference_field_;
  std::map<std::string, int> image_ids_;  // image identity -> frame (distinct-frame-files, online)
  int64_t released_before_ = INT64_MIN;
  uint64_t released_ = 0, peak_ = 0;
  int64_t latest_t_ = INT64_MIN;  // the latest event time read
  bool stream_over_ = false;  // no more reads (end, idle, error); ended_ once the backlog is in the ring
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
  void add(const GsResult& r) override;
  void frame_finished(int frame, size_t done, size_t total) override;
  // Latency per frame (ms): median, p95, max; frames; GS frames per second from the first frame
  // ready to the last written; the frames whose event window was partial.
  nlohmann::json report() const;
  const std::vector<int>& partial_frames() const { return partial_frames_; }

 private:
  ResultSink& inner_;
  FollowFrameSource& source_;
  std::map<int, double> keep_from_;  // frame -> the earliest event time any later frame needs
  std::vector<double> latency_ms_;
  std::vector<int> partial_frames_;
  Clock::time_point first_ready_{}, last_written_{};
  size_t gs_frames_ = 0;
};

// summary.json's "follow" (CLI and Python alike): the stream's counts, latency, partial windows, and
// `status`: complete (every planned GS frame written, every window whole), stopped (on request),
// partial (the stream ended or idled first: frames missing or from partial windows) or failed.
// `stop` is the StreamStopped that ended the job (null: none). Warnings go to `warnings`.
nlohmann::json follow_summary(const FollowFrameSource& source, const FollowSink& sink, const StreamStopped* stop,
                              size_t planned, std::vector<std::string>& warnings);
// The exit code a follow status means (docs/reliability.md, "Exit codes"): complete, stopped 0;
// partial 3; failed 65.
int follow_exit_code(const nlohmann::json& follow);

}  // namespace vkunroll
