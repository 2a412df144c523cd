#include "vkunroll/host/model/backend_vulkan.hpp"

#include <algorithm>
#include <cstring>

#include "vkunroll/kernels/backward_warp.hpp"
#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/kernels/copy_rect.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"

namespace vkunroll {

struct VulkanBackend::Buf {
  enum class State {
    live,    // held by its handle
    pooled,  // released, reusable by an alloc of the same size until the next flush
    // Pooled at the last flush and kept for the next recording: a repeated frame gets the same buffers
    // (the stream replays its commands only where they name the same ranges). Freed at the next flush
    // unless an alloc took it again.
    retained,
    // The builder's output of an earlier event_tensors() call whose handle is still held: not
    // readable, its slot kept until the handle releases it (so the id names no other buffer).
    stale,
  };
  Tensor t;
  State state = State::live;
  const Tensor* external = nullptr;  // a tensor the backend does not own (event_tensors())
  const Tensor& tensor() const { return external ? *external : t; }
};

VulkanBackend::VulkanBackend(Context& ctx, Profiler* profiler, uint64_t pool_flush_bytes, Precision precision)
    : ctx_(ctx), precision_(precision), dtype_(precision_dtype(precision)), workspace_(std::make_shared<ConvWorkspace>()),
      cs_(std::make_unique<CommandStream>(ctx, profiler)), pool_flush_bytes_(pool_flush_bytes) {
  if (precision == Precision::fp16) require_fp16(ctx, "vulkan backend (" + opt("precision") + " fp16)");
}

Tensor& VulkanBackend::scratch_f32(const Shape& shape) {
  scratch_.emplace_back(ctx_, shape, DType::f32);
  return scratch_.back();
}

VulkanBackend::~VulkanBackend() = default;

uint64_t VulkanBackend::max_buffer_bytes() const {
  const uint64_t device = ctx_.info().max_storage_buffer_range;
  return max_buffer_cap_ ? std::min(device, max_buffer_cap_) : device;
}

const Tensor& VulkanBackend::tensor(int id) const {
  if (id < 0 || id >= static_cast<int>(bufs_.size()) || !bufs_[id] || bufs_[id]->state != Buf::State::live)
    throw InternalError("vulkan backend: buffer " + std::to_string(id) + " is not allocated");
  return bufs_[id]->tensor();
}

int VulkanBackend::alloc_id(const Shape& shape, const std::string& what) {
  // Released buffers past the pool's limit: submit what reads them and free them first (a release
  // itself never submits, so a handle going out of scope cannot fail).
  if (pooled_bytes_ > pool_flush_bytes_) {
    pool_flushes_++;
    flush(/*keep_pool=*/false);
  }
  const uint64_t bytes = static_cast<uint64_t>(shape.count()) * dtype_size(dtype_);
  account_alloc(bytes);
  // A pooled buffer of the same size takes the new shape: only recorded dispatches (ordered by the
  // stream's barriers) write a backend buffer, never the host directly.
  for (size_t i = 0; i < bufs_.size(); ++i)
    if (bufs_[i] && (bufs_[i]->state == Buf::State::pooled || bufs_[i]->state == Buf::State::retained) &&
        bufs_[i]->t.bytes() == bytes) {
      bufs_[i]->t.reshape(shape);
      if (bufs_[i]->state == Buf::State::pooled) pooled_bytes_ -= bytes;
      bufs_[i]->state = Buf::State::live;
      return static_cast<int>(i);
    }
  if (bytes > max_buffer_bytes())
    throw DataError("vulkan backend: " + what + " " + shape.str() + " needs " + std::to_string(bytes >> 20) +
                " MiB, above the device's storage-buffer limit of " + std::to_string(max_buffer_bytes() >> 20) + " MiB");
  auto b = std::make_unique<Buf>();
  b->t = Tensor(ctx_, shape, dtype_);
  device_bytes_ += bytes;
  device_peak_ = std::max(device_peak_, device_bytes_);
  for (size_t i = 0; i < bufs_.size(); ++i)
    if (!bufs_[i]) {
      bufs_[i] = std::move(b);
      return static_cast<int>(i);
    }
  bufs_.push_back(std::move(b));
  return static_cast<int>(bufs_.size() - 1);
}

void VulkanBackend::release_id(int id) noexcept {
  Buf& b = *bufs_[size_t(id)];  // a live (or stale) buffer: only its handle releases it, once
  if (b.external || b.state == Buf::State::stale) {
    bufs_[size_t(id)].reset();
    if (id == events_buf_) events_buf_ = -1;
    return;
  }
  account_release(b.t.bytes());
  b.state = Buf::State::pooled;
  pooled_bytes_ += b.t.bytes();
}

Shape VulkanBackend::shape(int id) const { return tensor(id).shape(); }

namespace {
std::string_view stage_family(std::string_view stage) { return stage.substr(0, stage.find('.')); }
}  // namespace

void VulkanBackend::set_stage(const std::string& stage) {
  // The network's commands start a submission of their own: they repeat from frame to frame where
  // the uploads and event tensors before them do not, so they replay (runtime/command_stream.hpp).
  if (stage_family(stage) == "model" && stage_family(cs_->stage()) != "model") cs_->submit();
  cs_->set_stage(stage);
}

void VulkanBackend::flush() { flush(/*keep_pool=*/true); }

void VulkanBackend::flush(bool keep_pool) {
  cs_->submit_and_wait();
  physics_.clear();
  scratch_.clear();
  events_recorded_ = false;
  // Nothing recorded references the pooled buffers any more: the ones kept at the last flush and not
  // taken since give their memory back, and (unless memory asked for the flush) this recording's
  // released buffers are kept for the next one.
  for (auto& b : bufs_)
    if (b && (b->state == Buf::State::retained || (b->state == Buf::State::pooled && !keep_pool))) {
      device_bytes_ -= b->t.bytes();
      b.reset();
    } else if (b && b->state == Buf::State::pooled) {
      b->state = Buf::State::retained;
    }
  pooled_bytes_ = 0;
}

namespace {
Slice slice(const Tensor& t, const BufferSlice& v) { return Slice(t, v.c0, v.c, v.n0, v.n); }

// The trace's words for a conv's dispatches: "2x48x130x173->2x48x130x173 winograd".
std::string conv_detail(const Shape& in, const Shape& out, const char* algo) {
  return in.str() + "->" + out.str() + " " + algo;
}
}  // namespace

// A slice's batch items are contiguous byte ranges (its channels of one item): one transfer each,
// recorded in the stream, so uploads wait for nothing and downloads for one submission.
void VulkanBackend::upload(const BufferSlice& v, std::span<const float> data) {
  const Tensor& t = tensor(v.buf);
  check_slice(slice(t, v), "vulkan backend upload", "destination");
  const int64_t plane = t.shape().h * t.shape().w, item = v.c * plane;
  if (static_cast<int64_t>(data.size()) != v.n * item)
    throw InternalError("vulkan backend: upload of " + std::to_string(data.size()) + " values into " +
                Shape{v.n, v.c, t.shape().h, t.shape().w}.str());
  if (t.dtype() != DType::f32) {  // fp16: the f32 values go up as they are and convert on the device
    Tensor& staged = scratch_f32({v.n, v.c, t.shape().h, t.shape().w});
    cs_->upload(staged, 0, data.data(), data.size() * 4);
    vkunroll::copy(*cs_, Slice(staged), slice(t, v));
    return;
  }
  for (int64_t i = 0; i < v.n; ++i)
    cs_->upload(t, static_cast<size_t>(((v.n0 + i) * t.shape().c + v.c0) * plane) * 4, data.data() + i * item,
                static_cast<size_t>(item) * 4);
}

void VulkanBackend::download(const BufferSlice& v, std::span<float> dst) {
  const Tensor& t = tensor(v.buf);
  check_slice(slice(t, v), "vulkan backend download", "source");
  const int64_t plane = t.shape().h * t.shape().w, item = v.c * plane;
  if (static_cast<int64_t>(dst.size()) != v.n * item)
    throw InternalError("vulkan backend: download of " + Shape{v.n, v.c, t.shape().h, t.shape().w}.str() + " into " +
                std::to_string(dst.size()) + " values");
  if (t.dtype() != DType::f32) {  // fp16: converted to f32 on the device, then read back
    Tensor& staged = scratch_f32({v.n, v.c, t.shape().h, t.shape().w});
    vkunroll::copy(*cs_, slice(t, v), Slice(staged));
    cs_->download(staged, 0, dst.data(), dst.size() * 4);
    return;
  }
  for (int64_t i = 0; i < v.n; ++i)
    cs_->download(t, static_cast<size_t>(((v.n0 + i) * t.shape().c + v.c0) * plane) * 4, dst.data() + i * item,
                  static_cast<size_t>(item) * 4);
}

int VulkanBackend::prepare_conv(const ConvDesc& d, const WeightTensor& w, const WeightTensor& b) {
  const HostTensor wt(Shape{w.shape.at(0), w.shape.at(1), w.shape.at(2), w.shape.at(3)}, w.data);
  const HostTensor bt(Shape{1, 1, 1, static_cast<int64_t>(b.data.size())}, b.data);
  const Act act = d.leaky ? leaky_relu(d.slope) : Act{};
  ConvOptions options = conv_options_;
  options.precision = precision_;
  if (d.transposed) {
    deconvs_.push_back(
        std::make_unique<ConvTranspose2d>(ctx_, wt, bt, ConvTranspose2dParams{d.k, d.stride, d.pad, act}, d.name, options));
    conv_refs_.push_back({true, deconvs_.size() - 1});
  } else {
    convs_.push_back(
        std::make_unique<Conv2d>(ctx_, wt, bt, Conv2dParams{d.k, d.stride, d.pad, act}, d.name, workspace_, options));
    conv_refs_.push_back({false, convs_.size() - 1});
  }
  weight_bytes_ += w.data.size() * dtype_size(dtype_) + b.data.size() * 4;  // biases stay f32
  descs_.push_back(d);
  return static_cast<int>(conv_refs_.size() - 1);
}

void VulkanBackend::set_conv_choice(std::shared_ptr<ConvChoiceTable> table, ConvChoice choice, int reps) {
  if (choice == ConvChoice::automatic)
    choice = ctx_.info().type == VK_PHYSICAL_DEVICE_TYPE_CPU ? ConvChoice::cached : ConvChoice::measured;
  if (choice != ConvChoice::heuristic && choice != ConvChoice::gpu && !table) table = std::make_shared<ConvChoiceTable>();
  choice_table_ = std::move(table);
  choice_ = choice;
  choice_budget_ = ConvTimingBudget{};
  choice_budget_.reps = std::max(1, reps);
}

void VulkanBackend::set_conv_choice(std::shared_ptr<ConvChoiceTable> table, ConvChoice choice, const ConvTimingBudget& budget) {
  set_conv_choice(std::move(table), choice, budget.reps);
  choice_budget_ = budget;
}

std::optional<std::string> VulkanBackend::table_algorithm(const std::string& key,
                                                          const std::function<ConvChoiceEntry()>& time) {
  const ConvChoiceEntry* e = choice_table_->find(key);
  const bool again = choice_ == ConvChoice::retune && !retuned_.count(key);
  if ((again || (!e && choice_ == ConvChoice::measured)) && timing_deadline_ &&
      Clock::now() >= *timing_deadline_) {
    past_deadline_.insert(key);
  } else if (again || (!e && choice_ == ConvChoice::measured)) {
    // Timed on separate streams: this backend's recording is not submitted yet, so nothing waits on it.
    const Stopwatch timing;
    choice_table_->set(key, time());
    retuned_.insert(key);
    ++convs_timed_;
    e = choice_table_->find(key);
    if (on_conv_timed_)
      on_conv_timed_(key, *e, timing.seconds());
  }
  if (!e) return std::nullopt;
  return e->algo;
}

ConvAlgo VulkanBackend::gpu_choice(const Conv2d& c, const Shape& in, bool residual_in_output) const {
  const ConvAlgo a = gpu_family_algorithm(c, in);
  const std::vector<ConvAlgo> can = c.candidates(in, residual_in_output);
  // A pick this call cannot take (Winograd's scratch, a residual in the output) keeps the kernels' own.
  return std::find(can.begin(), can.end(), a) != can.end() ? a : ConvAlgo::automatic;
}

ConvAlgo VulkanBackend::conv2d_algorithm(const Conv2d& c, const Shape& in, bool residual, bool residual_in_output,
                                         bool& from_table) {
  from_table = false;
  if (choice_ == ConvChoice::gpu) return gpu_choice(c, in, residual_in_output);
  if (choice_ == ConvChoice::heuristic || !choice_table_) return ConvAlgo::automatic;
  const auto time = [&] { return time_conv_algorithms(ctx_, c, in, residual, choice_budget_); };
  if (auto name = table_algorithm(conv_choice_key(c, in, residual), time))
    // An entry naming an algorithm this call cannot take (another build's, a residual in the output
    // for chunked direct) falls back to the heuristic.
    for (ConvAlgo a : c.candidates(in, residual_in_output))
      if (*name == conv_algo_name(a)) {
        from_table = true;
        return a;
      }
  return ConvAlgo::automatic;
}

bool VulkanBackend::conv_folded_at_once(int id, const std::vector<BufferSlice>& pieces, const Shape& is,
                                        const ConvFold& fold, const BufferSlice& out) {
  const ConvRef ref = conv_refs_.at(static_cast<size_t>(id));
  if (ref.transposed || probe_) return false;  // the per-layer probe reads each conv's own output
  const Conv2d& c = *convs_[ref.index];
  bool from_table = false;
  const ConvAlgo algo = c.resolve_algorithm(is, conv2d_algorithm(c, is, false, false, from_table), false);
  if (!(is_igemm(algo) || algo == ConvAlgo::coopmat) || !c.supports(algo, is)) return false;
  if (from_table) ++convs_from_table_;
  std::vector<Slice> ps;
  for (const BufferSlice& v : pieces) ps.push_back(slice(tensor(v.buf), v));
  const Slice so = slice(tensor(out.buf), out);
  if (ctx_.trace()) cs_->set_detail(conv_detail(is, so.shape(), (std::string(conv_algo_name(algo)) + " folded").c_str()));
  ++conv_calls_by_algorithm_[conv_algo_name(c.record_folded(*cs_, ps, fold, so, std::nullopt, algo))];
  ++convs_folded_;
  cs_->set_detail({});
  return true;
}

void VulkanBackend::begin_dense_block(int64_t channels) {
  if (!dense_v_) dense_v_ = std::make_unique<WinogradInputCache>();
  dense_v_->begin(channels);
}

void VulkanBackend::end_dense_block() {
  if (dense_v_) dense_v_->end();
}

void VulkanBackend::conv(int id, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) {
  const ConvRef ref = conv_refs_.at(static_cast<size_t>(id));
  const Slice si = slice(tensor(in.buf), in), so = slice(tensor(out.buf), out);
  const Shape is = si.shape();
  // the key is built only then
  const bool tabled = choice_ != ConvChoice::heuristic && choice_ != ConvChoice::gpu && choice_table_;
  if (ref.transposed) {
    if (residual) throw InternalError("vulkan backend: " + descs_[id].name + ": a transposed conv takes no residual");
    const ConvTranspose2d& c = *deconvs_[ref.index];
    ConvTransposeAlgo algo = choice_ == ConvChoice::gpu ? gpu_family_algorithm(c) : ConvTransposeAlgo::automatic;
    if (auto name = tabled ? table_algorithm(conv_choice_key(c, is), [&] { return time_conv_algorithms(ctx_, c, is, choice_budget_); })
                           : std::nullopt)
      for (ConvTransposeAlgo a : c.candidates())
        if (*name == conv_transpose_algo_name(a)) algo = a;
    if (algo != ConvTransposeAlgo::automatic && choice_ != ConvChoice::gpu) ++convs_from_table_;
    const char* algo_name = conv_transpose_algo_name(algo == ConvTransposeAlgo::automatic ? c.choose_algorithm(is.h, is.w) : algo);
    ++conv_calls_by_algorithm_[std::string("transposed ") + algo_name];
    if (ctx_.trace()) cs_->set_detail(conv_detail(is, so.shape(), algo_name));
    c.record(*cs_, si, so, algo);
  } else {
    const Conv2d& c = *convs_[ref.index];
    std::optional<Slice> r;
    if (residual) r = slice(tensor(residual->buf), *residual);
    bool from_table = false;
    const bool overlap = c.residual_overlaps_output(so, r);
    // Resolved once, here (the trace names it before the dispatches are recorded); the count takes
    // what record() says it ran, for the whole batch.
    const ConvAlgo algo = c.resolve_algorithm(is, conv2d_algorithm(c, is, r.has_value(), overlap, from_table), overlap);
    if (from_table) ++convs_from_table_;
    if (ctx_.trace()) cs_->set_detail(conv_detail(is, so.shape(), conv_algo_name(algo)));
    ++conv_calls_by_algorithm_[conv_algo_name(c.record(*cs_, si, so, r, algo, dense_v_.get()))];
  }
  cs_->set_detail({});
  if (probe_) {
    const Shape os = tensor(out.buf).shape();
    probe_->emplace_back(descs_[id].name, std::vector<float>(static_cast<size_t>(out.n * out.c * os.h * os.w)));
    download(out, std::span<float>(probe_->back().second));
  }
}

void VulkanBackend::space_to_depth(const BufferSlice& in, const BufferSlice& out) {
  vkunroll::space_to_depth(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out));
}
void VulkanBackend::depth_to_space(const BufferSlice& in, const BufferSlice& out) {
  vkunroll::depth_to_space(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out));
}
void VulkanBackend::reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) {
  const Shape si = tensor(in.buf).shape(), so = tensor(out.buf).shape();
  reflection_pad(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out),
                 Pads{top, so.h - si.h - top, left, so.w - si.w - left});
}
void VulkanBackend::crop(const BufferSlice& in, const BufferSlice& out, int top, int left) {
  vkunroll::crop(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out), top, left);
}
void VulkanBackend::copy(const BufferSlice& in, const BufferSlice& out) {
  vkunroll::copy(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out));
}
void VulkanBackend::add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) {
  vkunroll::add(*cs_, slice(tensor(a.buf), a), slice(tensor(b.buf), b), slice(tensor(out.buf), out));
}
void VulkanBackend::clamp01(const BufferSlice& in, const BufferSlice& out) {
  vkunroll::clamp01(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out));
}
void VulkanBackend::tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) {
  vkunroll::tanh_scale(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out), scale);
}
void VulkanBackend::backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) {
  vkunroll::backward_warp(*cs_, slice(tensor(img.buf), img), slice(tensor(flow.buf), flow), slice(tensor(out.buf), out));
}

void VulkanBackend::copy_rect(const BufferSlice& in, const BufferSlice& out, const Rect& src, int64_t dst_y, int64_t dst_x) {
  vkunroll::copy_rect(*cs_, slice(tensor(in.buf), in), slice(tensor(out.buf), out), src, dst_y, dst_x);
}
void VulkanBackend::fill_rect(const BufferSlice& out, const Rect& rect, float value) {
  vkunroll::fill_rect(*cs_, slice(tensor(out.buf), out), rect, value);
}

int VulkanBackend::event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                    const EventTensorSpec& spec) {
  if (!events_) events_ = std::make_unique<EventTensorBuilder>(ctx_);
  // The builder reuses its buffers: what was recorded reading the previous build runs first.
  if (events_recorded_) flush();
  if (events_buf_ >= 0) {  // the previous build's handle is still held: no longer readable
    Buf& old = *bufs_[size_t(events_buf_)];
    old.external = nullptr;
    old.state = Buf::State::stale;
    events_buf_ = -1;
  }
  const Tensor& t = events_->record_resident(*cs_, events, pairs, spec);
  events_recorded_ = true;
  if (dtype_ != DType::f32) {
    // fp16: the counts are exact in the f32 build and stored saturated at 65504 (the conversion's clamp).
    const int id = alloc_id(t.shape(), "event tensors (fp16)");
    vkunroll::copy(*cs_, Slice(t), slice(tensor(id), {id, 0, t.shape().n, 0, t.shape().c}));
    return id;
  }
  auto b = std::make_unique<Buf>();
  b->external = &t;
  for (size_t i = 0; i <= bufs_.size(); ++i)
    if (i == bufs_.size() || !bufs_[i]) {
      if (i == bufs_.size()) bufs_.push_back(nullptr);
      bufs_[i] = std::move(b);
      events_buf_ = static_cast<int>(i);
      break;
    }
  return events_buf_;
}

void VulkanBackend::physics_unroll(const BufferSlice& rs, const PixelEventLists& lists, const PhysicsUnrollParams& params,
                                   const BufferSlice& out) {
  // The caller checked the image (check_physics_image); the lists' uploads are recorded in order.
  physics_.push_back(std::make_unique<PhysicsUnroll>(ctx_, lists, cs_.get()));
  const Slice si = slice(tensor(rs.buf), rs), so = slice(tensor(out.buf), out);
  if (dtype_ == DType::f32) {
    physics_.back()->record(*cs_, si, so, params);
    return;
  }
  // fp16 buffers: the unroller's exponentials run in f32 between two conversions.
  Tensor& rs32 = scratch_f32(si.shape());
  Tensor& out32 = scratch_f32(so.shape());
  vkunroll::copy(*cs_, si, Slice(rs32));
  physics_.back()->record(*cs_, rs32, out32, params);
  vkunroll::copy(*cs_, Slice(out32), so);
}

void VulkanBackend::hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m, const BufferSlice& out,
                                      float forced) {
  const Slice ms = slice(tensor(m.buf), m);
  if (forced >= 0) {
    vkunroll::fill_rect(*cs_, ms, Rect{0, 0, ms.height(), ms.width()}, forced);
  } else {
    scale_act(*cs_, slice(tensor(score.buf), score), ms, Act{Activation::hardsigmoid, 0.f}, 1.f);
  }
  blend(*cs_, ms, slice(tensor(a.buf), a), slice(tensor(b.buf), b), slice(tensor(out.buf), out));
}

}  // namespace vkunroll
