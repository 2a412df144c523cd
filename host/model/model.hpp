// SelfUnroll-S and -M (docs/model.md): the graph of docs/network.md,
// written once against the Backend interface (host/model/backend.hpp) and run by any backend.
//
//   Weights w = load_weights("model.safetensors");
//   CpuBackend cpu;               // or VulkanBackend vk(ctx);
//   Model model(cpu, w);
//   auto out = model.run({rs, ev1, ev2, ev3}, {.mode = Mode::m});   // out[ModelOutput::out], ...
#pragma once
#include <iosfwd>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "vkunroll/base/host_tensor.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/model/weights.hpp"

namespace vkunroll {

enum class Mode { s, m };

// What a run can return (the reference network's intermediates). sys, E, flow, warped and fused have
// one item per batch item; m and out one per target (mode m only: K = B / 2 items).
enum class ModelOutput { sys, E, flow, warped, fused, m, out };
inline constexpr ModelOutput kModelOutputs[] = {ModelOutput::sys,    ModelOutput::E,     ModelOutput::flow, ModelOutput::warped,
                                                ModelOutput::fused, ModelOutput::m,     ModelOutput::out};
const char* output_name(ModelOutput o);  // the reference name: "sys", "E", ...
std::ostream& operator<<(std::ostream& os, ModelOutput o);  // writes output_name(o)
// The output of that reference name; throws an OptionError of field "outputs" naming those expected.
ModelOutput parse_output(const std::string& name);
constexpr bool per_target(ModelOutput o) { return o == ModelOutput::m || o == ModelOutput::out; }
constexpr int64_t output_channels(ModelOutput o) { return o == ModelOutput::flow ? 2 : (o == ModelOutput::m ? 1 : 3); }

// The inputs as slices of backend buffers (e.g. the event tensors where Backend::event_tensors put
// them): rs [B, 3, H, W], ev1, ev2, ev3 [B, 2N, H, W], read in place.
struct ModelBuffers {
  BufferSlice rs, ev1, ev2, ev3;
  BufferSlice phys;  // the physics-informed variant's [B, 3, H, W] estimate (buf -1: none)
};

struct ModelInputs {
  // rs [B,3,H,W]; ev1, ev2, ev3 [B,2N,H,W]. SelfUnroll-S: B targets run independently.
  // SelfUnroll-M: B = 2K, items 2k and 2k+1 are RS frames 1 and 2 toward target k.
  HostTensor rs, ev1, ev2, ev3;
  HostTensor phys;  // the physics-informed variant only: the physics estimate [B, 3, H, W]
};

// Reflection padding of each UNet's input, per side, in rows / columns of the even-size input.
// top / left < 0: centered in the next multiple of 32 (the authors' size adapter; bottom / right
// must be < 0 too). top / left >= 0 and bottom / right < 0: the input at that offset, padded on to
// the next multiple of 32. All four >= 0: exactly these; the padded size must then be a multiple of
// every UNet's stride (Model::unet_stride()), and each pad smaller than the input (reflection).
struct UnetPadding {
  int top = -1, left = -1, bottom = -1, right = -1;
};

struct RunOptions {
  Mode mode = Mode::s;
  // The outputs to return; empty: all of the mode.
  std::vector<ModelOutput> outputs;
  // >= 0: replaces the MOA blend map m by this constant (tests: m = 1 gives S of frame 1).
  float force_m = -1.f;
  // Most batch items (M: frames, always whole pairs) run together; 0: as many as the backend's
  // buffer limit and `memory_budget` allow.
  int max_items = 0;
  // Bytes of intermediates the run should hold at once (0: no limit other than buffer size); it
  // bounds the chunk and sub-batch sizes (a single item may still need more, see docs/model.md).
  uint64_t memory_budget = 0;
  // Where every UNet's size adapter puts its input in the reflection-padded input (UnetPadding);
  // host/model/tiled_run.cpp gives each tile the untiled run's stride grid and border padding.
  UnetPadding unet_pad;
  // The precision the caller expects; the backend's own (weights are prepared in it when the Model
  // is built) decides, and a run whose expectation differs is refused rather than silently changed.
  std::optional<Precision> precision;
};

class Model {
 public:
  Model(Backend& backend, const Weights& weights);
  const ModelConfig& config() const { return cfg_; }
  Backend& backend() { return backend_; }

  // Runs the network; returns the requested intermediates, cropped to the input's H x W (sys, E,
  // flow, warped, fused: B items; m, out: K = B/2 items).
  std::map<ModelOutput, HostTensor> run(const ModelInputs& in, const RunOptions& opt);
  // The same on inputs already in the backend, recorded without waiting: returns the outputs as
  // new backend buffers (the caller downloads them; they go with their handles). Nothing is
  // submitted unless the backend's memory forces it. `handed_over`: buffers of the inputs the caller
  // gives up, each the buffer of exactly one input: released once its last reader is recorded (ev2
  // after the flow, ev3 after the fusion), which lowers the peak memory.
  std::map<ModelOutput, Buffer> run_on_backend(const ModelBuffers& in, const RunOptions& opt,
                                               std::vector<Buffer> handed_over = {});
  // Batch items [c0, c0 + n) of the inputs uploaded into new backend buffers (appended to `owned`,
  // which keeps them; run() hands them over): the ModelBuffers run_on_backend takes. Unchecked: run()
  // checks the inputs first.
  ModelBuffers upload_inputs(const ModelInputs& in, int64_t c0, int64_t n, std::vector<Buffer>& owned);

  // Batch items one chunk holds for inputs of this size (what run() uses when max_items = 0).
  int items_per_chunk(int64_t h, int64_t w, Mode mode, uint64_t memory_budget) const;
  // Bytes of the largest single buffer one batch item of this size needs (run() throws when it
  // exceeds the backend's max_buffer_bytes()); host/model/tiling.cpp sizes tiles with it.
  // (pad: RunOptions::unet_pad; top / left with bottom / right < 0 bound any explicit padding whose
  // top / left are no larger, as tiles' are.)
  int64_t item_buffer_bytes(int64_t h, int64_t w, Mode mode, const UnetPadding& pad = {}) const;
  // What every UNet's padded input size must be a multiple of: 2^depth of the deepest UNet.
  int64_t unet_stride() const;

  // The outputs a run returns: `requested` (each once), or every output of the mode when empty (in
  // kModelOutputs order); throws an OptionError of field "outputs" for m or out outside mode m.
  static std::vector<ModelOutput> resolve_outputs(const std::vector<ModelOutput>& requested, Mode mode);

 private:
  struct Conv {
    int id = -1;
    ConvDesc desc;
  };
  const Conv& conv(const std::string& name) const;
  // Prepares the layer `desc` names (desc.name: the checkpoint prefix) with its weights from `w`.
  void add_conv(const Weights& w, const ConvDesc& desc);
  void add_unet(const Weights& w, const std::string& p, int cin, int cout, const UnetConfig& u);

  // Stages on batch items [i0, i0+n) of the chunk buffers.
  struct Chunk;
  void stage_synthesis(Chunk& ch, int64_t i0, int64_t n);
  void stage_flow(Chunk& ch, int64_t i0, int64_t n);
  void stage_fusion(Chunk& ch, int64_t i0, int64_t n);
  void add_physics_gate();
  void stage_moa(Chunk& ch, int64_t t0, int64_t nt, float force_m);
  // The UNet on `pieces` (views with n items, concatenated along channels), output to `out`
  // (out_tanh_scale > 0: out_tanh_scale x tanh of it). pad: RunOptions::unet_pad.
  void unet(const std::string& p, const UnetConfig& u, const std::vector<BufferSlice>& pieces, const BufferSlice& out,
            const UnetPadding& pad, float out_tanh_scale = 0.f);
  Buffer resblock(const std::string& p, Buffer x);  // returns the output buffer; releases x

  // The one check of a run's inputs and options, on their extents (host tensors or backend slices
  // alike): throws Error naming the input or option and what was expected.
  struct InputExtents;
  void check_inputs(const InputExtents& in, const RunOptions& opt) const;
  void check_buffers(const ModelBuffers& in, const RunOptions& opt, const std::vector<Buffer>& handed_over) const;
  struct SubBatches;
  SubBatches sub_batches(int64_t he, int64_t we, const RunOptions& opt) const;
  // Batch items [c0, c0 + n) of run_on_backend: the stages, into `result`; the last chunk releases
  // `handed_over` as its inputs' readers are recorded.
  void run_chunk(const ModelBuffers& in, const RunOptions& opt, const std::set<ModelOutput>& want, int64_t c0, int64_t n,
                 const SubBatches& sb, std::map<ModelOutput, Buffer>& result, std::vector<Buffer>& handed_over);
  int64_t synthesis_item_bytes(int64_t h, int64_t w) const;
  int64_t unet_item_bytes(const UnetConfig& u, int cin, int64_t h, int64_t w, const UnetPadding& pad) const;
  void check_unet_padding(const UnetPadding& pad, int64_t he, int64_t we) const;  // throws Error naming the rule
  int sub_items(int64_t item_bytes, uint64_t memory_budget) const;

  Backend& backend_;
  ModelConfig cfg_;
  std::map<std::string, Conv> convs_;
};

}  // namespace vkunroll
