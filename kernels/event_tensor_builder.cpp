// The GPU side of the event tensors (kernels/event_tensor.hpp): the packings the shaders read and
// EventTensorBuilder, which records the binning kernels.
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

// ---- GPU ---------------------------------------------------------------------------------------

namespace {
struct BinPush {
  uint32_t n_events, jobs, job_begin, bins, width, height, out_job;
};
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
  last_algorithm_ = algo;
  Tensor rec(ctx_, Shape{1, 1, 1, static_cast<int64_t>(std::max<size_t>(1, plan.records.size()))}, DType::i32);
  if (!plan.records.empty()) rec.upload(plan.records);
  else rec.upload(std::vector<int32_t>{0});
  if (algo == EventBinAlgorithm::per_pixel) execute_per_pixel(events, plan, chunks, done, rec);
  else if (algo == EventBinAlgorithm::per_row) execute_per_row(events, plan, chunks, done, rec);
  else execute_per_event(events, plan, chunks, done, rec);
}

// One invocation per pixel over its events (packed by pixel), at most kLoopBudget loop iterations.
void EventTensorBuilder::execute_per_pixel(const EventStream& events, const BinningPlan& plan,
                                           const std::vector<std::pair<size_t, size_t>>& chunks,
                                           const std::function<void(size_t, Tensor&)>& done, const Tensor& rec) {
  const size_t plane = static_cast<size_t>(plan.width) * plan.height;
  const size_t window = plan.last_event - plan.first_event;
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
}

// Workgroups per (job, row) over the row's selected events (packed by row), pieces along z.
void EventTensorBuilder::execute_per_row(const EventStream& events, const BinningPlan& plan,
                                         const std::vector<std::pair<size_t, size_t>>& chunks,
                                         const std::function<void(size_t, Tensor&)>& done, const Tensor& rec) {
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
}

// One invocation per event and job over every event of the window, in pieces of one binding.
void EventTensorBuilder::execute_per_event(const EventStream& events, const BinningPlan& plan,
                                           const std::vector<std::pair<size_t, size_t>>& chunks,
                                           const std::function<void(size_t, Tensor&)>& done, const Tensor& rec) {
  const auto& info = ctx_.info();
  const size_t max_range = info.max_storage_buffer_range;
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
