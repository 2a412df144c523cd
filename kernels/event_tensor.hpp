// Row-aware event tensors (reference section 4): ev1, ev2, ev3 for a batch of (frame, target)
// pairs, on the GPU in one pass over the events, and the exact CPU reference.
//
// For one tensor each sensor row y has a source time a[y] and a key time b[y]. An event at row y
// with integer time t is used iff min(a,b) <= t < max(a,b) (a == b: nothing); its sign is +1 for
// p > 0 else -1, flipped when t < a; its bin is k = floor(|t - a| * N / |b - a|), N -> N - 1;
// it adds 1 at channel 2k + (sign > 0), pixel (y, x).
//
// Exactness: a[y] and b[y] are Rationals (base/row_timing.hpp) and event times are integers, so
// every decision above is a comparison of the integer t with a rational. The CPU reference
// evaluates the formula literally in 128-bit integers over a common denominator. The GPU path
// precomputes, per (job, row), the integer thresholds where the answer changes:
//   selected  <=>  ceil(min(a,b)) <= t < ceil(max(a,b))
//   a < b:  bin >= k  <=>  t >= ceil(a + k|b-a|/N)           (k = 1..N-1)
//   a > b:  bin >= k  <=>  t <  floor(a - k|b-a|/N) + 1      (and every selected t < a: flip)
// relative to a batch origin, so the shader only compares 32-bit ints (no int64, no float).
// Both are exact rational arithmetic; they agree with the reference's float64 wherever float64
// represents a[y], b[y] exactly (integer and dyadic times) — see docs/event_tensors.md.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "vkunroll/base/events.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

class Context;
class Profiler;

// A window of the sensor: rows and columns keep their full-sensor coordinates and times.
struct SensorCrop {
  int x0 = 0, y0 = 0;
  int width = 0, height = 0;  // 0: up to the sensor's edge
};

struct EventTensorSpec {
  int bins = 16;     // N: each tensor has 2N channels
  SensorCrop crop;
};

// One tensor's source and key time for every FULL-sensor row (size = sensor height).
struct RowIntervals {
  std::vector<Rational> a, b;
};

// One (RS frame, target) pair.
struct EventTensorPair {
  RowTiming timing;                           // the RS frame's row timing
  Rational target_us;                         // t*
  std::optional<Rational> target_exposure_us;  // ev3's window length; default timing.exposure
};

// Jobs of a batch, tensor-major: ev1 of every pair, then ev2 of every pair, then ev3
// (ev1: a = t*, b = start[y]; ev2: a = t*, b = end[y]; ev3: a = t*, b = t* + target exposure).
std::vector<RowIntervals> event_tensor_jobs(const std::vector<EventTensorPair>& pairs);

// The resolved crop (checked against the sensor; throws Error naming the bad field).
SensorCrop resolve_crop(const SensorCrop& crop, int sensor_width, int sensor_height);

// Float32 tensors [pairs, 2N, h, w] each (crop size h x w).
struct EventTensors {
  int pairs = 0, bins = 0, height = 0, width = 0;
  std::vector<float> ev1, ev2, ev3;
  size_t events_considered = 0;  // events inside the batch's time window (and crop)
  size_t slice() const { return static_cast<size_t>(2 * bins) * height * width; }
};

// The event times a batch needs: [first, last) in microseconds (first >= last: none). Read only
// this window from the event file.
std::pair<int64_t, int64_t> event_time_window(const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec,
                                              int sensor_width, int sensor_height);

// ---- CPU reference ----------------------------------------------------------------------------
// [jobs, 2N, h, w] float32 counts, the section-4 formula evaluated literally and exactly.
std::vector<float> bin_events_ref(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                  const EventTensorSpec& spec);
EventTensors build_event_tensors_ref(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                     const EventTensorSpec& spec);

// Per pair and crop pixel, how many events ev1 and ev2 select together: [pairs][h * w], equal to the
// sum over the channels of ev1 + ev2 (each selected event adds 1 to exactly one channel). What the
// sparse tile policy reads (host/model/tiling.hpp), computed from the events on the host, so the
// device-resident tensors need no readback.
std::vector<std::vector<uint32_t>> selected_event_counts(const EventStream& events,
                                                         const std::vector<EventTensorPair>& pairs,
                                                         const EventTensorSpec& spec);

// ---- GPU ---------------------------------------------------------------------------------------
// The host part of the GPU path, exposed for tests: per (job, crop row) records of N + 4 int32
// [lo, hi, N-1 ascending thresholds, flags(bit0: a > b), s, c (float bits)], relative to
// `origin_us` (s, c: a float estimate j ~ (t - lo) * s + c of the threshold count that the
// shader then corrects exactly against the integer thresholds), and the index
// range [first, last) of the sorted event stream the batch needs (binary search on t).
struct BinningPlan {
  int bins = 0, height = 0, width = 0, x0 = 0, y0 = 0;
  int64_t origin_us = 0;
  size_t first_event = 0, last_event = 0;
  size_t jobs = 0;
  std::vector<int32_t> records;  // [jobs][h][N + 4]
  int record_size() const { return bins + 4; }
};
BinningPlan plan_binning(const EventStream& events, const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec);
// Events of the plan's window inside the crop, packed for the shader: (t - origin, x | y << 15 |
// positive << 30), crop-relative x and y. Returns how many events were packed.
size_t pack_events(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& packed);
// The same events grouped by crop pixel (counting sort, time order kept inside a pixel) for the
// per-pixel shader: offsets[h*w + 1] and words (t - origin) | positive << 31.
size_t pack_events_by_pixel(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& offsets,
                            std::vector<uint32_t>& packed);

// The events of the window grouped by crop row (counting sort, time order kept): offsets[h + 1],
// words (t - origin, x | positive << 31), and for every (job, row) the range [begin, end) of the
// row's events inside [lo, hi) (binary search), ranges[jobs][h][2].
size_t pack_events_by_row(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& packed,
                          std::vector<uint32_t>& ranges);

// sparse (automatic's choice): per_row's kernel into a PERSISTENT output owned by the builder that
//   stays zero between builds: each build first puts back to zero only the cells the previous
//   build counted (a list the kernel writes), then counts. O(selected events) work, no dense fill;
//   the output and every device buffer are reused across calls. Needs the window's events and the
//   undo list in one binding each; otherwise automatic falls back to per_row.
// per_row: (job, row) items, each over exactly the row's selected
//   events; zero fill, then +1.0 on float32 cells through a 32-bit compare-and-swap loop (any N;
//   exact below 2^24 per cell). Needs the window's events in one binding (16M events).
// per_event: one invocation per event looping over jobs, same accumulation; events in pieces of
//   any size (the fallback for bigger windows).
// per_pixel: one invocation per pixel over its own events, writes every float32 cell once, no
//   atomics (N <= 64); dense, so slower on lavapipe; for devices where atomics are expensive.
enum class EventBinAlgorithm { automatic, sparse, per_row, per_event, per_pixel };
const char* event_bin_algorithm_name(EventBinAlgorithm a);  // "per-row", ...

class CommandStream;

class EventTensorBuilder {
 public:
  explicit EventTensorBuilder(Context& ctx, Profiler* profiler = nullptr);
  ~EventTensorBuilder();
  EventTensorBuilder(const EventTensorBuilder&) = delete;
  EventTensorBuilder& operator=(const EventTensorBuilder&) = delete;

  // [jobs, 2N, h, w] float32, identical to bin_events_ref. Splits jobs into chunks that fit one
  // storage-buffer binding; events are uploaded once for all chunks.
  std::vector<float> bin(const EventStream& events, const std::vector<RowIntervals>& jobs,
                         const EventTensorSpec& spec);
  EventTensors build(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                     const EventTensorSpec& spec);
  // The same into `out`, reusing its vectors' storage when the shape repeats (no fresh pages).
  void build(const EventStream& events, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec,
             EventTensors& out);
  // Device-resident through the sparse path: the builder's own persistent f32 tensor
  // [3 * pairs, 2N, h, w] (ev1, ev2, ev3 consecutive, as build_on_device). Read it only; it is
  // valid until the next call on this builder, which overwrites it. Throws if it exceeds one
  // binding or the sparse path cannot run (window beyond one binding).
  const Tensor& build_resident(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                               const EventTensorSpec& spec);
  // build_resident's work recorded into `cs` (uploads included) without submitting: the network's
  // dispatches recorded after it read the result in order. The caller must have run (submitted and
  // waited for) every earlier recording that read this builder's buffers before calling again.
  const Tensor& record_resident(CommandStream& cs, const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                const EventTensorSpec& spec);
  // Device-resident result for the network: one f32 tensor [3 * pairs, 2N, h, w] whose ev1, ev2,
  // ev3 are the consecutive ranges of `pairs` slices each. Throws if it exceeds one binding.
  Tensor build_on_device(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                         const EventTensorSpec& spec);

  // Limits below the device's (0: device limits); tests use them to exercise chunking.
  void set_chunk_limits(size_t max_jobs_per_chunk, size_t max_events_per_dispatch) {
    max_jobs_ = max_jobs_per_chunk;
    max_events_ = max_events_per_dispatch;
  }
  void set_algorithm(EventBinAlgorithm a) { algorithm_ = a; }
  EventBinAlgorithm last_algorithm() const { return last_algorithm_; }
  // Most workgroups the per-row kernels use, each looping over (job, row) items (0: one per
  // item). For the bench's comparison.
  void set_row_workgroups(uint32_t cap) { row_workgroups_ = cap; }

 private:
  // Bins jobs [job_begin, job_begin + out.shape().n) of `plan` into `out` (u32 counts converted
  // to float32 in place).
  // Uploads the plan's events once, then for each chunk [first_job, first_job + count) fills a
  // fresh [count, 2N, h, w] f32 tensor and hands it to `done(first_job, tensor)`.
  // allow_sparse: the caller only reads the chunk tensors (they stay the builder's).
  void execute(const EventStream& events, const BinningPlan& plan,
               const std::vector<std::pair<size_t, size_t>>& chunks,
               const std::function<void(size_t, Tensor&)>& done, bool allow_sparse);
  // execute()'s dense algorithms, reading the plan's uploaded records `rec`.
  void execute_per_pixel(const EventStream& events, const BinningPlan& plan, const std::vector<std::pair<size_t, size_t>>& chunks,
                         const std::function<void(size_t, Tensor&)>& done, const Tensor& rec);
  void execute_per_row(const EventStream& events, const BinningPlan& plan, const std::vector<std::pair<size_t, size_t>>& chunks,
                       const std::function<void(size_t, Tensor&)>& done, const Tensor& rec);
  void execute_per_event(const EventStream& events, const BinningPlan& plan, const std::vector<std::pair<size_t, size_t>>& chunks,
                         const std::function<void(size_t, Tensor&)>& done, const Tensor& rec);
  // The sparse path; false (nothing done) when a buffer would exceed one binding.
  // external: record into that stream without submitting (record_resident).
  bool execute_sparse(const EventStream& events, const BinningPlan& plan,
                      const std::vector<std::pair<size_t, size_t>>& chunks,
                      const std::function<void(size_t, Tensor&)>& done, CommandStream* external);
  size_t jobs_per_chunk(const BinningPlan& plan) const;
  // Reuses `t` when it holds at least `count` u32/i32 words, else replaces it (grown by half).
  Tensor& reserve_words(Tensor& t, size_t count, DType dtype);
  Context& ctx_;
  Profiler* profiler_;
  uint32_t row_workgroups_ = 64;
  std::unique_ptr<CommandStream> stream_;  // reused: no command pool, fence and query pool per call
  // Sparse path state: one persistent output per chunk of the last layout, each zero except at
  // the cells its undo list names.
  struct SparseChunk {
    Tensor out, touched;
    size_t touched_n = 0;
  };
  std::vector<SparseChunk> sparse_;
  std::vector<size_t> sparse_layout_;  // bins, h, w, then (first job, jobs) of every chunk
  std::vector<Tensor> retired_;        // buffers replaced while an external recording may read them
  Tensor events_buf_, records_buf_, ranges_buf_;  // inputs, reused with spare capacity
  std::vector<uint32_t> packed_, ranges_, ranges4_;  // host scratch, reused
  size_t last_events_ = 0;
  size_t max_jobs_ = 0, max_events_ = 0;
  EventBinAlgorithm algorithm_ = EventBinAlgorithm::automatic, last_algorithm_ = EventBinAlgorithm::automatic;
};

}  // namespace vkunroll
