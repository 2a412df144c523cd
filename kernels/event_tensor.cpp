#include "kernels/event_tensor.hpp"

#include <algorithm>
#include <cstring>
#include <limits>
#include <string>

#include "runtime/command_stream.hpp"
#include "runtime/context.hpp"
#include "runtime/error.hpp"
#include "runtime/pipeline.hpp"

namespace vkunroll {
namespace {

int128_t gcd128(int128_t a, int128_t b) {
  if (a < 0) a = -a;
  if (b < 0) b = -b;
  while (b) {
    const int128_t t = a % b;
    a = b;
    b = t;
  }
  return a;
}
int128_t floor_div(int128_t a, int128_t b) {  // b > 0
  int128_t q = a / b;
  if ((a % b != 0) && (a < 0)) --q;
  return q;
}
int128_t ceil_div(int128_t a, int128_t b) { return -floor_div(-a, b); }

int128_t abs128(int128_t v) { return v < 0 ? -v : v; }

// a and b of one row over a common denominator, relative to an integer origin:
// a - origin = A / D, b - origin = B / D.
struct ScaledRow {
  int128_t A = 0, B = 0, D = 1;
};
ScaledRow scale_row(const Rational& a, const Rational& b, int64_t origin) {
  const Rational ar = a - Rational(origin), br = b - Rational(origin);
  const int128_t g = gcd128(ar.den(), br.den());
  const int128_t D = ar.den() / g * br.den();
  ScaledRow r;
  r.D = D;
  r.A = ar.num() * (D / ar.den());
  r.B = br.num() * (D / br.den());
  // Headroom for T*D and |T-A|*N below: keep every quantity under 2^100.
  const int128_t lim = static_cast<int128_t>(1) << 100;
  if (abs128(r.A) > lim || abs128(r.B) > lim || D > (static_cast<int128_t>(1) << 64))
    throw Error("event tensor: row times " + a.str() + " / " + b.str() +
                " need denominators beyond 2^64 us; give timing with simpler fractions");
  return r;
}

void check_jobs(const EventStream& events, const std::vector<RowIntervals>& jobs) {
  for (size_t j = 0; j < jobs.size(); ++j) {
    if (jobs[j].a.size() != static_cast<size_t>(events.height) || jobs[j].b.size() != static_cast<size_t>(events.height))
      throw Error("event tensor: job " + std::to_string(j) + " has " + std::to_string(jobs[j].a.size()) + "/" +
                  std::to_string(jobs[j].b.size()) + " row times, the sensor has " + std::to_string(events.height) +
                  " rows");
  }
}

void check_spec(const EventTensorSpec& spec) {
  if (spec.bins < 1 || spec.bins > 4096)
    throw Error("event tensor: bins must be in [1, 4096], got " + std::to_string(spec.bins));
}

RowIntervals intervals(const EventTensorPair& pair, int which) {
  const RowTiming& tm = pair.timing;
  tm.validate("event tensor pair");
  RowIntervals r;
  r.a.assign(tm.rows, pair.target_us);
  r.b.resize(tm.rows);
  const Rational texp = pair.target_exposure_us.value_or(tm.exposure);
  for (int y = 0; y < tm.rows; ++y) {
    if (which == 0) r.b[y] = tm.start(y);
    else if (which == 1) r.b[y] = tm.end(y);
    else r.b[y] = pair.target_us + texp;
  }
  return r;
}

struct BinPush {
  uint32_t n_events, jobs, job_begin, bins, width, height;
};
struct ConvertPush {
  uint32_t n;
};

}  // namespace

RowIntervals ev1_intervals(const EventTensorPair& pair) { return intervals(pair, 0); }
RowIntervals ev2_intervals(const EventTensorPair& pair) { return intervals(pair, 1); }
RowIntervals ev3_intervals(const EventTensorPair& pair) { return intervals(pair, 2); }

std::vector<RowIntervals> event_tensor_jobs(const std::vector<EventTensorPair>& pairs) {
  std::vector<RowIntervals> jobs;
  jobs.reserve(pairs.size() * 3);
  for (int which = 0; which < 3; ++which)
    for (const auto& p : pairs) jobs.push_back(intervals(p, which));
  return jobs;
}

SensorCrop resolve_crop(const SensorCrop& c, int sensor_width, int sensor_height) {
  if (sensor_width <= 0 || sensor_height <= 0)
    throw Error("event tensor: sensor size " + std::to_string(sensor_width) + "x" + std::to_string(sensor_height) +
                " is not set");
  if (sensor_width > 32767 || sensor_height > 32767)
    throw Error("event tensor: sensor larger than 32767 pixels is not supported");
  SensorCrop r = c;
  if (r.width == 0) r.width = sensor_width - r.x0;
  if (r.height == 0) r.height = sensor_height - r.y0;
  if (r.x0 < 0 || r.y0 < 0 || r.width <= 0 || r.height <= 0 || r.x0 + r.width > sensor_width ||
      r.y0 + r.height > sensor_height)
    throw Error("event tensor: crop x0=" + std::to_string(c.x0) + " y0=" + std::to_string(c.y0) + " w=" +
                std::to_string(c.width) + " h=" + std::to_string(c.height) + " is not inside the " +
                std::to_string(sensor_width) + "x" + std::to_string(sensor_height) + " sensor");
  return r;
}

std::pair<int64_t, int64_t> event_time_window(const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec,
                                              int sensor_width, int sensor_height) {
  check_spec(spec);
  const SensorCrop c = resolve_crop(spec.crop, sensor_width, sensor_height);
  int64_t lo = std::numeric_limits<int64_t>::max(), hi = std::numeric_limits<int64_t>::min();
  for (size_t j = 0; j < jobs.size(); ++j) {
    if (jobs[j].a.size() != static_cast<size_t>(sensor_height) || jobs[j].b.size() != static_cast<size_t>(sensor_height))
      throw Error("event tensor: job " + std::to_string(j) + " row count does not match the sensor");
    for (int r = 0; r < c.height; ++r) {
      const Rational &a = jobs[j].a[c.y0 + r], &b = jobs[j].b[c.y0 + r];
      if (a == b) continue;
      lo = std::min(lo, std::min(a, b).ceil());
      hi = std::max(hi, std::max(a, b).ceil());
    }
  }
  if (lo >= hi) return {0, 0};
  return {lo, hi};
}

// ---- CPU reference ----------------------------------------------------------------------------

std::vector<float> bin_events_cpu(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                  const EventTensorSpec& spec) {
  check_spec(spec);
  check_jobs(events, jobs);
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  const int N = spec.bins;
  const size_t plane = static_cast<size_t>(c.width) * c.height, slice = 2 * N * plane;
  std::vector<float> out(jobs.size() * slice, 0.f);
  // The literal formula needs no origin; one is used only to keep the 128-bit products small.
  const int64_t origin = events.empty() ? 0 : events.t.front();
  for (size_t j = 0; j < jobs.size(); ++j) {
    std::vector<ScaledRow> rows(c.height);
    int64_t t_lo = std::numeric_limits<int64_t>::max(), t_hi = std::numeric_limits<int64_t>::min();
    for (int r = 0; r < c.height; ++r) {
      const Rational& a = jobs[j].a[c.y0 + r];
      const Rational& b = jobs[j].b[c.y0 + r];
      rows[r] = scale_row(a, b, origin);
      if (a != b) {
        t_lo = std::min(t_lo, std::min(a, b).floor());
        t_hi = std::max(t_hi, std::max(a, b).ceil());
      }
    }
    if (t_lo > t_hi) continue;
    // The sorted stream: only events in [floor(min), ceil(max)] can be selected.
    const size_t e0 = std::lower_bound(events.t.begin(), events.t.end(), t_lo) - events.t.begin();
    const size_t e1 = std::upper_bound(events.t.begin(), events.t.end(), t_hi) - events.t.begin();
    float* o = out.data() + j * slice;
    for (size_t i = e0; i < e1; ++i) {
      const int x = events.x[i] - c.x0, y = events.y[i] - c.y0;
      if (x < 0 || y < 0 || x >= c.width || y >= c.height) continue;
      const ScaledRow& R = rows[y];
      if (R.A == R.B) continue;  // empty interval selects nothing
      const int128_t T = static_cast<int128_t>(events.t[i] - origin) * R.D;
      // 1. min(a, b) <= t < max(a, b)
      if (T < std::min(R.A, R.B) || T >= std::max(R.A, R.B)) continue;
      // 2. sign, flipped when t < a
      int s = events.p[i] > 0 ? 1 : -1;
      if (T < R.A) s = -s;
      // 3. k = floor(|t - a| * N / |b - a|), N -> N - 1
      int128_t k = abs128(T - R.A) * N / abs128(R.B - R.A);
      if (k == N) k = N - 1;
      // 4. channel 2k + (s > 0)
      o[(2 * static_cast<size_t>(k) + (s > 0 ? 1 : 0)) * plane + static_cast<size_t>(y) * c.width + x] += 1.f;
    }
  }
  return out;
}

namespace {
EventTensors split_tensors(std::vector<float>&& flat, size_t pairs, const EventTensorSpec& spec, const SensorCrop& c) {
  EventTensors t;
  t.pairs = static_cast<int>(pairs);
  t.bins = spec.bins;
  t.height = c.height;
  t.width = c.width;
  const size_t n = pairs * t.slice();
  t.ev1.assign(flat.begin(), flat.begin() + n);
  t.ev2.assign(flat.begin() + n, flat.begin() + 2 * n);
  t.ev3.assign(flat.begin() + 2 * n, flat.begin() + 3 * n);
  return t;
}
}  // namespace

EventTensors build_event_tensors_cpu(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                     const EventTensorSpec& spec) {
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  for (const auto& p : pairs)
    if (p.timing.rows != events.height)
      throw Error("event tensor: frame timing has " + std::to_string(p.timing.rows) + " rows, the event sensor " +
                  std::to_string(events.height));
  const auto jobs = event_tensor_jobs(pairs);
  auto t = split_tensors(bin_events_cpu(events, jobs, spec), pairs.size(), spec, c);
  std::vector<uint32_t> packed;
  t.events_considered = pack_events(events, plan_binning(events, jobs, spec), packed);
  return t;
}

// ---- GPU host part ---------------------------------------------------------------------------

BinningPlan plan_binning(const EventStream& events, const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec) {
  check_spec(spec);
  check_jobs(events, jobs);
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  BinningPlan plan;
  plan.bins = spec.bins;
  plan.height = c.height;
  plan.width = c.width;
  plan.x0 = c.x0;
  plan.y0 = c.y0;
  plan.jobs = jobs.size();
  const int N = spec.bins, R = plan.record_size();
  // Window: selected t satisfy ceil(min(a,b)) <= t < ceil(max(a,b)).
  int64_t lo = std::numeric_limits<int64_t>::max(), hi = std::numeric_limits<int64_t>::min();
  for (const auto& job : jobs)
    for (int r = 0; r < c.height; ++r) {
      const Rational &a = job.a[c.y0 + r], &b = job.b[c.y0 + r];
      if (a == b) continue;
      lo = std::min(lo, std::min(a, b).ceil());
      hi = std::max(hi, std::max(a, b).ceil());
    }
  plan.records.assign(jobs.size() * c.height * R, 0);
  if (lo >= hi) return plan;  // nothing can be selected
  if (hi - lo >= (int64_t{1} << 31) - 2)
    throw Error("event tensor: the batch spans " + std::to_string(hi - lo) +
                " us, more than 2^31 us (35 min); split the batch");
  plan.origin_us = lo;
  plan.first_event = std::lower_bound(events.t.begin(), events.t.end(), lo) - events.t.begin();
  plan.last_event = std::lower_bound(events.t.begin(), events.t.end(), hi) - events.t.begin();
  for (size_t j = 0; j < jobs.size(); ++j)
    for (int r = 0; r < c.height; ++r) {
      int32_t* rec = plan.records.data() + (j * c.height + r) * R;
      const Rational &a = jobs[j].a[c.y0 + r], &b = jobs[j].b[c.y0 + r];
      if (a == b) continue;  // lo == hi == 0: empty
      const ScaledRow s = scale_row(a, b, lo);
      const int128_t L = abs128(s.B - s.A), DN = s.D * N;
      rec[0] = static_cast<int32_t>(ceil_div(std::min(s.A, s.B), s.D));
      rec[1] = static_cast<int32_t>(ceil_div(std::max(s.A, s.B), s.D));
      if (s.A < s.B) {
        // bin >= k  <=>  t >= ceil(a + k L / N): ascending in k
        for (int k = 1; k < N; ++k) rec[1 + k] = static_cast<int32_t>(ceil_div(s.A * N + k * L, DN));
        rec[N + 1] = 0;
      } else {
        // bin >= k  <=>  t < floor(a - k L / N) + 1 =: f_k (descending in k); stored ascending
        // as f_{N-1}, ..., f_1 so that (N - 1) - #{thresholds <= t} is the bin.
        for (int k = 1; k < N; ++k) rec[1 + (N - k)] = static_cast<int32_t>(floor_div(s.A * N - k * L, DN) + 1);
        rec[N + 1] = 1;
      }
    }
  return plan;
}

size_t pack_events(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& packed) {
  packed.clear();
  packed.reserve(2 * (plan.last_event - plan.first_event));
  for (size_t i = plan.first_event; i < plan.last_event; ++i) {
    const int x = events.x[i] - plan.x0, y = events.y[i] - plan.y0;
    if (x < 0 || y < 0 || x >= plan.width || y >= plan.height) continue;
    packed.push_back(static_cast<uint32_t>(events.t[i] - plan.origin_us));
    packed.push_back(static_cast<uint32_t>(x) | (static_cast<uint32_t>(y) << 15) | (events.p[i] > 0 ? 1u << 30 : 0u));
  }
  return packed.size() / 2;
}

// ---- GPU ---------------------------------------------------------------------------------------

void EventTensorBuilder::record_chunk(CommandStream& cs, const Tensor& packed, size_t n_events, const Tensor& records,
                                      const BinningPlan& plan, size_t job_begin, Tensor& out) {
  const auto& info = ctx_.info();
  const uint32_t jobs = static_cast<uint32_t>(out.shape().n);
  cs.fill(out, 0);
  const Pipeline& bin = ctx_.pipeline("event_tensor_bin", {}, sizeof(BinPush));
  // Events in pieces that fit one binding, at offsets the device accepts.
  const size_t align_ev = std::max<size_t>(1, info.min_storage_buffer_offset_alignment / 8);
  size_t per = std::min<size_t>(info.max_storage_buffer_range / 8, size_t{1} << 28);
  if (max_events_) per = std::min(per, max_events_);
  per = std::max(align_ev, per / align_ev * align_ev);
  for (size_t e0 = 0; e0 < n_events; e0 += per) {
    const size_t n = std::min(per, n_events - e0);
    BinPush push{static_cast<uint32_t>(n), jobs, static_cast<uint32_t>(job_begin), static_cast<uint32_t>(plan.bins),
                 static_cast<uint32_t>(plan.width), static_cast<uint32_t>(plan.height)};
    const uint32_t groups = static_cast<uint32_t>(std::min<size_t>((n + 63) / 64, 8192));
    cs.dispatch(bin, {{packed.range(e0 * 8, n * 8), Access::read}, in(records), inout(out)}, push, {groups},
                {"event_tensor_bin", 0, static_cast<double>(n) * (8 + jobs * 4.0 * (plan.bins + 3))});
  }
  const uint32_t count = static_cast<uint32_t>(out.shape().count());
  const uint32_t groups = std::min<uint32_t>((count + 255) / 256, 8192);
  cs.dispatch(ctx_.pipeline("event_tensor_to_float", {}, sizeof(ConvertPush)), {inout(out)}, ConvertPush{count},
              {groups}, {"event_tensor_to_float", static_cast<double>(count), 8.0 * count});
}

std::vector<float> EventTensorBuilder::bin(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                           const EventTensorSpec& spec) {
  const BinningPlan plan = plan_binning(events, jobs, spec);
  std::vector<uint32_t> packed;
  const size_t n_events = pack_events(events, plan, packed);
  last_events_ = n_events;
  const size_t slice = static_cast<size_t>(2 * plan.bins) * plan.height * plan.width;
  std::vector<float> result(jobs.size() * slice, 0.f);
  if (jobs.empty()) return result;
  const size_t max_range = ctx_.info().max_storage_buffer_range;
  size_t chunk = max_range / (slice * 4);
  if (max_jobs_ && chunk) chunk = std::min(chunk, max_jobs_);
  if (chunk == 0)
    throw Error("event tensor: one " + std::to_string(2 * plan.bins) + "x" + std::to_string(plan.height) + "x" +
                std::to_string(plan.width) + " tensor exceeds the device's storage-buffer range (" +
                std::to_string(max_range >> 20) + " MiB); use a crop");
  if (packed.empty()) packed.assign(2, 0);  // a valid (never read) binding
  const Binding eb = packed.size() * 4 > max_range ? Binding::ranged : Binding::whole;
  Tensor ev(ctx_, Shape{1, 1, 1, static_cast<int64_t>(packed.size())}, DType::u32, eb);
  ev.upload(packed);
  Tensor rec(ctx_, Shape{1, 1, 1, static_cast<int64_t>(plan.records.size())}, DType::i32);
  rec.upload(plan.records);
  for (size_t j0 = 0; j0 < jobs.size(); j0 += chunk) {
    const size_t nj = std::min(chunk, jobs.size() - j0);
    Tensor out(ctx_, Shape{static_cast<int64_t>(nj), 2 * plan.bins, plan.height, plan.width}, DType::f32);
    CommandStream cs(ctx_, profiler_);
    record_chunk(cs, ev, n_events, rec, plan, j0, out);
    cs.submit_and_wait();
    out.download(result.data() + j0 * slice, nj * slice * 4);
  }
  return result;
}

EventTensors EventTensorBuilder::build(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                       const EventTensorSpec& spec) {
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  for (const auto& p : pairs)
    if (p.timing.rows != events.height)
      throw Error("event tensor: frame timing has " + std::to_string(p.timing.rows) + " rows, the event sensor " +
                  std::to_string(events.height));
  auto t = split_tensors(bin(events, event_tensor_jobs(pairs), spec), pairs.size(), spec, c);
  t.events_considered = last_events_;
  return t;
}

Tensor EventTensorBuilder::build_on_device(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                           const EventTensorSpec& spec) {
  const auto jobs = event_tensor_jobs(pairs);
  const BinningPlan plan = plan_binning(events, jobs, spec);
  std::vector<uint32_t> packed;
  const size_t n_events = pack_events(events, plan, packed);
  last_events_ = n_events;
  const Shape shape{static_cast<int64_t>(jobs.size()), 2 * plan.bins, plan.height, plan.width};
  if (static_cast<uint64_t>(shape.count()) * 4 > ctx_.info().max_storage_buffer_range)
    throw Error("event tensor: " + shape.str() + " exceeds one storage-buffer binding; use fewer pairs or a crop");
  if (packed.empty()) packed.assign(2, 0);
  const Binding eb = packed.size() * 4 > ctx_.info().max_storage_buffer_range ? Binding::ranged : Binding::whole;
  Tensor ev(ctx_, Shape{1, 1, 1, static_cast<int64_t>(packed.size())}, DType::u32, eb);
  ev.upload(packed);
  Tensor rec(ctx_, Shape{1, 1, 1, static_cast<int64_t>(plan.records.size())}, DType::i32);
  rec.upload(plan.records);
  Tensor out(ctx_, shape, DType::f32);
  CommandStream cs(ctx_, profiler_);
  record_chunk(cs, ev, n_events, rec, plan, 0, out);
  cs.submit_and_wait();
  return out;
}

}  // namespace vkunroll
