#include "vkunroll/host/model/tiling.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "vkunroll/base/int_math.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {



// The untiled run's UNet input offset along one axis: half of the padding of the even size to 32.
int unet_offset(int64_t size) {
  const int64_t even = round_up(size, 2);
  return static_cast<int>((round_up(even, 32) - even) / 2);
}

void check_aligned(int64_t v, const char* what) {
  if (v < 0 || v % kTileAlign)
    throw Error(std::string("tiling: ") + what + " " + std::to_string(v) + " must be a non-negative multiple of " +
                std::to_string(kTileAlign) + " (tile alignment, docs/tiling.md)");
}

// Tile starts and interior lengths along one axis; input ranges grown by the halo, clipped.
void axis_tiles(int64_t size, int64_t tile, int64_t halo, std::vector<std::pair<int64_t, int64_t>>& interior,
                std::vector<std::pair<int64_t, int64_t>>& input) {
  for (int64_t a = 0; a < size; a += tile) {
    const int64_t n = std::min(tile, size - a);
    int64_t lo = std::max<int64_t>(0, a - halo), hi = std::min(size, a + n + halo);
    // At least 32 pixels (the UNets reflect up to 31), on the 32-grid (only with halo 0).
    if (hi - lo < kTileAlign) lo = std::max<int64_t>(0, (hi - kTileAlign) / kTileAlign * kTileAlign);
    interior.push_back({a, n});
    input.push_back({lo, hi - lo});
  }
}

bool per_target(const std::string& name) { return name == "m" || name == "out"; }

// Crops [n0, n0+1) x all channels x rect of `a` and appends it to `dst`.
void append_crop(const HostTensor& a, int64_t item, const Rect& r, std::vector<float>& dst) {
  const int64_t C = a.shape.c, H = a.shape.h, W = a.shape.w;
  for (int64_t c = 0; c < C; ++c)
    for (int64_t y = r.y; y < r.y + r.h; ++y) {
      const float* s = a.data.data() + ((item * C + c) * H + y) * W + r.x;
      dst.insert(dst.end(), s, s + r.w);
    }
}

// Copies the tile's interior from item `src_item` of `tile_out` (laid out at the input rect) to
// item `dst_item` of `full`.
void stitch(const HostTensor& tile_out, int64_t src_item, const Tile& t, HostTensor& full, int64_t dst_item) {
  const int64_t C = full.shape.c, H = full.shape.h, W = full.shape.w, th = tile_out.shape.h, tw = tile_out.shape.w;
  const int64_t oy = t.interior.y - t.input.y, ox = t.interior.x - t.input.x;
  for (int64_t c = 0; c < C; ++c)
    for (int64_t y = 0; y < t.interior.h; ++y) {
      const float* s = tile_out.data.data() + ((src_item * C + c) * th + oy + y) * tw + ox;
      std::copy(s, s + t.interior.w, full.data.begin() + ((dst_item * C + c) * H + t.interior.y + y) * W + t.interior.x);
    }
}

// Fills the interior of item `dst_item` of `full` with the same rect of item `src_item` of `src`
// (the RS frame; channels of `full`), or with `value` when src is null.
void fill(const HostTensor* src, int64_t src_item, float value, const Rect& r, HostTensor& full, int64_t dst_item) {
  const int64_t C = full.shape.c, H = full.shape.h, W = full.shape.w;
  for (int64_t c = 0; c < C; ++c)
    for (int64_t y = r.y; y < r.y + r.h; ++y) {
      float* d = full.data.data() + ((dst_item * C + c) * H + y) * W + r.x;
      if (src) {
        const float* s = src->data.data() + ((src_item * C + c) * H + y) * W + r.x;
        std::copy(s, s + r.w, d);
      } else {
        std::fill(d, d + r.w, value);
      }
    }
}

// Summed-area table of |ev1| + |ev2| over channels, per batch item: (H+1) x (W+1) doubles.
std::vector<double> activity_table(const ModelInputs& in, int64_t item) {
  const int64_t C = in.ev1.shape.c, H = in.ev1.shape.h, W = in.ev1.shape.w;
  std::vector<double> plane(size_t(H * W), 0.0);
  for (const HostTensor* a : {&in.ev1, &in.ev2})
    for (int64_t c = 0; c < C; ++c) {
      const float* s = a->data.data() + (item * C + c) * H * W;
      for (int64_t i = 0; i < H * W; ++i) plane[size_t(i)] += std::fabs(s[i]);
    }
  std::vector<double> sat(size_t((H + 1) * (W + 1)), 0.0);
  for (int64_t y = 0; y < H; ++y) {
    double row = 0;
    for (int64_t x = 0; x < W; ++x) {
      row += plane[size_t(y * W + x)];
      sat[size_t((y + 1) * (W + 1) + x + 1)] = sat[size_t(y * (W + 1) + x + 1)] + row;
    }
  }
  return sat;
}

double rect_sum(const std::vector<double>& sat, int64_t W, const Rect& r) {
  const int64_t s = W + 1;
  return sat[size_t((r.y + r.h) * s + r.x + r.w)] - sat[size_t(r.y * s + r.x + r.w)] - sat[size_t((r.y + r.h) * s + r.x)] +
         sat[size_t(r.y * s + r.x)];
}

}  // namespace

TilePlan make_tile_plan(int64_t height, int64_t width, int64_t tile_h, int64_t tile_w, int64_t halo) {
  if (height < 2 || width < 2)
    throw Error("tiling: image " + std::to_string(width) + "x" + std::to_string(height) + " (expected H and W >= 2)");
  if (tile_h <= 0 || tile_w <= 0)
    throw Error("tiling: tile " + std::to_string(tile_w) + "x" + std::to_string(tile_h) + " (expected a positive size)");
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
  r.fused = r.fusion_net + std::max(r.synthesis, r.flownet);
  r.out = cfg.moa ? std::max(r.fused, r.attfusion_net + std::max(r.synthesis, r.flownet)) : r.fused;
  return r;
}

int64_t exact_halo(const ModelConfig& cfg, Mode mode, double max_flow) {
  const ReceptiveRadius r = receptive_radius(cfg);
  // warped(q) reads flow(q) (flownet radius) and rs at q + flow(q) (bilinear: one more pixel).
  const int64_t warp = static_cast<int64_t>(std::ceil(std::max(0.0, max_flow))) + 1;
  int64_t h = r.fusion_net + std::max({r.synthesis, r.flownet, warp});
  if (mode == Mode::m && cfg.moa) h = std::max(h, r.attfusion_net + std::max(r.synthesis, r.flownet));
  return round_up(h, kTileAlign);
}

SparsePolicy parse_sparse_policy(const std::string& s, const std::string& what) {
  if (s == "off") return SparsePolicy::off;
  if (s == "exact") return SparsePolicy::exact;
  if (s == "fast") return SparsePolicy::fast;
  throw Error(what + " '" + s + "' (expected off, exact or fast)");
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
    if (model.item_buffer_bytes(h, w, mode, unet_offset(height), unet_offset(width)) <= limit) return t;
  }
  throw Error("tiling: even a " + std::to_string(kTileAlign) + "-pixel tile with halo " + std::to_string(halo) +
              " needs a buffer above the " + std::to_string(limit >> 20) + " MiB limit; use a smaller halo");
}

TiledResult run_tiled(Model& model, const ModelInputs& in, const RunOptions& opt, const TileOptions& topt) {
  TiledResult res;
  const auto t_plan = Clock::now();
  const int64_t B = in.rs.shape.n, H = in.rs.shape.h, W = in.rs.shape.w;
  const bool m_mode = opt.mode == Mode::m;
  const int64_t per = m_mode ? 2 : 1;  // batch items per target
  const Shape ev_shape{B, model.config().ev_channels(), H, W};
  if (in.rs.shape.c != 3 || B < 1 || (m_mode && B % 2))
    throw Error("run_tiled: input 'rs' has shape " + in.rs.shape.str() + ", expected [B,3,H,W] (B even in mode m)");
  for (const auto& [a, name] : {std::pair{&in.ev1, "ev1"}, std::pair{&in.ev2, "ev2"}, std::pair{&in.ev3, "ev3"}})
    if (!(a->shape == ev_shape) || static_cast<int64_t>(a->data.size()) != ev_shape.count())
      throw Error(std::string("run_tiled: input '") + name + "' has shape " + a->shape.str() + ", expected " + ev_shape.str());
  if (static_cast<int64_t>(in.rs.data.size()) != in.rs.shape.count())
    throw Error("run_tiled: input 'rs' holds " + std::to_string(in.rs.data.size()) + " values for shape " + in.rs.shape.str());
  if (topt.sparse == SparsePolicy::fast && !(topt.threshold >= 0))
    throw Error("run_tiled: sparse threshold " + std::to_string(topt.threshold) + " (expected >= 0 events per pixel)");

  const std::vector<std::string> names = Model::resolve_outputs(opt.outputs, opt.mode);

  const uint64_t limit = topt.max_buffer_bytes ? std::min(topt.max_buffer_bytes, model.backend().max_buffer_bytes())
                                               : model.backend().max_buffer_bytes();
  const int64_t tile = topt.tile > 0 ? topt.tile : choose_tile(model, H, W, opt.mode, topt.halo, limit);
  res.plan = make_tile_plan(H, W, tile, tile, topt.halo);
  const int64_t K = B / per;
  res.stage_ms["plan"] = ms_since(t_plan);

  std::map<std::string, double> model_ms;
  RunOptions ro = opt;
  ro.outputs = names;
  ro.stage_ms = &model_ms;
  if (!res.plan.untiled()) {
    // Every input rect starts on the 32-grid, so placing each tile's UNet input at the untiled run's
    // offset puts it on the untiled run's stride grid, and the border tiles get the untiled run's
    // reflection at the image border (docs/tiling.md, alignment).
    ro.unet_pad_top = unet_offset(H);
    ro.unet_pad_left = unet_offset(W);
  }
  auto finish_ms = [&] {
    for (const auto& [k, v] : model_ms) {
      res.stage_ms[k] += v;
      if (opt.stage_ms) (*opt.stage_ms)[k] += v;
    }
  };

  // The untiled, dense run is Model::run itself.
  if (res.plan.untiled() && topt.sparse == SparsePolicy::off) {
    const auto t = Clock::now();
    res.outputs = model.run(in, ro);
    res.stage_ms["model"] = ms_since(t);
    res.tiles = res.tiles_run = K;
    res.target_active_fraction.assign(size_t(K), 1.0);
    finish_ms();
    return res;
  }

  // Activity per (tile, target): the largest ev1 + ev2 count of the target's frames over the input rect.
  const auto t_cut = Clock::now();
  const size_t T = res.plan.tiles.size();
  std::vector<std::vector<bool>> active(T, std::vector<bool>(size_t(K), true));
  if (topt.sparse != SparsePolicy::off) {
    for (int64_t i = 0; i < B; ++i) {
      const std::vector<double> sat = activity_table(in, i);
      for (size_t t = 0; t < T; ++t) {
        const Rect& r = res.plan.tiles[t].input;
        const double sum = rect_sum(sat, W, r);
        const bool on = topt.sparse == SparsePolicy::exact ? sum > 0 : (sum > 0 && sum / double(r.area()) >= topt.threshold);
        const size_t k = size_t(i / per);
        // A target runs when any of its frames is active.
        if (i % per == 0) active[t][k] = on;
        else active[t][k] = active[t][k] || on;
      }
    }
  }
  res.stage_ms["cut"] = ms_since(t_cut);

  for (const auto& n : names) {
    const int64_t c = n == "flow" ? 2 : (n == "m" ? 1 : 3);
    res.outputs[n] = HostTensor{{per_target(n) ? K : B, c, H, W}, std::vector<float>(size_t((per_target(n) ? K : B) * c * H * W))};
  }

  // Inactive (tile, target): nothing moved there; the RS frame stands.
  res.tiles = int64_t(T) * K;
  std::vector<int64_t> target_runs(size_t(K), 0);
  const auto t_fill = Clock::now();
  for (size_t t = 0; t < T; ++t)
    for (int64_t k = 0; k < K; ++k) {
      if (active[t][size_t(k)]) {
        res.tiles_run++;
        target_runs[size_t(k)]++;
        continue;
      }
      const Rect& r = res.plan.tiles[t].interior;
      for (auto& [n, arr] : res.outputs) {
        if (per_target(n)) {
          if (n == "m") fill(nullptr, 0, 1.f, r, arr, k);
          else fill(&in.rs, k * per, 0.f, r, arr, k);
        } else {
          for (int64_t j = 0; j < per; ++j) {
            const int64_t i = k * per + j;
            if (n == "E" || n == "flow") fill(nullptr, 0, 0.f, r, arr, i);
            else fill(&in.rs, i, 0.f, r, arr, i);
          }
        }
      }
    }
  res.active_fraction = res.tiles ? double(res.tiles_run) / double(res.tiles) : 0.0;
  for (int64_t r : target_runs) res.target_active_fraction.push_back(double(r) / double(T));
  res.stage_ms["stitch"] += ms_since(t_fill);

  // What runs: the active tiles, or (merge_active) per target the bounding box of each 4-connected
  // group of active tiles as one rect with one halo, so neighbours share their halos.
  std::vector<Tile> runs = res.plan.tiles;
  std::vector<std::pair<size_t, int64_t>> work_items;  // (index in runs, target)
  if (topt.sparse != SparsePolicy::off && topt.merge_active && !res.plan.untiled()) {
    runs.clear();
    const int64_t cols = (W + res.plan.tile_w - 1) / res.plan.tile_w;
    // Regions stay within the largest tile the device fits (any image size still runs in bounded memory).
    const int64_t max_side = topt.max_region > 0 ? std::max(tile, topt.max_region)
                             : topt.tile > 0           ? choose_tile(model, H, W, opt.mode, topt.halo, limit)
                                                       : tile;  // `tile` is already that choice
    for (int64_t k = 0; k < K; ++k) {
      std::vector<int> seen(T, 0);
      for (size_t t0 = 0; t0 < T; ++t0) {
        if (seen[t0] || !active[t0][size_t(k)]) continue;
        std::vector<size_t> comp{t0}, stack{t0};
        seen[t0] = 1;
        while (!stack.empty()) {
          const size_t t = stack.back();
          stack.pop_back();
          const int64_t r = int64_t(t) / cols, c = int64_t(t) % cols;
          const std::pair<int64_t, int64_t> nb[] = {{r - 1, c}, {r + 1, c}, {r, c - 1}, {r, c + 1}};
          for (const auto& [nr, nc] : nb) {
            if (nr < 0 || nc < 0 || nc >= cols || nr * cols + nc >= int64_t(T)) continue;
            const size_t u = size_t(nr * cols + nc);
            if (seen[u] || !active[u][size_t(k)]) continue;
            seen[u] = 1;
            comp.push_back(u);
            stack.push_back(u);
          }
        }
        Rect box = res.plan.tiles[comp[0]].interior;
        for (size_t t : comp) {
          const Rect& q = res.plan.tiles[t].interior;
          const int64_t y1 = std::max(box.y + box.h, q.y + q.h), x1 = std::max(box.x + box.w, q.x + q.w);
          box.y = std::min(box.y, q.y), box.x = std::min(box.x, q.x);
          box.h = y1 - box.y, box.w = x1 - box.x;
        }
        if (box.h <= max_side && box.w <= max_side) {
          Tile region;
          region.interior = box;
          const int64_t y0 = std::max<int64_t>(0, box.y - topt.halo), x0 = std::max<int64_t>(0, box.x - topt.halo);
          region.input = {y0, x0, std::min(H, box.y + box.h + topt.halo) - y0, std::min(W, box.x + box.w + topt.halo) - x0};
          runs.push_back(region);
          work_items.push_back({runs.size() - 1, k});
        } else {
          // A group larger than the largest tile that fits the device: its tiles run one by one.
          for (size_t t : comp) {
            runs.push_back(res.plan.tiles[t]);
            work_items.push_back({runs.size() - 1, k});
          }
        }
      }
    }
  } else {
    for (size_t t = 0; t < T; ++t)
      for (int64_t k = 0; k < K; ++k)
        if (active[t][size_t(k)]) work_items.push_back({t, k});
  }
  double run_pixels = 0;
  for (const auto& [t, k] : work_items) run_pixels += double(runs[t].input.area());
  res.work_ratio = run_pixels / (double(K) * double(H * W));

  // The rects to run, grouped by input-rect shape, run in batches.
  std::map<std::pair<int64_t, int64_t>, std::vector<std::pair<size_t, int64_t>>> groups;
  for (const auto& [t, k] : work_items) groups[{runs[t].input.h, runs[t].input.w}].push_back({t, k});
  // Largest rects first: scratch buffers the conv kernels grow (and keep) reach their size once.
  std::vector<std::pair<std::pair<int64_t, int64_t>, std::vector<std::pair<size_t, int64_t>>>> ordered(groups.begin(), groups.end());
  std::stable_sort(ordered.begin(), ordered.end(),
                   [](const auto& a, const auto& b) { return a.first.first * a.first.second > b.first.first * b.first.second; });
  const int64_t ev = model.config().ev_channels();
  for (const auto& [shape, work] : ordered) {
    const auto [rh, rw] = shape;
    // Unless max_batch says otherwise, one batch holds no more pixels than the untiled run of one
    // target (so device memory stays near the untiled run's, or one tile's when that is larger) and
    // its host copies of the inputs stay under 256 MiB.
    const int64_t item_bytes = 4 * rh * rw * (3 + 3 * ev);
    const int64_t by_pixels = std::max<int64_t>(1, (H * W) / (rh * rw)) * per;
    const int64_t cap_items = topt.max_batch > 0 ? topt.max_batch
                                                 : std::max<int64_t>(per, std::min(by_pixels, (int64_t(256) << 20) / item_bytes));
    const size_t targets_per_batch = size_t(std::max<int64_t>(1, cap_items / per));
    for (size_t w0 = 0; w0 < work.size(); w0 += targets_per_batch) {
      const size_t nw = std::min(targets_per_batch, work.size() - w0);
      const int64_t nb = int64_t(nw) * per;
      const auto t0 = Clock::now();
      ModelInputs tin;
      tin.rs.shape = {nb, 3, rh, rw};
      tin.ev1.shape = tin.ev2.shape = tin.ev3.shape = {nb, ev, rh, rw};
      for (auto* a : {&tin.rs, &tin.ev1, &tin.ev2, &tin.ev3}) a->data.reserve(size_t(a->shape.count()));
      for (size_t q = 0; q < nw; ++q) {
        const auto [t, k] = work[w0 + q];
        const Rect& r = runs[t].input;
        for (int64_t j = 0; j < per; ++j) {
          append_crop(in.rs, k * per + j, r, tin.rs.data);
          append_crop(in.ev1, k * per + j, r, tin.ev1.data);
          append_crop(in.ev2, k * per + j, r, tin.ev2.data);
          append_crop(in.ev3, k * per + j, r, tin.ev3.data);
        }
      }
      res.stage_ms["cut"] += ms_since(t0);
      const auto t1 = Clock::now();
      const auto out = model.run(tin, ro);
      res.stage_ms["model"] += ms_since(t1);
      const auto t2 = Clock::now();
      for (size_t q = 0; q < nw; ++q) {
        const auto [t, k] = work[w0 + q];
        for (const auto& n : names) {
          if (per_target(n)) stitch(out.at(n), int64_t(q), runs[t], res.outputs[n], k);
          else
            for (int64_t j = 0; j < per; ++j) stitch(out.at(n), int64_t(q) * per + j, runs[t], res.outputs[n], k * per + j);
        }
      }
      res.stage_ms["stitch"] += ms_since(t2);
    }
  }
  finish_ms();
  return res;
}

}  // namespace vkunroll
