#include "vkunroll/runtime/trace.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include <unistd.h>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {
constexpr int kGpuTidBase = 100;  // GPU lanes' thread ids, after the host tracks'

std::string number(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3f", v);
  return b;
}

std::string span_args(const GpuSpan& s, double ms) {
  std::ostringstream a;
  a << "{\"op\":\"" << json_escape(s.name) << "\",\"stage\":\"" << json_escape(s.stage) << "\"";
  if (!s.detail.empty()) a << ",\"detail\":\"" << json_escape(s.detail) << "\"";
  if (s.groups[0]) a << ",\"groups\":\"" << s.groups[0] << "x" << s.groups[1] << "x" << s.groups[2] << "\"";
  char ms_text[32];
  std::snprintf(ms_text, sizeof ms_text, "%.6f", ms);
  a << ",\"ms\":" << ms_text;
  if (s.flop > 0) a << ",\"gflop\":" << s.flop * 1e-9 << ",\"gflops\":" << (ms > 0 ? s.flop / (ms * 1e6) : 0.0);
  if (s.bytes > 0) a << ",\"mb\":" << s.bytes * 1e-6 << ",\"gbps\":" << (ms > 0 ? s.bytes / (ms * 1e6) : 0.0);
  a << "}";
  return a.str();
}

std::string span_name(const GpuSpan& s, double ms) {
  std::string n = s.name;
  if (!s.detail.empty()) n += " " + s.detail;
  if (s.flop > 0 && ms > 0) {
    char b[48];
    std::snprintf(b, sizeof b, " %.1f GFLOP/s", s.flop / (ms * 1e6));
    n += b;
  }
  return n;
}
}  // namespace

std::string json_escape(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (unsigned char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += static_cast<char>(c);
    } else if (c < 0x20) {
      char b[8];
      std::snprintf(b, sizeof b, "\\u%04x", c);
      o += b;
    } else {
      o += static_cast<char>(c);
    }
  }
  return o;
}

Trace::Trace() : t0_(Clock::now()) {}

int Trace::track_id(const std::string& track) {
  auto it = tracks_.find(track);
  if (it != tracks_.end()) return it->second;
  const int tid = static_cast<int>(tracks_.size()) + 1;
  tracks_.emplace(track, tid);
  return tid;
}

int Trace::gpu_lane(double ts_us, double end_us) {
  for (size_t l = 0; l < lane_end_us_.size(); ++l)
    if (ts_us >= lane_end_us_[l]) {
      lane_end_us_[l] = end_us;
      return lane_tid_[l];
    }
  lane_end_us_.push_back(end_us);
  lane_tid_.push_back(kGpuTidBase + static_cast<int>(lane_tid_.size()));
  return lane_tid_.back();
}

void Trace::host_span(const std::string& track, const std::string& name, Clock::time_point begin, Clock::time_point end) {
  const double ts = std::chrono::duration<double, std::micro>(begin - t0_).count();
  const double dur = std::max(0.0, std::chrono::duration<double, std::micro>(end - begin).count());
  std::lock_guard<std::mutex> lock(mutex_);
  events_.push_back({track_id(track), name, "{}", ts, dur});
}

void Trace::gpu_submission(Clock::time_point submitted, const std::vector<GpuSpan>& spans) {
  if (spans.empty()) return;
  const double submit_us = std::chrono::duration<double, std::micro>(submitted - t0_).count();
  double first_ns = spans.front().begin_ns;
  for (const GpuSpan& s : spans) first_ns = std::min(first_ns, s.begin_ns);
  std::lock_guard<std::mutex> lock(mutex_);
  // The device cannot start a submission before the host submitted it: raise the offset if it would.
  const double needed = submit_us - first_ns * 1e-3;
  if (!offset_set_ || needed > offset_us_) offset_us_ = needed, offset_set_ = true;
  for (const GpuSpan& s : spans) {
    const double ts = s.begin_ns * 1e-3 + offset_us_;
    const double dur = std::max(0.0, (s.end_ns - s.begin_ns) * 1e-3);
    const double ms = dur * 1e-3;
    events_.push_back({gpu_lane(ts, ts + dur), span_name(s, ms), span_args(s, ms), ts, dur});
    gpu_ms_by_op_[s.name] += ms;
  }
}

std::string Trace::json() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<const Event*> order;
  order.reserve(events_.size());
  for (const Event& e : events_) order.push_back(&e);
  std::stable_sort(order.begin(), order.end(), [](const Event* a, const Event* b) { return a->ts_us < b->ts_us; });
  std::ostringstream o;
  o << "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[\n";
  o << "{\"name\":\"process_name\",\"ph\":\"M\",\"pid\":1,\"tid\":0,\"args\":{\"name\":\"vkunroll\"}}";
  for (const auto& [track, tid] : tracks_)
    o << ",\n{\"name\":\"thread_name\",\"ph\":\"M\",\"pid\":1,\"tid\":" << tid << ",\"args\":{\"name\":\"" << json_escape(track)
      << "\"}}";
  for (size_t l = 0; l < lane_tid_.size(); ++l)
    o << ",\n{\"name\":\"thread_name\",\"ph\":\"M\",\"pid\":1,\"tid\":" << lane_tid_[l] << ",\"args\":{\"name\":\"GPU dispatches"
      << (l ? " (overlapping, lane " + std::to_string(l + 1) + ")" : std::string()) << "\"}}";
  for (const Event* e : order)
    o << ",\n{\"name\":\"" << json_escape(e->name) << "\",\"ph\":\"X\",\"pid\":1,\"tid\":" << e->tid << ",\"ts\":" << number(e->ts_us)
      << ",\"dur\":" << number(e->dur_us) << ",\"args\":" << e->args << "}";
  o << "\n]}\n";
  return o.str();
}

void Trace::write(const std::string& path) const {
  const std::string text = json();
  const std::string tmp = path + ".tmp" + std::to_string(::getpid());
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw IoError(path + ": cannot create " + tmp + ": " + std::strerror(errno));
    f << text;
    f.flush();
    if (!f) {
      std::remove(tmp.c_str());
      throw IoError(path + ": writing " + tmp + " failed: " + std::strerror(errno));
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    std::remove(tmp.c_str());
    throw IoError(path + ": cannot rename " + tmp + " to it: " + why);
  }
}

std::map<std::string, double> Trace::gpu_ms_by_op() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return gpu_ms_by_op_;
}

size_t Trace::spans() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return events_.size();
}

}  // namespace vkunroll
