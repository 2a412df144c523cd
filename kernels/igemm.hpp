// The GPU conv family's shared core (shaders/conv2d_igemm.comp): the tile variants, the packing of
// weights as the GEMM's A, the split-K choice, one conv's (or one transposed conv's phases') dispatch,
// and the traffic its tiles imply. Conv2d (the igemm_* algorithms) and ConvTranspose2d (its igemm
// algorithm, the sub-pixel phases) record through it.
#pragma once
#include <cstdint>
#include <functional>
#include <vector>

#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

class ConvWorkspace;
struct DeviceInfo;

// A workgroup computes BM output channels x BN output pixels, BK reduction steps per shared-memory
// stage; an invocation TM x TN of them (<= 64 fp32 accumulators).
struct IgemmTile {
  uint32_t bm = 64, bn = 64, bk = 16, tm = 4, tn = 4;
  // The tensor-core form (conv2d_igemm_coopmat, fp16): warps of `warp` invocations, wm x wn of them,
  // each fm x fn fragments of lm x ln (lk deep: the stage); bm, bn and bk follow (coopmat_tile).
  bool coopmat = false, emulated = false;
  uint32_t lm = 16, ln = 8, lk = 16, fm = 2, fn = 4, wm = 2, wn = 2, warp = 32;
  uint32_t threads() const { return coopmat ? wm * wn * warp : (bm / tm) * (bn / tn); }
};
// 64 output channels x 64 pixels of lm x ln x lk fragments on 2 x 2 warps (32 pixels a warp).
IgemmTile coopmat_tile(uint32_t lm, uint32_t ln, uint32_t lk, bool emulated);

// How a conv reads its input and writes its output beyond plain slices, folded into the GEMM's
// addressing (exact: the same values the separate ops would have made). The input is the
// concatenation of pieces along the channels, read as they are, reflection-padded (the UNets' size
// adapter), space-to-depth (SFENet1's PixelUnshuffle(2)) or depth-to-space (UPNet.2's PixelShuffle(2));
// the output slice is the conv's output from (crop_y, crop_x) (the size adapter's crop), optionally
// through `scale` x tanh.
enum class InputMap : uint32_t { none = 0, reflect_pad = 1, space_to_depth = 2, depth_to_space = 3 };
constexpr int kMaxInputPieces = 5;

// What one conv (MODE 0) or one transposed conv (MODE 1, every phase) asks of the shader.
struct IgemmProblem {
  uint32_t kh = 3, kw = 3, stride = 1, pad = 1;  // MODE 1: the sub-kernel's side, the transposed conv's stride and pad
  bool transposed = false;
  int64_t cin = 0, cout = 0;
  Shape in, out;           // the input as the conv sees it (padded, rearranged), the output slice
  int64_t gh = 0, gw = 0;  // GEMM pixel grid per item (and phase): the conv's output extent (MODE 1: per phase)
  Act act;
  Precision precision = Precision::fp32;
  // Folds (InputMap above): the pieces' channels as the conv sees them, their extent and origin.
  InputMap map = InputMap::none;
  std::vector<int64_t> piece_channels;  // empty: one piece, all of `in`
  int64_t src_h = 0, src_w = 0, src_y = 0, src_x = 0;
  int64_t crop_y = 0, crop_x = 0;
  float scale = 1.f;  // the output is scale x act(...)
  int64_t taps() const { return int64_t(kh) * kw; }
  int64_t phases() const { return transposed ? int64_t(stride) * stride : 1; }
  int64_t npix() const { return in.n * gh * gw; }
};

// The reduction is tap-major: row k = tap * cin_pad + ci (tap = ky * kw + kx), the input channels
// padded to a whole number of the deepest stage (every tile's BK divides cin_pad), so that a stage
// reads one tap: one bounds test and one address per column and stage, not per element.
int64_t igemm_cin_pad(int64_t cin);
int64_t igemm_kpad(const IgemmProblem& pb);  // taps x cin_pad: whole stages
int64_t igemm_cout_pad(int64_t cout);        // to whole vec4s

// The weight of tap `tap` (ky * kw + kx) of input channel ci for output channel co, phase `phase`.
using IgemmWeight = std::function<float(int64_t phase, int64_t ci, int64_t tap, int64_t co)>;
// A as conv2d_igemm reads it: [phase][kpad][cout_pad], zeros in the padding.
std::vector<float> igemm_pack(int64_t phases, int64_t cin, int64_t taps, int64_t cout, const IgemmWeight& weight);
// A as conv2d_igemm_coopmat reads it: [cout_pad][kpad] (one phase), zeros in the padding.
std::vector<float> igemm_pack_rows(int64_t cin, int64_t taps, int64_t cout, int64_t cout_pad, const IgemmWeight& weight);

// Splits of the reduction so that the device gets enough workgroups (about two per shader core) where
// the output alone gives few (deep, small layers), each split at least 4 stages deep, their partial sums
// within `scratch_limit` bytes; 1 where none is needed. `forced` > 0 asks for that many (tests).
uint32_t igemm_splits(const DeviceInfo& info, const IgemmTile& tile, const IgemmProblem& pb, uint64_t scratch_limit,
                      int forced = 0);
// Whether the grid fits the device's workgroup counts.
bool igemm_fits(const DeviceInfo& info, const IgemmTile& tile, const IgemmProblem& pb);

// Records the dispatch (and, split, the reduce into the output). `weight`: the packed A; `bias`: fp32
// [cout]; `res`: the residual slice, or any bound range when there is none.
struct IgemmBindings {
  BoundSlice in, out, res;  // in: input piece 0
  bool has_res = false;
  Arg weight, bias;
  std::vector<BoundSlice> more_pieces;  // input pieces 1.. (IgemmProblem::piece_channels)
};
void igemm_record(Context& ctx, CommandStream& cs, ConvWorkspace& workspace, const IgemmTile& tile,
                  const IgemmProblem& pb, const IgemmBindings& b, uint32_t splits, const DispatchInfo& info);

// The multiply-adds the tiles compute (padding included) and the bytes they move through global and
// shared memory: what a tile size implies, for reasoning where no GPU is at hand.
struct ConvCost {
  double fma = 0;           // multiply-adds executed (padded tiles included)
  double global_bytes = 0;  // bytes loaded from and stored to device memory
  double shared_bytes = 0;  // bytes stored to and loaded from shared memory (0 for algorithms without)
};
ConvCost igemm_cost(const IgemmTile& tile, const IgemmProblem& pb, uint32_t splits);

}  // namespace vkunroll
