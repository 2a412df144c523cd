#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/event_tensor.hpp"

#include <algorithm>
#include <cstring>
#include <limits>
#include <string>

#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {
namespace {


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
  // The window search and the per-row ranges rely on time order; say so instead of binning wrong.
  for (size_t i = 1; i < events.t.size(); ++i)
    if (events.t[i] < events.t[i - 1])
      throw Error("event tensor: the event stream is not sorted by time (event " + std::to_string(i) + " at " +
                  std::to_string(events.t[i]) + " us follows " + std::to_string(events.t[i - 1]) + " us)");
  if (events.x.size() != events.t.size() || events.y.size() != events.t.size() || events.p.size() != events.t.size())
    throw Error("event tensor: the event stream's t, x, y, p arrays differ in length");
  for (size_t j = 0; j < jobs.size(); ++j) {
    if (jobs[j].a.size() != static_cast<size_t>(events.height) || jobs[j].b.size() != static_cast<size_t>(events.height))
      throw Error("event tensor: job " + std::to_string(j) + " has " + std::to_string(jobs[j].a.size()) + "/" +
                  std::to_string(jobs[j].b.size()) + " row times, the sensor has " + std::to_string(events.height) +
                  " rows");
  }
}

// Counts are float32 (the network's input type; the GPU adds 1.0 through a 32-bit CAS), and
// float32 holds every integer only up to 2^24: one more event in a cell would be lost silently
// (x + 1 == x). A cell can only exceed 2^24 if its pixel has more than 2^24 events in the window,
// so refuse that (conservatively: the events could spread over bins) instead of miscounting.
// Scans per pixel only when the window itself holds more than 2^24 events.
constexpr size_t kMaxExactCount = size_t{1} << 24;
void check_counts_stay_exact(const EventStream& events, size_t first, size_t last, const SensorCrop& c) {
  if (last <= first || last - first <= kMaxExactCount) return;
  std::vector<uint32_t> per_pixel(static_cast<size_t>(c.width) * c.height, 0);
  for (size_t i = first; i < last; ++i) {
    const int x = events.x[i] - c.x0, y = events.y[i] - c.y0;
    if (x < 0 || y < 0 || x >= c.width || y >= c.height) continue;
    if (++per_pixel[static_cast<size_t>(y) * c.width + x] > kMaxExactCount)
      throw Error("event tensor: pixel (x=" + std::to_string(events.x[i]) + ", y=" + std::to_string(events.y[i]) +
                  ") has more than 2^24 = 16777216 events in the batch's time window (event " + std::to_string(i) +
                  " at " + std::to_string(events.t[i]) +
                  " us); float32 counts are exact only up to 2^24, so the tensor would be wrong. "
                  "Use shorter targets/exposures or check the event stream");
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

}  // namespace

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

std::vector<float> bin_events_ref(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                  const EventTensorSpec& spec) {
  check_spec(spec);
  check_jobs(events, jobs);
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  const int N = spec.bins;
  const size_t plane = static_cast<size_t>(c.width) * c.height, slice = 2 * N * plane;
  std::vector<float> out(jobs.size() * slice, 0.f);
  // The literal formula needs no origin; one is used only to keep the 128-bit products small.
  const int64_t origin = events.empty() ? 0 : events.t.front();
  {
    // Union of the jobs' windows, for the float32 exactness guard.
    const auto [lo, hi] = event_time_window(jobs, spec, events.width, events.height);
    check_counts_stay_exact(events,
                            std::lower_bound(events.t.begin(), events.t.end(), lo) - events.t.begin(),
                            std::lower_bound(events.t.begin(), events.t.end(), hi) - events.t.begin(), c);
  }
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

std::vector<std::vector<uint32_t>> selected_event_counts(const EventStream& events,
                                                         const std::vector<EventTensorPair>& pairs,
                                                         const EventTensorSpec& spec) {
  check_spec(spec);
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  const size_t plane = static_cast<size_t>(c.width) * c.height;
  std::vector<std::vector<uint32_t>> out(pairs.size(), std::vector<uint32_t>(plane, 0));
  for (size_t p = 0; p < pairs.size(); ++p) {
    const RowIntervals jobs[2] = {intervals(pairs[p], 0), intervals(pairs[p], 1)};  // ev1, ev2
    check_jobs(events, {jobs[0], jobs[1]});
    // An integer t is selected iff min(a, b) <= t < max(a, b): ceil(min) <= t < ceil(max).
    std::vector<int64_t> lo(2 * c.height), hi(2 * c.height);
    int64_t t_lo = std::numeric_limits<int64_t>::max(), t_hi = std::numeric_limits<int64_t>::min();
    for (int j = 0; j < 2; ++j)
      for (int r = 0; r < c.height; ++r) {
        const Rational& a = jobs[j].a[c.y0 + r];
        const Rational& b = jobs[j].b[c.y0 + r];
        lo[j * c.height + r] = std::min(a, b).ceil();
        hi[j * c.height + r] = std::max(a, b).ceil();
        if (a != b) t_lo = std::min(t_lo, lo[j * c.height + r]), t_hi = std::max(t_hi, hi[j * c.height + r]);
      }
    if (t_lo >= t_hi) continue;
    const size_t e0 = std::lower_bound(events.t.begin(), events.t.end(), t_lo) - events.t.begin();
    const size_t e1 = std::lower_bound(events.t.begin(), events.t.end(), t_hi) - events.t.begin();
    uint32_t* o = out[p].data();
    for (size_t i = e0; i < e1; ++i) {
      const int x = events.x[i] - c.x0, y = events.y[i] - c.y0;
      if (x < 0 || y < 0 || x >= c.width || y >= c.height) continue;
      const int64_t t = events.t[i];
      o[static_cast<size_t>(y) * c.width + x] += (t >= lo[y] && t < hi[y]) + (t >= lo[c.height + y] && t < hi[c.height + y]);
    }
  }
  return out;
}

EventTensors build_event_tensors_ref(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                     const EventTensorSpec& spec) {
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  for (const auto& p : pairs)
    if (p.timing.rows != events.height)
      throw Error("event tensor: frame timing has " + std::to_string(p.timing.rows) + " rows, the event sensor " +
                  std::to_string(events.height));
  const auto jobs = event_tensor_jobs(pairs);
  auto t = split_tensors(bin_events_ref(events, jobs, spec), pairs.size(), spec, c);
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
  check_counts_stay_exact(events, plan.first_event, plan.last_event, c);
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
      // Estimate of the threshold count: (t - min(a,b)) * N / |b - a| = (t - lo) * sc + c0.
      const double sc = static_cast<double>(N) * static_cast<double>(s.D) / static_cast<double>(L);
      const double c0 = static_cast<double>(static_cast<int128_t>(rec[0]) * s.D - std::min(s.A, s.B)) *
                        static_cast<double>(N) / static_cast<double>(L);
      const float scf = static_cast<float>(sc), c0f = static_cast<float>(c0);
      std::memcpy(&rec[N + 2], &scf, 4);
      std::memcpy(&rec[N + 3], &c0f, 4);
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

}  // namespace vkunroll
