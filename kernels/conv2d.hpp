// conv2d: 2-D convolution with bias, zero padding, a fused activation and an optional fused
// residual add: out = act(conv(in) + bias) + residual. Input, output and residual are slices, so a
// conv reads a prefix of a dense-concatenation tensor and writes its own channel range of it.
#pragma once
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv_options.hpp"
#include "vkunroll/kernels/igemm.hpp"

namespace vkunroll {

struct Conv2dParams {
  int kernel = 3, stride = 1, pad = 1;
  Act act;
};

// How the GPU computes it; every algorithm gives the same result within rounding (fp32 or fp16).
enum class ConvAlgo : uint32_t {
  automatic = 0,  // chosen per shape (see choose_algorithm)
  naive = 1,      // one invocation per output value: the baseline
  blocked = 2,    // register blocking: 8 pixels x 8 or 16 output channels per invocation, packed weights
                  // (3 was `subgroup`, removed: no device choice used it)
  winograd = 4,   // Winograd F(4x4, 3x3): input transform, batched GEMM, output transform; 3x3 stride 1
                  // (pad 1), 5x5 stride 1 (pad 2) as four 3x3 blocks on shifted inputs, 3x3 stride 2
                  // (pad 1) as four 3x3 stride-1 convs on the 2x2 phase images
  gemm = 5,       // 1x1 stride 1: pack the input aligned, register-blocked GEMM (the Winograd GEMM with
                  // one position: 8 pixels x 8/16 channels per invocation, vec4 loads), epilogue
  direct = 6,     // register blocking (8 pixels x 16 output channels per invocation) with the weights in
                  // a uniform buffer, one dispatch per channel block and input-channel chunk; all shapes
  coopmat = 7,    // fp16 only: the GPU family's implicit GEMM on cooperative matrices (tensor cores,
                  // VK_NV_cooperative_matrix: fp16 operands, fp32 accumulators), any kernel and stride,
                  // operands staged in shared memory, epilogue fused, one dispatch; conv2d_coopmat.cpp.
                  // Tests run its emulated form where the device has none.
  pointwise = 8,  // 1x1 stride 1 (pad 0): one dispatch per block of output channels and chunk of input channels
                  // reads the input slice in place and writes the output slice (bias, activation, residual
                  // in the last chunk); the chunk's channel loop unrolled so the weights load as scalars on
                  // llvmpipe; conv2d_pointwise.cpp
  // The GPU family (conv2d_igemm.cpp, kernels/igemm.hpp): any kernel, stride and padding as one tiled
  // implicit GEMM dispatch with the epilogue fused (split-K adds a reduce where the output gives the
  // device too few workgroups). BM output channels x BN pixels per workgroup:
  igemm_l = 9,   // 128 x 128, 8 x 8 per invocation (wide layers)
  igemm_m = 10,  // 64 x 64, 4 x 4
  igemm_s = 11,  // 32 x 64, 4 x 4 (up to 32 output channels)
  igemm_n = 12,  // 16 x 128, 4 x 4 (heads: up to 16 output channels)
};
// Whether `a` is one of the igemm_* tile variants.
bool is_igemm(ConvAlgo a);
const char* conv_algo_name(ConvAlgo a);

// What the heuristic on a GPU (any device that is not a CPU) looks at: the shape, and which
// algorithms apply to it (Conv2d::supports). A pure function, so that its rules are tested on lavapipe.
struct GpuConvFacts {
  int kernel = 3, stride = 1;
  int64_t cin = 0, cout = 0, pixels = 0;  // pixels: output pixels of the whole batch
  int64_t cores = 0;                      // DeviceInfo::compute_units (0: unknown)
  bool coopmat = false;                   // the coopmat path applies to this conv and input
};
ConvAlgo gpu_conv_heuristic(const GpuConvFacts& f);

// Output extent of a convolution along one axis: floor((in + 2 pad - k) / stride) + 1.
int64_t conv_output_size(int64_t in, int kernel, int stride, int pad);

// CPU reference: plain loops, double accumulation. weight [cout, cin, k, k], bias [cout] (or empty
// data: no bias). `out` must already have the output's extent.
void conv2d_ref(HostSlice in, HostSliceOut out, const HostTensor& weight, const HostTensor& bias,
                const Conv2dParams& params, std::optional<HostSlice> residual = {});

// A conv's input and output folded into the GPU family's addressing (kernels/igemm.hpp): the input is
// pieces concatenated along the channels, read as they are, reflection-padded to padded_h x padded_w
// with the pieces at (top, left) (the UNets' size adapter), space-to-depth (PixelUnshuffle(2)) or
// depth-to-space (PixelShuffle(2));
// the output slice is the conv's output from (crop_top, crop_left); with tanh_scale > 0 it is
// tanh_scale x tanh(conv) (for a conv without activation). Exact: the separate ops' values.
struct ConvFold {
  InputMap map = InputMap::none;
  int64_t padded_h = 0, padded_w = 0, top = 0, left = 0;  // reflect_pad
  int64_t crop_top = 0, crop_left = 0;
  float tanh_scale = 0.f;
  // The input as the conv sees it, from the pieces' shapes (equal batch and extent; an Error otherwise).
  Shape conv_input(const std::vector<Shape>& pieces, const std::string& who) const;
  // The channels a piece of c channels gives the conv's input.
  int64_t piece_channels(int64_t c) const {
    return map == InputMap::space_to_depth ? 4 * c : map == InputMap::depth_to_space ? c / 4 : c;
  }
};

// CPU reference of a folded conv: the separate ops (reflection_pad_ref, space_to_depth_ref, conv2d_ref,
// crop_ref, tanh) composed.
void conv2d_folded_ref(const std::vector<HostSlice>& pieces, const ConvFold& fold, HostSliceOut out,
                       const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
                       std::optional<HostSlice> residual = {});

// Scratch buffers of the multi-pass algorithms (Winograd's transformed tiles). Share one between
// all convs of a model: buffers only grow, and a grown-out buffer stays alive (an already recorded
// dispatch may still use it) until the workspace is destroyed, which must be after the last submit.
class ConvWorkspace {
 public:
  // A buffer of at least `bytes` bytes for `slot` (0, 1, ...); contents undefined.
  const Tensor& get(Context& ctx, int slot, uint64_t bytes);

 private:
  std::vector<std::unique_ptr<Tensor>> slots_;  // stable addresses while more slots are added
  std::vector<Tensor> retired_;
};

// Winograd's transformed input (V) shared by the 3x3 convs of a dense block, which read growing
// channel prefixes of one input: each transforms only the channels the earlier ones had not (an
// RDB: 288 channels instead of 960). begin() at the start of every block (the input may have
// changed), with the most channels a conv of the block reads; end() after it. Where V of that many
// channels does not fit one texel view, or for other convs, the convs run as without it.
class WinogradInputCache {
 public:
  void begin(int64_t capacity) { *this = {}; capacity_ = capacity; }
  void end() { *this = {}; }
  bool active() const { return capacity_ > 0; }

 private:
  friend class Conv2d;
  struct Key {
    VkBuffer input = VK_NULL_HANDLE, v = VK_NULL_HANDLE;
    uint64_t range_offset = 0;
    uint32_t in_off = 0, in_bs = 0;
    int64_t n = 0, h = 0, w = 0;
    bool operator==(const Key&) const = default;
  };
  Key key_;
  int64_t capacity_ = 0, channels_ = 0;  // V rows of the buffer; rows [0, channels_) hold their tiles
};

class Conv2d {
 public:
  // Uploads (and repacks) the weights once. weight [cout, cin, k, k]; bias count cout or empty.
  // `workspace`: scratch shared with other convs; null creates a private one when first needed.
  // `options`: precision (fp16: f16 weights, inputs, outputs and residuals; an Error on a device
  // without 16-bit storage) and tuning knobs, validated here (an Error names a bad field).
  Conv2d(Context& ctx, const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
         std::string name = "conv2d", std::shared_ptr<ConvWorkspace> workspace = nullptr,
         const ConvOptions& options = {});

  // Records out = act(conv(in) + bias) [+ residual]; out and residual have the output's extent, and
  // in, out and residual the conv's precision (f32 or f16 tensors). Returns the algorithm it recorded
  // (what reports count: automatic resolved for this input, batch included).
  ConvAlgo record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual = {}) const;
  // The same with a forced algorithm (tests and the bench); throws if it does not apply to the shape.
  ConvAlgo record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual, ConvAlgo algo,
                  WinogradInputCache* shared_v = nullptr) const;

  // out = the folded conv of `pieces` (ConvFold) [+ residual], in one dispatch of `algo`: the GPU
  // family (an igemm variant, or coopmat in fp16); automatic takes gpu_choice. Returns the algorithm
  // recorded. conv2d_fold.cpp.
  ConvAlgo record_folded(CommandStream& cs, const std::vector<Slice>& pieces, const ConvFold& fold, Slice out,
                         std::optional<Slice> residual = {}, ConvAlgo algo = ConvAlgo::automatic) const;

  // The algorithm record() runs for `algo` on an input of this shape: `automatic` resolved (the GPU
  // family's choice on a GPU or with set_gpu_family, choose_algorithm's elsewhere; a chunked path
  // replaced where the residual overlaps the output, an inapplicable one by blocked), any other as it
  // is. The one place automatic is resolved: a caller that names the algorithm before recording (a
  // trace) asks here once and passes the answer to record().
  ConvAlgo resolve_algorithm(const Shape& in, ConvAlgo algo, bool residual_in_output) const;
  // The algorithm `automatic` picks for one item of this height and width (record() decides on the
  // whole batch's pixels: resolve_algorithm).
  ConvAlgo choose_algorithm(int64_t h, int64_t w) const;
  // `automatic` takes the GPU family's choice (gpu_conv_heuristic) on any device, lavapipe included
  // (the default on devices that are not CPUs): `--conv-choice gpu`, tests, dispatch counts.
  void set_gpu_family(bool on) { gpu_family_ = on; }
  ConvAlgo gpu_choice(const Shape& in) const;  // gpu_conv_heuristic's answer for this input
  // Every algorithm record() accepts for this input, naive left out (the baseline, 10-50x slower):
  // the candidates a measured choice times. `residual_in_output`: the residual overlaps the output
  // (see residual_overlaps_output), which the chunked direct path cannot add.
  std::vector<ConvAlgo> candidates(const Shape& in, bool residual_in_output = false) const;
  bool residual_overlaps_output(const Slice& out, const std::optional<Slice>& residual) const;
  // Whether `algo` runs in several input-channel chunks that add to the output (direct, pointwise):
  // it then cannot add a residual that overlaps the output.
  bool accumulates_in_output(ConvAlgo algo) const;
  bool supports(ConvAlgo algo) const;
  // Whether `algo` can run an input of this shape (Winograd's scratch must fit one binding).
  bool supports(ConvAlgo algo, const Shape& in) const;
  // Caps Winograd's transformed-input scratch (it then runs in chunks of input channels that the
  // GEMM accumulates); default 64 MiB (and never above maxStorageBufferRange). Tests, memory tuning.
  void set_winograd_scratch_limit(uint64_t bytes);
  int64_t winograd_chunk(const Shape& in) const;
  // Caps the input channels per dispatch of the direct path (default: as many as fit one uniform
  // binding); several chunks then accumulate in the output. Tests.
  void set_direct_chunk_limit(int64_t channels) { direct_chunk_limit_ = channels; }  // input channels (x4 for 5x5) per chunk
  // Caps the input channels per dispatch of the pointwise path (default: at most 128, evened out). Tests.
  void set_pointwise_chunk_limit(int64_t channels) { pointwise_chunk_limit_ = channels; }
  // direct and pointwise read their input, winograd its input, V, U and M, through uniform texel
  // buffers (a gather on lavapipe, where a storage-buffer load is a per-lane loop) where each bound
  // range fits maxTexelBufferElements; false forces the storage-buffer variants (tests).
  void set_texel_fetch(bool on) { texel_fetch_ = on; }
  // pointwise fetches pixel pairs (an RG texel view) where the plane and offsets are even; false: single
  // pixels (tests, bench).
  void set_pointwise_pairs(bool on) { pointwise_pairs_ = on; }
  // Tests: `coopmat` runs the emulated form of its shader (plain GLSL with the same tiling, fragments
  // 16 x n x k; n, k 8 or 16) where the device has no cooperative matrix (supports() then says yes).
  void set_coopmat_emulation(bool on, uint32_t n = 8, uint32_t k = 16);
  // Splits of the igemm reduction: 0 chooses per device and shape, n > 0 forces n (tests).
  void set_igemm_splits(int n) { igemm_splits_forced_ = n; }
  // What `algo`'s tiles imply for an input of this shape: multiply-adds and global / shared bytes.
  ConvCost cost(ConvAlgo algo, const Shape& in) const;
  Shape output_shape(const Shape& in) const;  // {n, cout, oh, ow}
  double flop(const Shape& in) const;         // 2 x multiply-adds of the direct algorithm
  int64_t cin() const { return cin_; }
  int64_t cout() const { return cout_; }
  const Conv2dParams& params() const { return params_; }
  const std::string& name() const { return name_; }
  Precision precision() const { return precision_; }

 private:
  // What record() resolved for one algorithm's dispatches.
  struct Push {
    uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs;
    uint32_t cin, h, w, cout, oh, ow, pad;
    uint32_t co0 = 0;  // direct: first output channel of the dispatch (the other shaders ignore it)
  };
  struct Recording {
    Shape is, os;
    BoundSlice in, out, res;  // res: the bias when there is no residual (never read then)
    bool has_res = false;
    Push push;
    std::vector<uint32_t> spec;  // K, STRIDE, ACT, SLOPE, HAS_RES
    DispatchInfo info;
    WinogradInputCache* shared_v = nullptr;
  };
  void record_naive(CommandStream& cs, const Recording& r) const;
  void record_blocked(CommandStream& cs, const Recording& r) const;
  void record_direct(CommandStream& cs, const Recording& r) const;    // conv2d_direct.cpp
  void record_winograd(CommandStream& cs, const Recording& r) const;  // conv2d_winograd.cpp
  void record_winograd_items(CommandStream& cs, const Recording& r) const;  // one group of batch items
  bool winograd_m_fits(const Shape& in) const;  // M of all of `in`'s items in one binding
  void record_gemm(CommandStream& cs, const Recording& r) const;      // conv2d_winograd.cpp
  void record_coopmat(CommandStream& cs, const Recording& r) const;   // conv2d_coopmat.cpp
  void record_pointwise(CommandStream& cs, const Recording& r) const;  // conv2d_pointwise.cpp
  void record_igemm(CommandStream& cs, const Recording& r, ConvAlgo algo) const;  // conv2d_igemm.cpp
  // What record_igemm, record_coopmat and record_folded share: the packed weights and tile of `algo`
  // (an igemm variant or coopmat) bound, the split-K count, the dispatch (conv2d_igemm.cpp).
  void record_gpu_family(CommandStream& cs, ConvAlgo algo, const IgemmProblem& pb, IgemmBindings b,
                         const DispatchInfo& info) const;
  IgemmProblem igemm_problem(const Shape& in) const;                            // conv2d_igemm.cpp
  bool igemm_fits_shape(ConvAlgo algo, const Shape& in) const;                  // conv2d_igemm.cpp
  void pack_igemm() const;                                                       // conv2d_igemm.cpp
  static IgemmTile igemm_tile(ConvAlgo algo);                                    // conv2d_igemm.cpp
  // The 1x1 paths' shared passes (gemm, coopmat; conv2d_winograd.cpp): input channels [c0, c0 + cn)
  // packed into `v` as `rows` (>= cn; the extra rows zero) x pix_pad values, and M [cout_pad][pix_pad]
  // + bias, activation and residual into the output slice. `tag` names the dispatches.
  void record_1x1_pack(CommandStream& cs, const Recording& r, const BufferRange& v, int64_t c0, int64_t cn,
                       int64_t rows, int64_t pix_pad, const std::string& tag) const;
  void record_1x1_output(CommandStream& cs, const Recording& r, const BufferRange& m, int64_t pix_pad,
                         const std::string& tag) const;
  bool coopmat_applies() const;                  // conv2d_coopmat.cpp: supports(coopmat)
  bool coopmat_fits(const Shape& in) const;      // conv2d_coopmat.cpp: supports(coopmat, in)
  IgemmTile coopmat_tile_for_device() const;     // conv2d_coopmat.cpp: the fragments the device (or emulation) has
  void choose_blocking(const ConvOptions& options);
  // Packings other than the automatic path's are uploaded on first use (record is const).
  void pack_naive() const;
  void pack_blocked() const;
  void pack_direct() const;  // conv2d_direct.cpp
  void pack_winograd();      // conv2d_winograd.cpp
  void pack_gemm();          // conv2d_winograd.cpp
  void pack_winograd8();  // conv2d_winograd.cpp: U of the 8x8-tile forms
  void pack_coopmat() const;  // conv2d_coopmat.cpp
  void pack_pointwise() const;  // conv2d_pointwise.cpp
  // The direct and pointwise layout [cout/cob][cin_pad + tail][k*k][cob] of the weights, zero-padded
  // (+ 8 values for fp16's whole 16-byte entries); conv2d_direct.cpp.
  std::vector<float> pack_channel_blocks(int64_t cob, int64_t cin_pad, int64_t tail_channels) const;
  bool pointwise_applies() const;  // conv2d_pointwise.cpp: supports(pointwise)
  UniformSlabChunks pointwise_chunks() const;  // input-channel chunks of its uniform weight slabs
  UniformSlabChunks direct_chunks() const;  // input-channel chunks of the uniform weight slabs
  // A packed weight array on the device in the conv's precision (common.hpp's upload_weights).
  Tensor upload_weights(const std::vector<float>& w) const;
  size_t elem_bytes() const { return dtype_size(precision_dtype(precision_)); }
  // Whether a texel view of `texel_bytes`-byte texels over `bytes` may be bound: texel fetch on
  // (set_texel_fetch) and within maxTexelBufferElements; the storage-buffer forms otherwise.
  bool texel_fits(uint64_t bytes, uint64_t texel_bytes) const;
  // The bound input as a one-value texel view (R32, R16 in fp16); a storage binding ignores the format.
  Arg input_texel_arg(const Recording& r) const;
  std::string shader(const char* base) const { return shader_for(ctx_, base, precision_, name_); }

  Context& ctx_;
  std::string name_;
  Conv2dParams params_;
  Precision precision_ = Precision::fp32;
  int64_t cin_ = 0, cout_ = 0;
  HostTensor weight_host_;         // as given, for the lazily uploaded packings
  std::vector<float> bias_host_;   // [cout], zeros when none was given
  mutable Tensor weight_;          // [cout][cin][k][k] as given (naive)
  Tensor bias_;                    // [cout], always f32
  mutable Tensor weight_blocked_;  // [ceil(cout/COB)][cin][k*k][COB], zero-padded output channels
  mutable Tensor bias_blocked_;    // [ceil(cout/COB)*COB], f32
  int64_t blocked_cob_ = 8;  // output channels per invocation of the blocked path (4, 8 or 16)
  uint32_t blocked_px_ = 8;  // output pixels per invocation of the blocked path
  mutable Tensor weight_direct_;  // [ceil(cout/COB)][cin (+ one chunk of padding)][k*k][COB]
  int64_t direct_cob_ = 16;  // output channels per invocation of the direct path
  uint32_t direct_px_ = 8;   // output pixels per row and invocation of the direct path
  uint32_t direct_py_ = 1;   // output rows per invocation of the direct path
  int64_t direct_chunk_limit_ = 0;  // 0: none
  bool texel_fetch_ = true;
  Tensor weight_winograd_; // U = G g G^T: [36 or 64 positions][virtual cin][cout_pad]
  Tensor weight_gemm_;     // 1x1: [cin][cout_pad] (the transpose), for the gemm path
  int64_t gemm_cob_ = 8;     // output channels per GEMM invocation (winograd and gemm)
  uint32_t gemm_tv_ = 4;     // vec4s of tiles per GEMM invocation
  int64_t gemm_cout_pad_ = 0, winograd_ks_ = 1;
  // The Winograd form (ConvOptions::winograd_tile): F(4x4, 3x3) on 6x6 tiles, 36 positions (3x3; a 5x5
  // kernel split into four; 3x3 stride 2 as four phases), or on 8x8 tiles, 64 positions: F(4x4, 5x5)
  // and F(6x6, 3x3) (stride 1).
  enum class WinogradForm { f4x4_3x3, f4x4_5x5, f6x6_3x3 };
  WinogradForm winograd_form_ = WinogradForm::f4x4_3x3;
  bool winograd_tile8() const { return winograd_form_ != WinogradForm::f4x4_3x3; }
  int64_t winograd_npos() const { return winograd_tile8() ? 64 : 36; }
  int64_t winograd_tile_out() const { return winograd_form_ == WinogradForm::f6x6_3x3 ? 6 : 4; }
  const char* winograd_shader_stem() const {
    return winograd_form_ == WinogradForm::f4x4_5x5 ? "winograd45" : (winograd_form_ == WinogradForm::f6x6_3x3 ? "winograd63" : "winograd");
  }
  uint64_t winograd_scratch_limit_ = 64ull << 20;  // bytes of transformed input tiles per chunk
  mutable Tensor weight_coopmat_;  // fp16 [cout_pad][kpad], kk = ci*k*k + tap (zero-padded to 16): coopmat
  bool coopmat_emulated_ = false;
  uint32_t coopmat_emulated_n_ = 8, coopmat_emulated_k_ = 16;
  mutable Tensor weight_pointwise_;  // [ceil(cout/COB)][cin_pad (+ one chunk of padding)][COB]
  int64_t pointwise_cob_ = 12;   // output channels per invocation of the pointwise path
  uint32_t pointwise_px_ = 1;    // pixels per invocation of the pointwise path
  bool pointwise_pairs_ = true;
  int64_t pointwise_chunk_limit_ = 0;  // input channels per pointwise dispatch at most (0: no limit)
  mutable Tensor weight_igemm_;  // A of the igemm family: [kpad][cout_pad] (kernels/igemm.hpp)
  int igemm_splits_forced_ = 0;
  bool gpu_family_ = false;
  mutable std::shared_ptr<ConvWorkspace> workspace_;
};

}  // namespace vkunroll
