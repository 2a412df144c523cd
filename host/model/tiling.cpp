#include "vkunroll/host/model/tiling.hpp"

#include <algorithm>
#include <cmath>

#include "vkunroll/base/int_math.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

int unet_offset(int64_t size) {
  const int64_t even = round_up(size, 2);
  return static_cast<int>((round_up(even, 32) - even) / 2);
}

std::pair<int, int> unet_axis_padding(bool aligned, bool at_start, bool at_end, int64_t n, int64_t size, int64_t stride) {
  const int64_t ne = round_up(n, 2);
  if (!aligned) {
    const int64_t pad = round_up(ne, stride) - ne;
    return {int(pad / 2), int(pad - pad / 2)};
  }
  const int64_t full = round_up(size, 2), off = unet_offset(size), full_after = round_up(full, 32) - full - off;
  const int64_t before = at_start ? off : off % stride;
  const int64_t after = at_end ? full_after : round_up(before + ne, stride) - before - ne;
  return {int(before), int(after)};
}

namespace {

void check_aligned(int64_t v, const char* what) {
  if (v < 0 || v % kTileAlign)
    throw UsageError(std::string("tiling: ") + what + " " + std::to_string(v) + " must be a non-negative multiple of " +
                std::to_string(kTileAlign) + " (tile alignment, docs/tiling.md)");
}

// The input range (start, length) of the interior [a, a + n) along an axis of `size` pixels.
std::pair<int64_t, int64_t> input_range(int64_t a, int64_t n, int64_t halo, int64_t size) {
  int64_t lo = std::max<int64_t>(0, a - halo), hi = std::min(size, a + n + halo);
  // At least 32 pixels (the UNets reflect up to 31), on the 32-grid (only with halo 0).
  if (hi - lo < kTileAlign) lo = std::max<int64_t>(0, (hi - kTileAlign) / kTileAlign * kTileAlign);
  return {lo, hi - lo};
}

// Tile starts and interior lengths along one axis; input ranges grown by the halo, clipped.
void axis_tiles(int64_t size, int64_t tile, int64_t halo, std::vector<std::pair<int64_t, int64_t>>& interior,
                std::vector<std::pair<int64_t, int64_t>>& input) {
  for (int64_t a = 0; a < size; a += tile) {
    const int64_t n = std::min(tile, size - a);
    interior.push_back({a, n});
    input.push_back(input_range(a, n, halo, size));
  }
}

}  // namespace

Rect input_rect(const Rect& interior, int64_t halo, int64_t height, int64_t width) {
  const auto [y, h] = input_range(interior.y, interior.h, halo, height);
  const auto [x, w] = input_range(interior.x, interior.w, halo, width);
  return {y, x, h, w};
}

TilePlan make_tile_plan(int64_t height, int64_t width, int64_t tile_h, int64_t tile_w, int64_t halo) {
  if (height < 2 || width < 2)
    throw DataError("tiling: image " + std::to_string(width) + "x" + std::to_string(height) + " (expected H and W >= 2)");
  if (tile_h <= 0 || tile_w <= 0)
    throw UsageError("tiling: tile " + std::to_string(tile_w) + "x" + std::to_string(tile_h) + " (expected a positive size)");
  TilePlan p;
  p.height = height;
  p.width = width;
  p.tile_h = std::min(tile_h, height);
  p.tile_w = std::min(tile_w, width);
  if (p.tile_h < height) check_aligned(p.tile_h, "tile height");
  if (p.tile_w < width) check_aligned(p.tile_w, "tile width");
  check_aligned(halo, "halo");
  p.halo = halo;
  std::vector<std::pair<int64_t, int64_t>> iy, ix, ry, rx;
  axis_tiles(height, p.tile_h, halo, iy, ry);
  axis_tiles(width, p.tile_w, halo, ix, rx);
  for (size_t a = 0; a < iy.size(); ++a)
    for (size_t b = 0; b < ix.size(); ++b)
      p.tiles.push_back({{iy[a].first, ix[b].first, iy[a].second, ix[b].second}, {ry[a].first, rx[b].first, ry[a].second, rx[b].second}});
  return p;
}

int64_t unet_receptive_radius(const UnetConfig& u) {
  // Growth of the input interval an output interval depends on, in full-resolution pixels (a
  // level-i pixel covers a 2^i block): 3x3 conv at level i: 2^i; stride-2 3x3 conv into level i+1:
  // 2^i; kernel-4 stride-2 deconv from level i+1 into level i (rounding included): 2^(i+1).
  int64_t r = 1 + 1;  // head, pred
  for (int i = 0; i < u.depth; ++i) {
    const int64_t s = int64_t(1) << i;
    r += 2 * s + s;              // down: ResBlock (two 3x3) + stride-2 conv
    r += 2 * s + s + 2 * s;      // up: deconv, conv1, ResBlock
  }
  r += 4 * (int64_t(1) << u.depth);  // bottom: two ResBlocks
  return r;
}

ReceptiveRadius receptive_radius(const ModelConfig& cfg) {
  ReceptiveRadius r;
  // At half resolution (2 px each): SFENet1 5x5 (2), SFENet2, D*C RDB convs, GFF.1, UPNet.0 (1 each);
  // UPNet.2 at full resolution plus the rounding out to 2x2 cells at depth_to_space: 2.
  r.synthesis = 2 * (2 + 1 + int64_t(cfg.D) * cfg.C + 1 + 1) + 2;
  r.flownet = unet_receptive_radius(cfg.flownet);
  r.fusion_net = unet_receptive_radius(cfg.fusion_net);
  r.attfusion_net = cfg.moa ? unet_receptive_radius(cfg.attfusion_net) : 0;
  // The variant's event gate reads ev1/ev2 within its radius: far inside the fusion path's.
  r.fused = std::max<int64_t>(r.fusion_net + std::max(r.synthesis, r.flownet), cfg.physics_gate);
  r.out = cfg.moa ? std::max(r.fused, r.attfusion_net + std::max(r.synthesis, r.flownet)) : r.fused;
  return r;
}

int64_t exact_halo(const ModelConfig& cfg, Mode mode, double max_flow) {
  const ReceptiveRadius r = receptive_radius(cfg);
  // warped(q) reads flow(q) (flownet radius) and rs at q + flow(q) (bilinear: one more pixel).
  const int64_t warp = static_cast<int64_t>(std::ceil(std::max(0.0, max_flow))) + 1;
  int64_t h = std::max<int64_t>(r.fusion_net + std::max({r.synthesis, r.flownet, warp}), cfg.physics_gate);
  if (mode == Mode::m && cfg.moa) h = std::max(h, r.attfusion_net + std::max(r.synthesis, r.flownet));
  return round_up(h, kTileAlign);
}

SparsePolicy parse_sparse_policy(const std::string& s, const std::string& what) {
  if (s == "off") return SparsePolicy::off;
  if (s == "exact") return SparsePolicy::exact;
  if (s == "fast") return SparsePolicy::fast;
  throw OptionError(what, "'" + s + "'", "expected off, exact or fast", opt(what) + " '" + s + "' (expected off, exact or fast)");
}

const char* sparse_policy_name(SparsePolicy p) {
  switch (p) {
    case SparsePolicy::off: return "off";
    case SparsePolicy::exact: return "exact";
    case SparsePolicy::fast: return "fast";
  }
  return "?";
}

int64_t choose_tile(const Model& model, int64_t height, int64_t width, Mode mode, int64_t halo, uint64_t max_buffer_bytes) {
  const int64_t limit = static_cast<int64_t>(max_buffer_bytes);
  const int64_t whole = std::max(height, width);
  if (model.item_buffer_bytes(height, width, mode) <= limit) return whole;
  for (int64_t t = whole / kTileAlign * kTileAlign; t >= kTileAlign; t -= kTileAlign) {
    const int64_t h = std::min(height, t + 2 * halo), w = std::min(width, t + 2 * halo);
    if (model.item_buffer_bytes(h, w, mode, UnetPadding{unet_offset(height), unet_offset(width)}) <= limit) return t;
  }
  throw UsageError("tiling: even a " + std::to_string(kTileAlign) + "-pixel tile with halo " + std::to_string(halo) +
              " needs a buffer above the " + std::to_string(limit >> 20) + " MiB limit; use a smaller halo");
}

}  // namespace vkunroll
