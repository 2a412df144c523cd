// Tiled and event-driven sparse execution of the SelfUnroll model (docs/tiling.md).
//
// The image is cut into tiles: an interior (the pixels a tile writes) grown by a halo (context the
// network reads, clipped to the image). Each tile's input rect runs through Model::run, tiles of
// equal shape batched together, and the interiors are stitched into full-size outputs. This bounds
// every device tensor by the tile size (any image size runs), and lets tiles without events skip
// the network (sparse policies).
//
//   TileOptions t;
//   t.tile = 0;                       // 0: untiled if it fits the backend, else the largest tile that fits
//   t.halo = 64;                      // exact when >= exact_halo(cfg, mode, max |flow|)
//   t.sparse = SparsePolicy::exact;   // tiles with no ev1/ev2 event take the RS pixels (gated variant: clamp(phys))
//   TiledResult r = run_tiled(model, inputs, run_options, t);
//   r.outputs[ModelOutput::fused], r.active_fraction, r.stage_ms["record"], ...
//
// Alignment (why tile and halo are multiples of 32): the model works at even size (space_to_depth)
// and the untiled run's UNets pad their input to multiples of 32. Tile origins on the 32-grid see
// the untiled run's space_to_depth cells, and each batch of tiles pads its UNet input
// (RunOptions::unet_pad) so that it sees the untiled stride grid (the untiled offset modulo the
// UNets' stride, 8 for depth 3) and, at the image border, the untiled run's border padding;
// elsewhere only up to the stride, not to 32. A tiled run with halo >= exact_halo() then equals the
// untiled one bit for bit on the CPU backend, for any image size (tests/test_tiling.cpp); smaller
// halos differ by a measured tolerance.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "vkunroll/base/shape.hpp"
#include "vkunroll/host/model/model.hpp"

namespace vkunroll {

// Tile origins, interiors and halos are multiples of this (see above).
constexpr int64_t kTileAlign = 32;

struct Tile {
  Rect interior;  // pixels this tile writes; the interiors partition the image
  Rect input;     // interior grown by the halo, clipped to the image: what the network reads
};

struct TilePlan {
  int64_t height = 0, width = 0;
  int64_t tile_h = 0, tile_w = 0;  // interior size (the last row/column of tiles may be smaller)
  int64_t halo = 0;
  std::vector<Tile> tiles;  // row-major
  bool untiled() const { return tiles.size() == 1; }
};

// Tiles of tile_h x tile_w interior (multiples of kTileAlign, or >= the image side) with `halo`
// (a multiple of kTileAlign) on every side. Throws Error naming the bad value.
TilePlan make_tile_plan(int64_t height, int64_t width, int64_t tile_h, int64_t tile_w, int64_t halo);
// The input rect of `interior` (on the 32-grid): grown by `halo`, clipped to the image, and at
// least 32 pixels a side where the image is (a 4-row last tile with halo 0 reads 32 rows).
Rect input_rect(const Rect& interior, int64_t halo, int64_t height, int64_t width);

// Receptive-field radii (pixels of the full-resolution image, one side) of each branch, from the
// layer list: how far an output pixel's value can depend on input pixels.
struct ReceptiveRadius {
  int64_t synthesis = 0;  // E-IC_T: E, sys (convs at half resolution after space_to_depth)
  int64_t flownet = 0;    // flow
  int64_t fusion_net = 0;
  int64_t attfusion_net = 0;
  int64_t fused = 0;      // fusion_net + max(synthesis, flownet): the S output, flow displacement excluded
  int64_t out = 0;        // max(fused, attfusion_net + max(synthesis, flownet)): the M output, same
};
ReceptiveRadius receptive_radius(const ModelConfig& cfg);
// One UNet: the head, each level's ResBlock + stride-2 conv, the bottom, each level's deconv,
// conv1 and ResBlock, the pred conv: 12 * 2^depth - 6.
int64_t unet_receptive_radius(const UnetConfig& u);

// The halo for which a tiled run equals the untiled one: the output's receptive radius, where
// backward_warp's displacement (it samples rs at +flow, up to 100 px) may reach further:
// fusion_net + max(synthesis, flownet, ceil(max_flow) + 1); rounded up to kTileAlign.
int64_t exact_halo(const ModelConfig& cfg, Mode mode, double max_flow);

// Which rect's events decide a tile (its "activity rect"): the input rect; for the gated variant
// (physics_gate r >= 0) the interior grown by r, since with no event there the gate is 0 on the
// whole interior and the S output is clamp(phys, 0, 1) exactly, whatever the network computes.
enum class SparsePolicy {
  off,    // every tile runs the network
  exact,  // tiles whose activity rect holds no ev1/ev2 event take the standing image (below)
  fast,   // tiles whose ev1+ev2 events per pixel of the activity rect are below `threshold` take it
};
SparsePolicy parse_sparse_policy(const std::string& s, const std::string& what);  // "off" | "exact" | "fast"
const char* sparse_policy_name(SparsePolicy p);

struct TileOptions {
  int64_t tile = 0;      // interior side (multiple of 32); 0: untiled if the image fits, else the largest that fits
  int64_t halo = 64;     // multiple of 32; ignored when the run is untiled
  SparsePolicy sparse = SparsePolicy::off;
  double threshold = 0.01;  // fast: events per pixel (ev1 + ev2 |counts| over the activity rect)
  // Limit for any one tensor when choosing the tile (0: the backend's max_buffer_bytes()).
  uint64_t max_buffer_bytes = 0;
  // Most tile items (tiles x batch items) per Model::run call (0: as many tiles as hold no more
  // pixels than one untiled target, and at most 256 MiB of input copies; M: whole pairs).
  int max_batch = 0;
  // Sparse only: per target, each 4-connected group of active tiles runs as one rect (the group's
  // bounding box, one halo around it), so neighbouring active tiles do not each pay a halo. A group
  // wider or taller than max(tile, max_region) runs tile by tile (max_region 0: the largest tile
  // that fits the device, choose_tile()).
  bool merge_active = true;
  int64_t max_region = 0;
  // With merge_active: a group whose bounding box holds inactive tiles runs instead as rectangles
  // of its tiles when their input rects hold fewer pixels than the box's. Fewer pixels, less
  // context where a rectangle's edge cuts a moving object (docs/tiling.md: -0.2 dB at halo 0 on
  // nat_03002), so off by default; exact at the exact halo either way.
  bool split_groups = false;
};

// Which tiles and targets ran, and how much work that was.
struct TileStats {
  TilePlan plan;
  int64_t tiles = 0;          // tiles x targets considered
  int64_t tiles_run = 0;      // of them, run through the network
  double active_fraction = 1; // tiles_run / tiles
  std::vector<double> target_active_fraction;  // per target (S: batch item; M: pair)
  // Pixels the network processed (input rects of the tiles run) / pixels of the untiled run of
  // every target: the halo overhead times the active fraction (1 for an untiled dense run).
  double work_ratio = 1;
  // Host wall milliseconds: "plan" (tile choice, activity), "record" (the network, cuts and
  // stitches; on the device only recorded, GPU time is the context's DeviceTraffic::gpu_ms).
  std::map<std::string, double> stage_ms;
};

struct TiledResult : TileStats {
  std::map<ModelOutput, HostTensor> outputs;  // as Model::run: full H x W
};
struct TiledBuffers : TileStats {
  std::map<ModelOutput, Buffer> outputs;  // backend buffers [B or K, c, H, W], held by the caller
};

// Per batch item, the summed-area table ((H + 1) x (W + 1)) of the events ev1 and ev2 select at
// each pixel: what the sparse policies decide on.
using ActivityTables = std::vector<std::vector<double>>;
// From host tensors: the sum of |ev1| + |ev2| over the channels.
ActivityTables activity_tables(const ModelInputs& in);
// From per-pixel counts ([items][H * W], e.g. kernels' selected_event_counts), no tensor readback.
ActivityTables activity_tables(const std::vector<std::vector<uint32_t>>& counts, int64_t height, int64_t width);

// The largest tile interior (multiple of 32, square, clamped to the image) whose input rect
// (interior + 2 halo) fits every tensor of one batch item under the buffer limit; the whole
// image (tile = max side) when the untiled run fits. Throws Error when even 32 + 2 halo does not fit.
int64_t choose_tile(const Model& model, int64_t height, int64_t width, Mode mode, int64_t halo, uint64_t max_buffer_bytes);

// Runs the model tile by tile (see the top of this file) on inputs in the backend, recorded without
// waiting: tiles are cut (crop) and stitched (copy_rect) on the device. Inactive tiles (sparse
// policy) take the standing image, rs or (gated variant) clamp(phys, 0, 1), for sys, fused and out
// (S: the item's; M: frame 1 of the pair), rs for warped, E = 0, flow = 0, m = 1 (so with the
// gate, `exact` S fused equals the dense run's; M's out is frame 1's, not the dense blend).
// `activity` (per batch item) is needed unless topt.sparse is off.
TiledBuffers run_tiled_on_backend(Model& model, const ModelBuffers& in, const RunOptions& opt, const TileOptions& topt,
                                  const ActivityTables* activity);
// The same from and to the host: tiles cut from the host inputs and uploaded batch by batch, so inputs
// of any size run (each upload stays within one binding); one submission per batch.
TiledResult run_tiled(Model& model, const ModelInputs& in, const RunOptions& opt, const TileOptions& topt);

// The untiled run's UNet input offset along one axis (half the padding of the even size to 32):
// a border tile's UNets place their input there, the others at it modulo the UNets' stride.
int unet_offset(int64_t size);

// The UNet padding (before, after) along one axis of a batch of input rects n long in an image
// `size` long, for the UNets' `stride` (run_tiled passes it per batch as RunOptions::unet_pad).
// Aligned (halo > 0): the untiled run's stride grid (its offset modulo the stride: every rect starts
// on the 32-grid), and where a rect of the batch reaches the image's start or end the untiled run's
// padding on that side, elsewhere only up to the stride. The batch's other rects then get more
// reflection than they need, outside their input rects, which their interiors do not see at the
// exact halo. Not aligned (halo 0, far from exact anyway): centered, up to the stride.
std::pair<int, int> unet_axis_padding(bool aligned, bool at_start, bool at_end, int64_t n, int64_t size, int64_t stride);

}  // namespace vkunroll
