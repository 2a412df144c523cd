#include "vkunroll/host/unroll/follow_source.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

std::atomic<int> g_signal{0};
struct sigaction g_old_int {}, g_old_term {};

extern "C" void on_stop_signal(int sig) {
  g_signal.store(sig);
  std::signal(sig, SIG_DFL);  // a second one kills
}

constexpr int kPollMs = 20;

// Whether a frame file is complete: "" when it exists and, a PNG, ends with its IEND chunk (writers
// that rename into place are always complete; others are waited for); else what it is so far.
std::string frame_file_state(const std::string& path) {
  std::error_code ec;
  const auto st = fs::status(path, ec);
  if (ec || !fs::exists(st)) return "does not exist";
  if (!fs::is_regular_file(st)) return "is not a regular file";
  const uint64_t size = fs::file_size(path, ec);
  const std::string bytes = " (" + std::to_string(size) + " bytes so far)";
  if (ec || size < 8) return "exists but is too short to be an image" + bytes;
  std::ifstream in(path, std::ios::binary);
  char sig[4] = {};
  in.read(sig, 4);
  if (sig[1] != 'P' || sig[2] != 'N' || sig[3] != 'G') return "";
  const uint64_t tail = std::min<uint64_t>(size, 64);
  std::string end(tail, '\0');
  in.seekg(std::streamoff(size - tail));
  in.read(end.data(), std::streamsize(tail));
  if (end.find("IEND") != std::string::npos) return "";
  return "exists but is an incomplete PNG, no IEND chunk at its end" + bytes +
         " (write frames under another name and rename them into place)";
}

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

}  // namespace

InterruptFlag::InterruptFlag() {
  g_signal.store(0);
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, &g_old_int);
  sigaction(SIGTERM, &sa, &g_old_term);
}

InterruptFlag::~InterruptFlag() {
  sigaction(SIGINT, &g_old_int, nullptr);
  sigaction(SIGTERM, &g_old_term, nullptr);
}

bool InterruptFlag::raised() { return g_signal.load() != 0; }
const char* InterruptFlag::signal_name() { return g_signal.load() == SIGTERM ? "SIGTERM" : "SIGINT"; }

FollowFrameSource::FollowFrameSource(const Sequence& seq, const FollowOptions& options)
    : seq_(seq), options_(options), follower_(options.events, seq.event_options) {
  ring_.width = seq.width;
  ring_.height = seq.height;
  reader_ = std::thread([this] { reader_loop(); });
}

FollowFrameSource::~FollowFrameSource() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    quit_ = true;
  }
  cv_.notify_all();
  reader_.join();
}

// The reader thread: bytes -> events into the ring, until the end, an error or quit. The ring never
// holds more than max_events: what a read decoded beyond that waits in the backlog (and the reader
// with it; the writer then waits on the pipe), so the cap is hard and its outcome deterministic.
void FollowFrameSource::reader_loop() {
  try {
    for (;;) {
      {
        std::unique_lock<std::mutex> lock(mu_);
        move_backlog();
        reader_full_ = ring_.size() - head_ >= options_.max_events;
        if (reader_full_) cv_.notify_all();
        cv_.wait(lock, [&] { return quit_ || ring_.size() - head_ < options_.max_events; });
        reader_full_ = false;
        if (quit_) return;
        move_backlog();
        if (backlog_at_ < backlog_.size()) continue;  // the ring filled again
        if (stream_over_) return;                      // everything read is in the ring
      }
      read_into_ring();
    }
  } catch (...) {
    std::lock_guard<std::mutex> lock(mu_);
    reader_error_ = std::current_exception();
    stream_over_ = ended_ = true;
    cv_.notify_all();
  }
}

// One read of the stream into the backlog and, as it takes them, the ring.
void FollowFrameSource::read_into_ring() {
  EventStream batch;
  const auto status = follower_.read_some(kPollMs, batch);
  std::lock_guard<std::mutex> lock(mu_);
  if (status == EventStreamFollower::Status::data) last_news_ = Clock::now();
  backlog_ = std::move(batch), backlog_at_ = 0, backlog_clock_ = follower_.clock_us();
  if (status == EventStreamFollower::Status::end) {
    end_stream("end of stream (" + follower_.name() + " closed)");
  } else if (options_.idle_s > 0 && seconds_since(last_news_) > options_.idle_s) {
    follower_.finish();  // a partial word left is a truncated stream, as at the pipe's end
    std::ostringstream why;
    why << "no new events for " << options_.idle_s << " s (" << opt("follow_idle_s") << ")";
    end_stream(why.str());
  }
  move_backlog();
  cv_.notify_all();
}

// As much of the backlog as the ring takes (under mu_); the clock counts once all of it is in.
void FollowFrameSource::move_backlog() {
  const int64_t before = latest_t_;
  const size_t room = options_.max_events - std::min(options_.max_events, ring_.size() - head_);
  const size_t n = std::min(room, backlog_.size() - backlog_at_);
  for (size_t i = backlog_at_; i < backlog_at_ + n; ++i) ring_.push(backlog_.t[i], backlog_.x[i], backlog_.y[i], backlog_.p[i]);
  if (n) latest_t_ = std::max(latest_t_, ring_.t.back());
  backlog_at_ += n;
  const bool drained = backlog_at_ == backlog_.size();
  if (drained) latest_t_ = std::max(latest_t_, backlog_clock_);
  peak_ = std::max<uint64_t>(peak_, ring_.size() - head_);
  if (latest_t_ != before) arrivals_.push_back({latest_t_, Clock::now()});
  if (drained && stream_over_ && !ended_) ended_ = true;
  if (n || ended_) cv_.notify_all();
}

// Under mu_: no more reads; once the backlog is in the ring the stream has ended and the job
// unrolls what is there (a window the stream did not pass is partial).
void FollowFrameSource::end_stream(const std::string& why) {
  stream_over_ = true;
  end_reason_ = why;
}

void FollowFrameSource::check_stop(const char* waiting_for) const {
  using K = StreamStopped::Kind;
  if (InterruptFlag::raised())
    throw StreamStopped(std::string(InterruptFlag::signal_name()) + " while waiting for " + waiting_for, K::requested);
  if (reader_error_) {
    try {
      std::rethrow_exception(reader_error_);
    } catch (const Error& e) {  // a bad record (--on-bad error) or a read error: what was written stays
      throw StreamStopped(e.text(), K::failed);
    }
  }
  if (options_.stop_requested && options_.stop_requested())
    throw StreamStopped(std::string("stopped by the caller while waiting for ") + waiting_for, K::requested);
}

void FollowFrameSource::wait_image(const std::string& path, int k) {
  const auto since = Clock::now();
  for (std::string state; !(state = frame_file_state(path)).empty();) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      const std::string what = k >= 0 ? "frame " + std::to_string(k) : "ground truth " + std::to_string(-1 - k);
      check_stop(what.c_str());
      const double quiet = std::min(seconds_since(since), seconds_since(last_news_));
      if (options_.idle_s > 0 && (ended_ ? seconds_since(since) : quiet) > options_.idle_s) {
        std::ostringstream why;
        why << what << "'s image " << path << " " << state << " after " << options_.idle_s << " s (" << opt("follow_idle_s") << ")"
            << (ended_ ? "; the stream ended: " + end_reason_ : "");
        throw StreamStopped(why.str(), StreamStopped::Kind::stream);
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(kPollMs));
  }
  ready_ = std::max(ready_, Clock::now());
}

// The schema's image rules, as each image appears (offline they hold for the folder up front):
// images-agree (size, the first frame's channels) and distinct-frame-files (hard links too).
void FollowFrameSource::check_image_rules(const std::string& path, int k) {
  try {
    check_image_rules_or_throw(path, k);
  } catch (const StreamStopped&) {
    throw;
  } catch (const Error& e) {  // refused as offline; the frames written before it stay
    throw StreamStopped(e.text(), StreamStopped::Kind::failed);
  }
}

void FollowFrameSource::check_image_rules_or_throw(const std::string& path, int k) {
  const std::string field = k >= 0 ? "frames[" + std::to_string(k) + "].file" : "ground_truth[" + std::to_string(-1 - k) + "].file";
  const ImageHeader h = check_sequence_image(seq_, path, k >= 0 ? "frame" : "ground-truth");
  if (!reference_header_) reference_header_ = h, reference_field_ = field;
  rule_image_agrees(seq_, field, path, h, *reference_header_, reference_field_);
  if (k < 0) return;
  const auto [it, fresh] = image_ids_.emplace(image_identity(path), k);
  if (!fresh && it->second != k)
    throw MetaSchemaError((fs::path(seq_.root) / "meta.json").string(), field, "\"" + path + "\"",
                          "the same image as frames[" + std::to_string(it->second) + "] (distinct-frame-files: a link to it)");
}

cv::Mat FollowFrameSource::decode_frame(int k) {
  const std::string& path = seq_.frames.at(size_t(k)).image;
  wait_image(path, k);
  check_image_rules(path, k);
  return read_frame_image(path, seq_.width, seq_.height);
}

cv::Mat FollowFrameSource::decode_ground_truth(int j) {
  const std::string& path = seq_.ground_truth.at(size_t(j)).image;
  wait_image(path, -1 - j);
  check_image_rules(path, -1 - j);
  return read_frame_image(path, seq_.width, seq_.height);
}

double FollowFrameSource::recorded_gamma() const { return read_meta_gamma(seq_); }

EventStream FollowFrameSource::events(double lo, double hi) {
  // As a sequence's window: [floor(lo), ceil(hi)] microseconds, complete once a later event came.
  const int64_t b = static_cast<int64_t>(std::floor(lo)), e = static_cast<int64_t>(std::ceil(hi));
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    check_stop("events");
    if (latest_t_ > e || ended_) break;
    if (reader_full_)
      throw DataError(opt("follow_max_events") + " " + std::to_string(options_.max_events) + ": the window [" + std::to_string(b) +
                      ", " + std::to_string(e) + "] us needs more events than the ring holds; raise it");
    cv_.wait_for(lock, std::chrono::milliseconds(kPollMs));
  }
  if (b < released_before_)
    throw InternalError("internal: events before " + std::to_string(released_before_) + " us were released, the window starts at " +
                std::to_string(b) + " us");
  last_window_whole_ = latest_t_ > e;  // else the stream ended inside (or before) the window
  // When the stream first passed the window's end (the reader logged each read).
  auto when = std::upper_bound(arrivals_.begin(), arrivals_.end(), e,
                               [](int64_t t, const std::pair<int64_t, Clock::time_point>& a) { return t < a.first; });
  ready_ = std::max(ready_, when != arrivals_.end() ? when->second : Clock::now());
  const auto t0 = ring_.t.begin() + long(head_);
  const size_t i0 = size_t(std::lower_bound(t0, ring_.t.end(), b) - ring_.t.begin());
  const size_t i1 = size_t(std::upper_bound(t0, ring_.t.end(), e) - ring_.t.begin());
  EventStream w;
  w.width = seq_.width;
  w.height = seq_.height;
  w.t.assign(ring_.t.begin() + long(i0), ring_.t.begin() + long(i1));
  w.x.assign(ring_.x.begin() + long(i0), ring_.x.begin() + long(i1));
  w.y.assign(ring_.y.begin() + long(i0), ring_.y.begin() + long(i1));
  w.p.assign(ring_.p.begin() + long(i0), ring_.p.begin() + long(i1));
  return w;
}

void FollowFrameSource::release_before(double t_us) {
  std::lock_guard<std::mutex> lock(mu_);
  const int64_t t = static_cast<int64_t>(std::floor(t_us));
  if (t <= released_before_) return;
  released_before_ = t;
  const size_t cut = size_t(std::lower_bound(ring_.t.begin() + long(head_), ring_.t.end(), t) - ring_.t.begin());
  released_ += cut - head_;
  head_ = cut;
  if (head_ > (1u << 16) && head_ * 2 > ring_.size()) {  // compact: the ring's memory stays bounded
    ring_.t.erase(ring_.t.begin(), ring_.t.begin() + long(head_));
    ring_.x.erase(ring_.x.begin(), ring_.x.begin() + long(head_));
    ring_.y.erase(ring_.y.begin(), ring_.y.begin() + long(head_));
    ring_.p.erase(ring_.p.begin(), ring_.p.begin() + long(head_));
    head_ = 0;
  }
  auto keep = std::lower_bound(arrivals_.begin(), arrivals_.end(), t,
                               [](const std::pair<int64_t, Clock::time_point>& a, int64_t v) { return a.first < v; });
  arrivals_.erase(arrivals_.begin(), keep);
  cv_.notify_all();
}

Clock::time_point FollowFrameSource::take_ready() {
  const Clock::time_point r = ready_;
  ready_ = {};
  return r;
}

nlohmann::json FollowFrameSource::report() const {
  std::lock_guard<std::mutex> lock(mu_);
  const EventReadReport& r = follower_.report();
  return {{"events_source", follower_.name()},
          {"pipe", follower_.is_pipe()},
          {"bytes_read", follower_.bytes_read()},
          {"records", r.records},
          {"events_kept", r.kept},
          {"events_dropped", r.dropped()},
          {"stream_clock_us", follower_.clock_us() == INT64_MIN ? nlohmann::json() : nlohmann::json(follower_.clock_us())},
          {"events_released", released_},
          {"ring_peak_events", peak_},
          {"ring_capacity_events", options_.max_events},
          {"stream_ended", ended_},
          {"end_reason", end_reason_}};
}

EventTotals FollowFrameSource::event_totals() const {
  std::lock_guard<std::mutex> lock(mu_);
  const EventReadReport& r = follower_.report();
  EventTotals t;
  t.records = r.records;
  t.valid = r.records - r.dropped();
  t.dropped_out_of_sensor = r.dropped_out_of_sensor, t.dropped_time_order = r.dropped_time_order;
  t.dropped_nan = r.dropped_nan, t.dropped_unknown_word = r.dropped_unknown_word, t.dropped_bad_polarity = r.dropped_bad_polarity;
  t.size_disagreement = r.size_disagreement;
  return t;
}

FollowSink::FollowSink(ResultSink& inner, FollowFrameSource& source, const UnrollJob& job) : inner_(inner), source_(source) {
  // A frame's window starts at its first row's start or its earliest target (unroll_plan.cpp,
  // frame_window); the minimum over the frames after it is what must stay.
  const Sequence& layout = source.layout();
  double later = INFINITY;
  const std::vector<int>& frames = job.frames();
  for (auto it = frames.rbegin(); it != frames.rend(); ++it) {
    keep_from_[*it] = later;
    double lo = layout.frames[size_t(*it)].timing.first_start().to_double();
    if (auto t = job.targets().find(*it); t != job.targets().end())
      for (const UnrollTarget& u : t->second) lo = std::min(lo, u.t_us.to_double());
    later = std::min(later, lo);
  }
}

void FollowSink::add(const GsResult& r) {
  if (source_.last_window_whole() || r.reused) return inner_.add(r);
  if (partial_frames_.empty() || partial_frames_.back() != r.frame) partial_frames_.push_back(r.frame);
  GsResult partial = r;
  partial.events_window = "partial";
  inner_.add(partial);
}

void FollowSink::frame_finished(int frame, size_t done, size_t total) {
  inner_.frame_finished(frame, done, total);
  const Clock::time_point now = Clock::now(), ready = source_.take_ready();
  if (ready != Clock::time_point{}) {
    latency_ms_.push_back(std::chrono::duration<double, std::milli>(now - ready).count());
    if (first_ready_ == Clock::time_point{}) first_ready_ = ready;
  }
  last_written_ = now;
  gs_frames_ = done;
  if (auto k = keep_from_.find(frame); k != keep_from_.end() && std::isfinite(k->second)) source_.release_before(k->second);
}

nlohmann::json FollowSink::report() const {
  nlohmann::json j = {{"frames", latency_ms_.size()}, {"gs_frames", gs_frames_}};
  if (latency_ms_.empty()) return j;
  std::vector<double> l = latency_ms_;
  std::sort(l.begin(), l.end());
  auto at = [&](double q) { return l[std::min(l.size() - 1, size_t(q * double(l.size())))]; };
  j["latency_ms"] = {{"median", at(0.5)}, {"p95", at(0.95)}, {"max", l.back()}};
  const double span_s = std::chrono::duration<double>(last_written_ - first_ready_).count();
  if (span_s > 0) j["gs_frames_per_s"] = double(gs_frames_) / span_s;
  return j;
}

nlohmann::json follow_summary(const FollowFrameSource& source, const FollowSink& sink, const StreamStopped* stop,
                              size_t planned, std::vector<std::string>& warnings) {
  nlohmann::json j = source.report();
  j.update(sink.report());
  j["gs_frames_planned"] = planned;
  j["partial_window_frames"] = sink.partial_frames();
  const size_t written = j["gs_frames"].get<size_t>();
  using K = StreamStopped::Kind;
  std::string status = "complete";
  if (stop) status = stop->kind == K::requested ? "stopped" : stop->kind == K::failed ? "failed" : "partial";
  if (!sink.partial_frames().empty() && status != "failed") status = "partial";
  j["status"] = status;
  j["stopped_because"] = stop ? nlohmann::json(stop->text()) : nlohmann::json();
  if (!sink.partial_frames().empty()) {
    std::string list;
    for (size_t i = 0; i < sink.partial_frames().size(); ++i) list += (i ? ", " : "") + std::to_string(sink.partial_frames()[i]);
    warnings.push_back(opt("follow") + ": the stream ended (" + j.value("end_reason", std::string("?")) + ") inside the event window of " +
                       std::to_string(sink.partial_frames().size()) + " frame(s) (" + list +
                       "): their GS frames were computed from part of their events (events_window \"partial\" in gs_frames)");
  }
  if (stop && stop->kind != K::requested) warnings.push_back(opt("follow") + ": " + status + ": " + stop->text() + "; " + std::to_string(written) + " of " +
                               std::to_string(planned) + " GS frame(s) written");
  return j;
}

int follow_exit_code(const nlohmann::json& follow) {
  const std::string status = follow.value("status", std::string("complete"));
  if (status == "partial") return 3;
  if (status == "failed") return 65;
  return 0;
}

}  // namespace vkunroll
