// The Vulkan backend: the kernels' GPU ops recorded into one CommandStream per flush. Buffers are
// device Tensors; a released buffer is reused by a later alloc() of the same size (the stream's
// hazard barriers order the reuse), kept over one flush for the next recording (a repeated frame
// then names the same buffers, and its commands replay), and destroyed at the flush after that if
// nothing took it, or at once when an alloc() finds more than pool_flush_bytes pooled, so device
// memory follows the graph's liveness.
#pragma once
#include <chrono>
#include <deque>
#include <map>
#include <set>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/kernels/conv_options.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/runtime/command_stream.hpp"

namespace vkunroll {

class Conv2d;
class ConvTranspose2d;
class ConvWorkspace;
class EventTensorBuilder;
class PhysicsUnroll;
class WinogradInputCache;
class Profiler;

class VulkanBackend final : public Backend {
 public:
  // pool_flush_bytes: pooled bytes past which released buffers are freed (kPoolFlushBytes).
  // precision: fp16 keeps weights and every buffer in float16 (the kernels' per-op arithmetic:
  // docs/kernels.md "Precision"); uploads and downloads stay f32 on the host and convert on the
  // device, event tensors are built exactly in f32 and stored saturated at 65504, and the physics
  // unroller computes in f32 (its exponentials). An Error on a device without 16-bit storage.
  explicit VulkanBackend(Context& ctx, Profiler* profiler = nullptr, uint64_t pool_flush_bytes = kPoolFlushBytes,
                         Precision precision = Precision::fp32);
  ~VulkanBackend() override;
  std::string name() const override { return "vulkan"; }
  Precision precision() const override { return precision_; }
  Shape shape(int buf) const override;
  void upload(const BufferSlice& dst, std::span<const float> data) override;
  void download(const BufferSlice& src, std::span<float> dst) override;
  using Backend::download;
  int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) override;
  void conv(int conv, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) override;
  void begin_dense_block(int64_t channels) override;
  void end_dense_block() override;
  void space_to_depth(const BufferSlice& in, const BufferSlice& out) override;
  void depth_to_space(const BufferSlice& in, const BufferSlice& out) override;
  void reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void crop(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void copy(const BufferSlice& in, const BufferSlice& out) override;
  void add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) override;
  void clamp01(const BufferSlice& in, const BufferSlice& out) override;
  void tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) override;
  void backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) override;
  void copy_rect(const BufferSlice& in, const BufferSlice& out, const Rect& src, int64_t dst_y, int64_t dst_x) override;
  void fill_rect(const BufferSlice& out, const Rect& rect, float value) override;
  void physics_unroll(const BufferSlice& rs, const PixelEventLists& lists, const PhysicsUnrollParams& params,
                      const BufferSlice& out) override;
  void hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m, const BufferSlice& out,
                         float forced) override;
  void flush() override;
  void set_stage(const std::string& stage) override;
  uint64_t max_buffer_bytes() const override;
  // Caps max_buffer_bytes() below the device's limit (0: no cap), e.g. to test tiling.
  void set_max_buffer_bytes(uint64_t b) { max_buffer_cap_ = b; }

  // The per-layer precision report (vkunroll-bench-model --per-layer): while set, every conv's output
  // is also downloaded into `probe` as (conv name, values) in call order, valid after flush().
  using LayerProbe = std::deque<std::pair<std::string, std::vector<float>>>;
  void set_layer_probe(LayerProbe* probe) { probe_ = probe; }

  // The conv algorithm per shape: `table` (shared; timed shapes are added to it) under `choice`
  // (conv_choice.hpp). Without a call the kernels' heuristic decides. `reps`: timed runs per candidate.
  void set_conv_choice(std::shared_ptr<ConvChoiceTable> table, ConvChoice choice, int reps = 3);
  void set_conv_choice(std::shared_ptr<ConvChoiceTable> table, ConvChoice choice, const ConvTimingBudget& budget);
  // No shape is timed after `deadline` (vkunroll tune --budget-s): the rest take the table or the
  // heuristic, counted in convs_past_deadline().
  void set_conv_timing_deadline(Clock::time_point deadline) { timing_deadline_ = deadline; }
  uint64_t convs_past_deadline() const { return past_deadline_.size(); }
  // The kernels' tuning knobs (ConvOptions; their precision is the backend's) for the convs prepared
  // after the call; validated by each conv.
  void set_conv_options(const ConvOptions& o) { conv_options_ = o; }
  const std::shared_ptr<ConvChoiceTable>& conv_choice_table() const { return choice_table_; }
  const ConvChoiceTable* conv_table() const override { return choice_table_.get(); }
  uint64_t convs_timed() const override { return convs_timed_; }
  // Called after each shape the measured choice times (key, its entry, seconds spent): benches report
  // progress with it, so a run stopped by a time limit still says which shapes it reached.
  void on_conv_timed(std::function<void(const std::string&, const ConvChoiceEntry&, double)> f) { on_conv_timed_ = std::move(f); }
  uint64_t convs_from_table() const override { return convs_from_table_; }
  // Conv calls recorded per algorithm name (transposed convs as "transposed NAME"); a call left to the
  // kernel counts under its choose_algorithm. Shows what --conv-choice changed.
  std::map<std::string, uint64_t> conv_calls_by_algorithm() const override { return conv_calls_by_algorithm_; }
  // conv_folded calls run as one dispatch (their pads, crops, shuffles and tanh folded into the conv).
  uint64_t convs_folded() const { return convs_folded_; }

  Context& context() { return ctx_; }
  // Bytes of device memory held by buffers (live + pooled for reuse), and its peak.
  uint64_t device_bytes() const { return device_bytes_; }
  uint64_t device_peak_bytes() const override { return device_peak_; }
  // Bytes of prepared weights on the device (all packings the conv kernels keep).
  uint64_t weight_bytes() const { return weight_bytes_; }
  // Submissions the backend made on its own (at an alloc()) because released buffers held more
  // than pool_flush_bytes (memory forced a wait inside the work).
  uint64_t pool_flushes() const override { return pool_flushes_; }

 private:
  struct Buf;
  int alloc_id(const Shape& shape, const std::string& what) override;
  // Submits and waits; then frees the buffers kept at the last flush that no alloc took since, and
  // keeps this recording's released buffers for the next one (keep_pool) or frees them too.
  void flush(bool keep_pool);
  void release_id(int buf) noexcept override;
  int event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec) override;
  const Tensor& tensor(int buf) const;
  // An f32 tensor living until the next flush: the host side of an fp16 buffer's transfers.
  Tensor& scratch_f32(const Shape& shape);
  Context& ctx_;
  Precision precision_ = Precision::fp32;
  DType dtype_ = DType::f32;              // of every buffer the backend allocates
  LayerProbe* probe_ = nullptr;
  std::deque<Tensor> scratch_;  // f32 conversions recorded since the last flush (stable references)
  std::shared_ptr<ConvWorkspace> workspace_;  // Winograd scratch shared by every conv
  std::unique_ptr<WinogradInputCache> dense_v_;  // V shared by a dense block's convs (begin_dense_block)
  std::unique_ptr<CommandStream> cs_;
  std::vector<std::unique_ptr<Buf>> bufs_;
  std::vector<std::unique_ptr<Conv2d>> convs_;
  std::vector<std::unique_ptr<ConvTranspose2d>> deconvs_;
  struct ConvRef {
    bool transposed = false;  // in deconvs_, else in convs_
    size_t index = 0;
  };
  std::vector<ConvRef> conv_refs_;  // by conv id
  std::vector<ConvDesc> descs_;
  // Event tensors are built into the builder's persistent output (the sparse path), recorded into
  // this backend's stream; a new build waits for the recorded readers of the previous one.
  std::unique_ptr<EventTensorBuilder> events_;
  bool events_recorded_ = false;  // since the last flush
  int events_buf_ = -1;           // the buffer naming the builder's output, -1: none
  std::vector<std::unique_ptr<PhysicsUnroll>> physics_;  // ops whose uploads and dispatch are recorded
  uint64_t device_bytes_ = 0, device_peak_ = 0, weight_bytes_ = 0, pooled_bytes_ = 0;
  uint64_t max_buffer_cap_ = 0;
  uint64_t pool_flushes_ = 0;
  uint64_t pool_flush_bytes_ = kPoolFlushBytes;
  std::shared_ptr<ConvChoiceTable> choice_table_;
  ConvChoice choice_ = ConvChoice::heuristic;
  ConvTimingBudget choice_budget_;
  std::optional<Clock::time_point> timing_deadline_;
  std::set<std::string> past_deadline_;  // keys left untimed for the deadline
  ConvOptions conv_options_;
  std::set<std::string> retuned_;  // keys timed again under ConvChoice::retune
  uint64_t convs_timed_ = 0, convs_from_table_ = 0, convs_folded_ = 0;
  std::map<std::string, uint64_t> conv_calls_by_algorithm_;
  std::function<void(const std::string&, const ConvChoiceEntry&, double)> on_conv_timed_;
  // The table's algorithm for this conv call (timing it first where the choice says so); nullopt: the
  // heuristic. Only called with a table and a choice other than heuristic.
  std::optional<std::string> table_algorithm(const std::string& key, const std::function<ConvChoiceEntry()>& time);
  // ConvChoice::gpu's algorithm for a conv call (gpu_family_algorithm where the call can take it).
  ConvAlgo gpu_choice(const Conv2d& c, const Shape& in, bool residual_in_output) const;
  // The algorithm a conv call runs under the choice: the table's (from_table set), ConvChoice::gpu's,
  // or automatic (the kernels' heuristic).
  ConvAlgo conv2d_algorithm(const Conv2d& c, const Shape& in, bool residual, bool residual_in_output, bool& from_table);
  // Folds into one dispatch where the conv runs the GPU family (igemm, coopmat) on the folded input.
  bool conv_folded_at_once(int conv, const std::vector<BufferSlice>& pieces, const Shape& in, const ConvFold& fold,
                           const BufferSlice& out) override;
};

}  // namespace vkunroll
