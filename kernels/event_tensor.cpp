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

struct BinPush {
  uint32_t n_events, jobs, job_begin, bins, width, height, out_job;
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
    const RowIntervals jobs[2] = {ev1_intervals(pairs[p]), ev2_intervals(pairs[p])};
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

// ---- GPU ---------------------------------------------------------------------------------------

namespace {
struct PixelPush {
  uint32_t jobs, job_begin, width, height, out_job;
};
struct RowPush {
  uint32_t job_begin, bins, width, height, jobs;
};
// Workgroups of the per-row kernels; each loops over (job, row) items. cap 0: one per item.
// An invocation runs at most kRowPiece / 64 = 256 events per item (a CAS loop and two threshold
// steps each, <= ~1,500 loop iterations), so a workgroup takes at most 39 items: lavapipe's 65535
// loop iterations per invocation (see below) are never reached, whatever the cap.
constexpr size_t kRowItemsPerGroup = 39;
uint32_t row_groups(size_t items, uint32_t cap) {
  const size_t wanted = std::clamp<size_t>(items, 1, cap ? cap : std::min<size_t>(items, 65535));
  return static_cast<uint32_t>(std::max(wanted, (items + kRowItemsPerGroup - 1) / kRowItemsPerGroup));
}
constexpr int kMaxPixelBins = 64;  // the per-pixel shader keeps 2N counters per invocation
// lavapipe (llvmpipe) silently stops a shader invocation's loops after 65535 iterations in all
// (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS, shared by every loop of the invocation): a longer loop
// returns a wrong tensor without any error. So every dispatch below bounds the loop iterations of
// one invocation well under that, on every device (the split costs nothing on small inputs).
constexpr size_t kLoopBudget = 60000;
constexpr uint32_t kRowPiece = 16384;        // per_row: events per workgroup (256 per invocation)
// Workgroups along z for the row kernels: each takes the z-th piece of kRowPiece events of every
// (job, row) range; `ranges` holds [begin, end, ...] per range, `stride` words apart, ranges [first, last).
uint32_t row_pieces(const std::vector<uint32_t>& ranges, size_t stride, size_t first, size_t last) {
  uint32_t longest = 1;
  for (size_t k = first; k < last; ++k) longest = std::max(longest, ranges[stride * k + 1] - ranges[stride * k]);
  return (longest + kRowPiece - 1) / kRowPiece;
}
constexpr size_t kEventsPerInvocation = 8;   // per_event: events per invocation per dispatch
constexpr size_t kEventJobsPerDispatch = 64; // per_event: jobs per dispatch (x up to ~17 CAS tries)
}  // namespace

size_t pack_events_by_pixel(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& offsets,
                            std::vector<uint32_t>& packed) {
  const size_t plane = static_cast<size_t>(plan.width) * plan.height;
  offsets.assign(plane + 1, 0);
  for (size_t i = plan.first_event; i < plan.last_event; ++i) {
    const int x = events.x[i] - plan.x0, y = events.y[i] - plan.y0;
    if (x < 0 || y < 0 || x >= plan.width || y >= plan.height) continue;
    ++offsets[static_cast<size_t>(y) * plan.width + x + 1];
  }
  for (size_t i = 0; i < plane; ++i) offsets[i + 1] += offsets[i];
  packed.resize(offsets[plane]);
  std::vector<uint32_t> cursor(offsets.begin(), offsets.end() - 1);
  for (size_t i = plan.first_event; i < plan.last_event; ++i) {
    const int x = events.x[i] - plan.x0, y = events.y[i] - plan.y0;
    if (x < 0 || y < 0 || x >= plan.width || y >= plan.height) continue;
    packed[cursor[static_cast<size_t>(y) * plan.width + x]++] =
        static_cast<uint32_t>(events.t[i] - plan.origin_us) | (events.p[i] > 0 ? 1u << 31 : 0u);
  }
  return packed.size();
}

const char* event_bin_algorithm_name(EventBinAlgorithm a) {
  switch (a) {
    case EventBinAlgorithm::automatic: return "automatic";
    case EventBinAlgorithm::sparse: return "sparse-rows";
    case EventBinAlgorithm::per_row: return "per-row";
    case EventBinAlgorithm::per_event: return "per-event";
    case EventBinAlgorithm::per_pixel: return "per-pixel";
  }
  return "?";
}

size_t pack_events_by_row(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& packed,
                          std::vector<uint32_t>& ranges) {
  std::vector<uint32_t> offsets(static_cast<size_t>(plan.height) + 1, 0);
  for (size_t i = plan.first_event; i < plan.last_event; ++i) {
    const int x = events.x[i] - plan.x0, y = events.y[i] - plan.y0;
    if (x < 0 || y < 0 || x >= plan.width || y >= plan.height) continue;
    ++offsets[y + 1];
  }
  for (int y = 0; y < plan.height; ++y) offsets[y + 1] += offsets[y];
  packed.resize(2 * static_cast<size_t>(offsets[plan.height]));
  std::vector<uint32_t> cursor(offsets.begin(), offsets.end() - 1);
  for (size_t i = plan.first_event; i < plan.last_event; ++i) {
    const int x = events.x[i] - plan.x0, y = events.y[i] - plan.y0;
    if (x < 0 || y < 0 || x >= plan.width || y >= plan.height) continue;
    const size_t k = cursor[y]++;
    packed[2 * k] = static_cast<uint32_t>(events.t[i] - plan.origin_us);
    packed[2 * k + 1] = static_cast<uint32_t>(x) | (events.p[i] > 0 ? 1u << 31 : 0u);
  }
  // First index in the row segment [b, e) whose time is >= v.
  auto lower = [&](uint32_t b, uint32_t e, int32_t v) {
    while (b < e) {
      const uint32_t m = b + (e - b) / 2;
      if (static_cast<int32_t>(packed[2 * m]) < v) b = m + 1;
      else e = m;
    }
    return b;
  };
  const int R = plan.record_size();
  ranges.assign(plan.jobs * plan.height * 2, 0);
  for (size_t j = 0; j < plan.jobs; ++j)
    for (int y = 0; y < plan.height; ++y) {
      const int32_t* rec = plan.records.data() + (j * plan.height + y) * R;
      if (rec[0] >= rec[1]) continue;
      const uint32_t b = lower(offsets[y], offsets[y + 1], rec[0]);
      ranges[2 * (j * plan.height + y)] = b;
      ranges[2 * (j * plan.height + y) + 1] = lower(b, offsets[y + 1], rec[1]);
    }
  return offsets[plan.height];
}

EventTensorBuilder::EventTensorBuilder(Context& ctx, Profiler* profiler) : ctx_(ctx), profiler_(profiler) {}
EventTensorBuilder::~EventTensorBuilder() = default;

Tensor& EventTensorBuilder::reserve_words(Tensor& t, size_t count, DType dtype) {
  count = std::max<size_t>(count, 1);
  if (t.empty() || t.dtype() != dtype || static_cast<size_t>(t.shape().count()) < count) {
    t = Tensor();  // free first so the allocator can reuse the range
    const size_t cap = std::min(count + count / 2, ctx_.info().max_storage_buffer_range / 4);
    t = Tensor(ctx_, Shape{1, 1, 1, static_cast<int64_t>(std::max(cap, count))}, dtype);
  }
  return t;
}

size_t EventTensorBuilder::jobs_per_chunk(const BinningPlan& plan) const {
  const size_t slice = static_cast<size_t>(2 * plan.bins) * plan.height * plan.width;
  const size_t max_range = ctx_.info().max_storage_buffer_range;
  size_t chunk = max_range / (slice * 4);
  if (chunk == 0)
    throw Error("event tensor: one " + std::to_string(2 * plan.bins) + "x" + std::to_string(plan.height) + "x" +
                std::to_string(plan.width) + " tensor exceeds the device's storage-buffer range (" +
                std::to_string(max_range >> 20) + " MiB); use a crop");
  if (max_jobs_) chunk = std::min(chunk, max_jobs_);
  return chunk;
}

void EventTensorBuilder::execute(const EventStream& events, const BinningPlan& plan,
                                 const std::vector<std::pair<size_t, size_t>>& chunks,
                                 const std::function<void(size_t, Tensor&)>& done, bool allow_sparse) {
  const auto& info = ctx_.info();
  const size_t max_range = info.max_storage_buffer_range;
  const size_t plane = static_cast<size_t>(plan.width) * plan.height;
  const size_t window = plan.last_event - plan.first_event;
  // Automatic: sparse, else per_row. On lavapipe a dense pass over the output (the zero fill:
  // 34.5 MB for one pair at 346x260, N = 16) costs as much as the binning itself, so the sparse
  // path, which only undoes the previous build's cells, wins; per_row reads only selected events
  // with a uniform row record.
  if (algorithm_ == EventBinAlgorithm::sparse && !allow_sparse)
    throw Error("event tensor: the sparse algorithm keeps its output; use build, bin or build_resident");
  if ((algorithm_ == EventBinAlgorithm::automatic && allow_sparse) || algorithm_ == EventBinAlgorithm::sparse) {
    if (execute_sparse(events, plan, chunks, done, nullptr)) {
      last_algorithm_ = EventBinAlgorithm::sparse;
      return;
    }
    if (algorithm_ == EventBinAlgorithm::sparse)
      throw Error("event tensor: the sparse algorithm needs the window's events and its undo list in one binding");
  }
  EventBinAlgorithm algo = algorithm_ == EventBinAlgorithm::automatic ? EventBinAlgorithm::per_row : algorithm_;
  if (algo == EventBinAlgorithm::per_pixel &&
      !(plan.bins <= kMaxPixelBins && window * 4 <= max_range && (plane + 1) * 4 <= max_range))
    throw Error("event tensor: the per-pixel algorithm needs N <= 64 and the window's events in one binding");
  if (algo == EventBinAlgorithm::per_row && window * 8 > max_range) {
    if (algorithm_ == EventBinAlgorithm::per_row)
      throw Error("event tensor: the per-row algorithm needs the window's events in one binding");
    algo = EventBinAlgorithm::per_event;
  }
  const bool per_pixel = algo == EventBinAlgorithm::per_pixel;
  last_algorithm_ = algo;
  Tensor rec(ctx_, Shape{1, 1, 1, static_cast<int64_t>(std::max<size_t>(1, plan.records.size()))}, DType::i32);
  if (!plan.records.empty()) rec.upload(plan.records);
  else rec.upload(std::vector<int32_t>{0});

  if (per_pixel) {
    std::vector<uint32_t> offsets, packed;
    last_events_ = pack_events_by_pixel(events, plan, offsets, packed);
    if (packed.empty()) packed.push_back(0);  // a valid (never read) binding
    Tensor off(ctx_, Shape{1, 1, 1, static_cast<int64_t>(offsets.size())}, DType::u32);
    off.upload(offsets);
    Tensor ev(ctx_, Shape{1, 1, 1, static_cast<int64_t>(packed.size())}, DType::u32);
    ev.upload(packed);
    const Pipeline& pipe = kernel_pipeline(ctx_, "event_tensor_pixels", {static_cast<uint32_t>(plan.bins)}, sizeof(PixelPush));
    const uint32_t groups = static_cast<uint32_t>(std::min<size_t>((plane + 63) / 64, 65535));
    // Loop iterations of one invocation per job: its pixels (grid stride) x (events + 4N).
    size_t busiest = 0, busiest_pixel = 0;
    for (size_t k = 0; k < plane; ++k)
      if (offsets[k + 1] - offsets[k] > busiest) busiest = offsets[k + 1] - offsets[k], busiest_pixel = k;
    const size_t per_job = (plane + size_t{groups} * 64 - 1) / (size_t{groups} * 64) * (busiest + 4 * plan.bins + 2);
    if (per_job > kLoopBudget)
      throw Error("event tensor: the per-pixel algorithm cannot bin pixel (x=" +
                  std::to_string(plan.x0 + busiest_pixel % plan.width) + ", y=" +
                  std::to_string(plan.y0 + busiest_pixel / plan.width) + ") with " + std::to_string(busiest) +
                  " events in the window: one invocation would loop more than " + std::to_string(kLoopBudget) +
                  " times (lavapipe ends shader loops after 65535); use the per-row algorithm");
    const size_t jobs_per_dispatch = std::max<size_t>(1, kLoopBudget / per_job);
    for (const auto& [j0, nj] : chunks) {
      Tensor dst(ctx_, Shape{static_cast<int64_t>(nj), 2 * plan.bins, plan.height, plan.width}, DType::f32);
      CommandStream cs(ctx_, profiler_);
      for (size_t js = 0; js < nj; js += jobs_per_dispatch) {
        const size_t n = std::min(jobs_per_dispatch, nj - js);
        PixelPush push{static_cast<uint32_t>(n), static_cast<uint32_t>(j0 + js), static_cast<uint32_t>(plan.width),
                       static_cast<uint32_t>(plan.height), static_cast<uint32_t>(js)};
        cs.dispatch(pipe, {in(off), in(ev), in(rec), vkunroll::out(dst)}, push, {groups},
                    {"event_tensor_pixels", 0, 4.0 * (plane + window * n) + 4.0 * plane * 2 * plan.bins * n});
      }
      cs.submit_and_wait();
      done(j0, dst);
    }
    return;
  }

  if (algo == EventBinAlgorithm::per_row) {
    std::vector<uint32_t> packed, ranges;
    last_events_ = pack_events_by_row(events, plan, packed, ranges);
    if (packed.empty()) packed.assign(2, 0);  // a valid (never read) binding
    Tensor ev(ctx_, Shape{1, 1, 1, static_cast<int64_t>(packed.size())}, DType::u32);
    ev.upload(packed);
    Tensor rg(ctx_, Shape{1, 1, 1, static_cast<int64_t>(ranges.size())}, DType::u32);
    rg.upload(ranges);
    const Pipeline& pipe = kernel_pipeline(ctx_, "event_tensor_rows", {}, sizeof(RowPush));
    const uint32_t pieces = row_pieces(ranges, 2, 0, ranges.size() / 2);  // <= 1024 for the 16M-event window
    for (const auto& [j0, nj] : chunks) {
      Tensor dst(ctx_, Shape{static_cast<int64_t>(nj), 2 * plan.bins, plan.height, plan.width}, DType::f32);
      CommandStream cs(ctx_, profiler_);
      cs.fill(dst, 0);
      RowPush push{static_cast<uint32_t>(j0), static_cast<uint32_t>(plan.bins), static_cast<uint32_t>(plan.width),
                   static_cast<uint32_t>(plan.height), static_cast<uint32_t>(nj)};
      cs.dispatch(pipe, {in(ev), in(rec), in(rg), inout(dst)}, push,
                  {row_groups(nj * plan.height, row_workgroups_), 1, pieces},
                  {"event_tensor_rows", 0, 12.0 * last_events_ * nj});
      cs.submit_and_wait();
      done(j0, dst);
    }
    return;
  }

  std::vector<uint32_t> packed;
  const size_t n_events = pack_events(events, plan, packed);
  last_events_ = n_events;
  if (packed.empty()) packed.assign(2, 0);
  const Binding eb = packed.size() * 4 > max_range ? Binding::ranged : Binding::whole;
  Tensor ev(ctx_, Shape{1, 1, 1, static_cast<int64_t>(packed.size())}, DType::u32, eb);
  ev.upload(packed);
  const Pipeline& bin = kernel_pipeline(ctx_, "event_tensor_bin", {}, sizeof(BinPush));
  // Events in pieces that fit one binding, at offsets the device accepts.
  const size_t align_ev = std::max<size_t>(1, info.min_storage_buffer_offset_alignment / 8);
  size_t per = std::min<size_t>(max_range / 8, 8192 * 64 * kEventsPerInvocation);
  if (max_events_) per = std::min(per, max_events_);
  per = std::max(align_ev, per / align_ev * align_ev);
  for (const auto& [j0, nj] : chunks) {
    Tensor out(ctx_, Shape{static_cast<int64_t>(nj), 2 * plan.bins, plan.height, plan.width}, DType::f32);
    CommandStream cs(ctx_, profiler_);
    cs.fill(out, 0);
    for (size_t e0 = 0; e0 < n_events; e0 += per)
      for (size_t js = 0; js < nj; js += kEventJobsPerDispatch) {
        const size_t n = std::min(per, n_events - e0), jn = std::min(kEventJobsPerDispatch, nj - js);
        BinPush push{static_cast<uint32_t>(n), static_cast<uint32_t>(jn), static_cast<uint32_t>(j0 + js),
                     static_cast<uint32_t>(plan.bins), static_cast<uint32_t>(plan.width),
                     static_cast<uint32_t>(plan.height), static_cast<uint32_t>(js)};
        const uint32_t groups = static_cast<uint32_t>(std::min<size_t>((n + 63) / 64, 8192));
        cs.dispatch(bin, {{ev.range(e0 * 8, n * 8), Access::read}, in(rec), inout(out)}, push, {groups},
                    {"event_tensor_bin", 0, static_cast<double>(n) * (8 + jn * 4.0 * (plan.bins + 3))});
      }
    cs.submit_and_wait();
    done(j0, out);
  }
}

bool EventTensorBuilder::execute_sparse(const EventStream& events, const BinningPlan& plan,
                                        const std::vector<std::pair<size_t, size_t>>& chunks,
                                        const std::function<void(size_t, Tensor&)>& done, CommandStream* external) {
  const size_t max_words = ctx_.info().max_storage_buffer_range / 4;
  if (2 * (plan.last_event - plan.first_event) > max_words) return false;
  last_events_ = pack_events_by_row(events, plan, packed_, ranges_);
  // (begin, end, undo-list base, 0) per (job, row); bases restart at every chunk's first job.
  const size_t rows = static_cast<size_t>(plan.height);
  ranges4_.resize(plan.jobs * rows * 4);
  std::vector<size_t> touched_n(chunks.size(), 0);
  for (size_t c = 0; c < chunks.size(); ++c) {
    size_t base = 0;
    for (size_t jr = chunks[c].first * rows; jr < (chunks[c].first + chunks[c].second) * rows; ++jr) {
      const uint32_t b = ranges_[2 * jr], e = ranges_[2 * jr + 1];
      ranges4_[4 * jr] = b;
      ranges4_[4 * jr + 1] = e;
      ranges4_[4 * jr + 2] = static_cast<uint32_t>(std::min<size_t>(base, UINT32_MAX));
      ranges4_[4 * jr + 3] = 0;
      base += e - b;
    }
    if (base > max_words) return false;
    touched_n[c] = base;
  }
  if (ranges4_.size() > max_words || plan.records.size() > max_words) return false;

  // A new layout (size, bins or chunks) starts from freshly zeroed outputs.
  std::vector<size_t> layout = {static_cast<size_t>(plan.bins), rows, static_cast<size_t>(plan.width)};
  for (const auto& [j0, nj] : chunks) layout.insert(layout.end(), {j0, nj});
  const bool fresh = layout != sparse_layout_;
  if (fresh) {
    sparse_.clear();
    sparse_layout_.clear();
    sparse_.resize(chunks.size());
  }

  if (!external && !stream_) stream_ = std::make_unique<CommandStream>(ctx_, profiler_);
  CommandStream& cs = external ? *external : *stream_;
  retired_.clear();  // the caller ran (or waited for) what recorded reads of them
  // Into an external stream the uploads are recorded too: ordered, no queue wait on discrete GPUs.
  auto upload = [&](Tensor& t, const void* data, size_t bytes) {
    if (external) cs.upload(t, 0, data, bytes);
    else t.upload_part(0, data, bytes);
  };
  Tensor& ev = reserve_words(events_buf_, packed_.size(), DType::u32);
  upload(ev, packed_.data(), packed_.size() * 4);
  Tensor& rec = reserve_words(records_buf_, plan.records.size(), DType::i32);
  upload(rec, plan.records.data(), plan.records.size() * 4);
  Tensor& rg = reserve_words(ranges_buf_, ranges4_.size(), DType::u32);
  upload(rg, ranges4_.data(), ranges4_.size() * 4);
  const auto words = [](const Tensor& t, size_t n) { return t.range(0, std::max<size_t>(n, 1) * 4); };

  const Pipeline& undo = kernel_pipeline(ctx_, "event_tensor_undo", {}, sizeof(uint32_t));
  const Pipeline& pipe = kernel_pipeline(ctx_, "event_tensor_rows_sparse", {}, sizeof(RowPush));
  std::vector<Tensor>& retired = retired_;  // undo lists replaced by bigger ones, alive until the submit
  try {
  for (size_t c = 0; c < chunks.size(); ++c) {
    const auto [j0, nj] = chunks[c];
    SparseChunk& sc = sparse_[c];
    if (fresh) {
      sc.out = Tensor(ctx_, Shape{static_cast<int64_t>(nj), 2 * plan.bins, plan.height, plan.width}, DType::f32);
      cs.fill(sc.out, 0);
      sc.touched_n = 0;
    } else if (sc.touched_n > 0) {
      const uint32_t n = static_cast<uint32_t>(sc.touched_n);
      cs.dispatch(undo, {{words(sc.touched, sc.touched_n), Access::read}, inout(sc.out)}, n,
                  // Few large workgroups: on lavapipe each workgroup has a fixed cost that 64 stores do not hide.
                  {static_cast<uint32_t>(std::min<size_t>((sc.touched_n + 63) / 64, 32))},
                  {"event_tensor_undo", 0, 8.0 * sc.touched_n});
    }
    if (sc.touched.empty() || static_cast<size_t>(sc.touched.shape().count()) < std::max<size_t>(touched_n[c], 1)) {
      retired.push_back(std::move(sc.touched));
      const size_t cap = std::min(touched_n[c] + touched_n[c] / 2, max_words);
      sc.touched = Tensor(ctx_, Shape{1, 1, 1, static_cast<int64_t>(std::max<size_t>(std::max(cap, touched_n[c]), 1))},
                          DType::u32);
    }
    RowPush push{static_cast<uint32_t>(j0), static_cast<uint32_t>(plan.bins), static_cast<uint32_t>(plan.width),
                 static_cast<uint32_t>(plan.height), static_cast<uint32_t>(nj)};
    const uint32_t pieces = row_pieces(ranges4_, 4, j0 * plan.height, (j0 + nj) * plan.height);
    cs.dispatch(pipe,
                {{words(ev, packed_.size()), Access::read}, {words(rec, plan.records.size()), Access::read},
                 {words(rg, ranges4_.size()), Access::read}, inout(sc.out),
                 {words(sc.touched, touched_n[c]), Access::write}},
                push, {row_groups(nj * plan.height, row_workgroups_), 1, pieces},
                {"event_tensor_rows_sparse", 0, 16.0 * touched_n[c]});
    sc.touched_n = touched_n[c];
  }
    if (!external) cs.submit_and_wait();
  } catch (...) {
    // The outputs' state is unknown now: start from fresh zeros and a fresh stream next time.
    sparse_.clear();
    sparse_layout_.clear();
    stream_.reset();
    throw;
  }
  sparse_layout_ = std::move(layout);
  for (size_t c = 0; c < chunks.size(); ++c) done(chunks[c].first, sparse_[c].out);
  return true;
}

namespace {
// Consecutive job ranges of at most `chunk` jobs that never cross a multiple of `boundary`.
std::vector<std::pair<size_t, size_t>> job_chunks(size_t jobs, size_t chunk, size_t boundary) {
  std::vector<std::pair<size_t, size_t>> out;
  for (size_t j0 = 0; j0 < jobs;) {
    size_t n = std::min(chunk, jobs - j0);
    if (boundary) n = std::min(n, boundary - j0 % boundary);
    out.push_back({j0, n});
    j0 += n;
  }
  return out;
}
}  // namespace

std::vector<float> EventTensorBuilder::bin(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                           const EventTensorSpec& spec) {
  const BinningPlan plan = plan_binning(events, jobs, spec);
  const size_t slice = static_cast<size_t>(2 * plan.bins) * plan.height * plan.width;
  std::vector<float> result(jobs.size() * slice);
  if (jobs.empty()) return result;
  execute(
      events, plan, job_chunks(jobs.size(), jobs_per_chunk(plan), 0),
      [&](size_t j0, Tensor& out) { out.download(result.data() + j0 * slice, static_cast<size_t>(out.shape().count()) * 4); },
      true);
  return result;
}

EventTensors EventTensorBuilder::build(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                       const EventTensorSpec& spec) {
  EventTensors t;
  build(events, pairs, spec, t);
  return t;
}

void EventTensorBuilder::build(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                               const EventTensorSpec& spec, EventTensors& t) {
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  for (const auto& p : pairs)
    if (p.timing.rows != events.height)
      throw Error("event tensor: frame timing has " + std::to_string(p.timing.rows) + " rows, the event sensor " +
                  std::to_string(events.height));
  t.pairs = static_cast<int>(pairs.size());
  t.bins = spec.bins;
  t.height = c.height;
  t.width = c.width;
  t.events_considered = 0;
  const size_t P = pairs.size(), slice = t.slice();
  // resize keeps the storage of a repeated shape: every cell is overwritten below.
  t.ev1.resize(P * slice);
  t.ev2.resize(P * slice);
  t.ev3.resize(P * slice);
  if (P == 0) return;
  const BinningPlan plan = plan_binning(events, event_tensor_jobs(pairs), spec);
  // Chunks stay inside one tensor's jobs, so each downloads straight into ev1, ev2 or ev3.
  std::vector<float>* dst[3] = {&t.ev1, &t.ev2, &t.ev3};
  execute(
      events, plan, job_chunks(3 * P, jobs_per_chunk(plan), P),
      [&](size_t j0, Tensor& out) {
        out.download(dst[j0 / P]->data() + (j0 % P) * slice, static_cast<size_t>(out.shape().count()) * 4);
      },
      true);
  t.events_considered = last_events_;
}

Tensor EventTensorBuilder::build_on_device(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                           const EventTensorSpec& spec) {
  const auto jobs = event_tensor_jobs(pairs);
  const BinningPlan plan = plan_binning(events, jobs, spec);
  const Shape shape{static_cast<int64_t>(jobs.size()), 2 * plan.bins, plan.height, plan.width};
  if (static_cast<uint64_t>(shape.count()) * 4 > ctx_.info().max_storage_buffer_range)
    throw Error("event tensor: " + shape.str() + " exceeds one storage-buffer binding; use fewer pairs or a crop");
  Tensor result;
  execute(events, plan, {{0, jobs.size()}}, [&](size_t, Tensor& out) { result = std::move(out); }, false);
  return result;
}

const Tensor& EventTensorBuilder::build_resident(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                                 const EventTensorSpec& spec) {
  if (pairs.empty()) throw Error("event tensor: build_resident needs at least one pair");
  const auto jobs = event_tensor_jobs(pairs);
  const BinningPlan plan = plan_binning(events, jobs, spec);
  const Shape shape{static_cast<int64_t>(jobs.size()), 2 * plan.bins, plan.height, plan.width};
  if (static_cast<uint64_t>(shape.count()) * 4 > ctx_.info().max_storage_buffer_range)
    throw Error("event tensor: " + shape.str() + " exceeds one storage-buffer binding; use fewer pairs or a crop");
  if (algorithm_ != EventBinAlgorithm::automatic && algorithm_ != EventBinAlgorithm::sparse)
    throw Error(std::string("event tensor: build_resident runs the sparse algorithm, not ") +
                event_bin_algorithm_name(algorithm_));
  if (!execute_sparse(events, plan, {{0, jobs.size()}}, [](size_t, Tensor&) {}, nullptr))
    throw Error("event tensor: build_resident needs the window's events and its undo list in one binding");
  last_algorithm_ = EventBinAlgorithm::sparse;
  return sparse_[0].out;
}

const Tensor& EventTensorBuilder::record_resident(CommandStream& cs, const EventStream& events,
                                                  const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec) {
  if (pairs.empty()) throw Error("event tensor: record_resident needs at least one pair");
  const auto jobs = event_tensor_jobs(pairs);
  const BinningPlan plan = plan_binning(events, jobs, spec);
  const Shape shape{static_cast<int64_t>(jobs.size()), 2 * plan.bins, plan.height, plan.width};
  if (static_cast<uint64_t>(shape.count()) * 4 > ctx_.info().max_storage_buffer_range)
    throw Error("event tensor: " + shape.str() + " exceeds one storage-buffer binding; use fewer pairs or a crop");
  if (!execute_sparse(events, plan, {{0, jobs.size()}}, [](size_t, Tensor&) {}, &cs))
    throw Error("event tensor: the window's " + std::to_string(plan.last_event - plan.first_event) +
                " events and their undo list must fit one storage-buffer binding; use a crop or tiles");
  last_algorithm_ = EventBinAlgorithm::sparse;
  return sparse_[0].out;
}

}  // namespace vkunroll
