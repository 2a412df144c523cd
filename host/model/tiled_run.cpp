// Tiled and sparse execution on the backend (host/model/tiling.hpp): activity, the tiles that run,
// cuts and stitches recorded on the device, and the host-in/host-out wrapper.
#include <algorithm>
#include <cmath>
#include <functional>
#include <set>
#include <tuple>

#include "vkunroll/base/int_math.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/kernels/copy_rect.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"

namespace vkunroll {

namespace {

BufferSlice item_of(const Buffer& buf, int64_t i) { return buf.items(i, 1); }
BufferSlice item_of(const BufferSlice& v, int64_t i) { return {v.buf, v.n0 + i, 1, v.c0, v.c}; }

std::vector<double> summed_area(const std::vector<double>& plane, int64_t H, int64_t W) {
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

// The rect whose ev1/ev2 events decide tile t: its input rect, or for the gated variant its
// interior grown by the gate radius (no event there: the gate is 0 on the whole interior, so the
// S output there is exactly the physics estimate, whatever the network would compute).
Rect activity_rect(const TilePlan& plan, size_t t, int64_t gate) {
  if (gate < 0) return plan.tiles[t].input;
  const Rect& q = plan.tiles[t].interior;
  const int64_t y0 = std::max<int64_t>(0, q.y - gate), x0 = std::max<int64_t>(0, q.x - gate);
  return {y0, x0, std::min(plan.height, q.y + q.h + gate) - y0, std::min(plan.width, q.x + q.w + gate) - x0};
}

// active[t][k]: whether tile t of target k runs (a target runs where any of its frames is active).
std::vector<std::vector<bool>> tile_activity(const TilePlan& plan, const TileOptions& topt, const ActivityTables* activity,
                                             int64_t B, int64_t per, int64_t gate) {
  const size_t T = plan.tiles.size(), K = size_t(B / per);
  std::vector<std::vector<bool>> active(T, std::vector<bool>(K, true));
  if (topt.sparse == SparsePolicy::off) return active;
  if (!activity || static_cast<int64_t>(activity->size()) != B)
    throw InternalError("run_tiled: the sparse policy needs the activity of every batch item (" + std::to_string(B) + "), got " +
                std::to_string(activity ? activity->size() : 0));
  for (int64_t i = 0; i < B; ++i)
    for (size_t t = 0; t < T; ++t) {
      const Rect r = activity_rect(plan, t, gate);
      const double sum = rect_sum((*activity)[size_t(i)], plan.width, r);
      const bool on = topt.sparse == SparsePolicy::exact ? sum > 0 : (sum > 0 && sum / double(r.area()) >= topt.threshold);
      const size_t k = size_t(i / per);
      active[t][k] = (i % per == 0) ? on : (active[t][k] || on);
    }
  return active;
}

bool any_inactive(const std::vector<std::vector<bool>>& active) {
  for (const auto& row : active)
    for (bool on : row)
      if (!on) return true;
  return false;
}

// Inactive (tile, target): the standing image (RS, or for the variant clamp(phys, 0, 1), clamped
// straight into the outputs) for sys, fused and out, rs for warped; E and flow 0, m 1. Written over
// the whole frame (a few dispatches, not a few per inactive tile): the active runs' interiors are
// stitched after.
void fill_standing(Backend& b, const BufferSlice& rs, const BufferSlice* phys, int64_t H, int64_t W,
                   const std::map<ModelOutput, Buffer>& outputs, int64_t per) {
  const Rect all{0, 0, H, W};
  for (const auto& [n, buf] : outputs) {
    const bool clamped = phys && n != ModelOutput::warped;  // the variant's outputs but warped: clamp(phys)
    const BufferSlice& src = clamped ? *phys : rs;
    auto standing = [&](const BufferSlice& from, const BufferSlice& to) {
      if (clamped) b.clamp01(from, to);
      else b.copy(from, to);
    };
    const bool zero = n == ModelOutput::E || n == ModelOutput::flow;
    if (n != ModelOutput::m && !zero && (per == 1 || !per_target(n))) {
      standing(src, buf.whole());  // item i from item i
      continue;
    }
    for (int64_t i = 0; i < buf.shape().n; ++i) {
      const BufferSlice dst = item_of(buf, i);
      if (n == ModelOutput::m) b.fill_rect(dst, all, 1.f);
      else if (zero) b.fill_rect(dst, all, 0.f);
      else standing(item_of(src, i * per), dst);  // M's out: frame 1 of the pair
    }
  }
}

// The same into host tensors.
void fill_standing_host(const HostTensor& rs, const HostTensor& standing, std::map<ModelOutput, HostTensor>& outputs, int64_t per) {
  for (auto& [n, arr] : outputs) {
    const Rect all{0, 0, arr.shape.h, arr.shape.w};
    for (int64_t i = 0; i < arr.shape.n; ++i) {
      HostSliceOut dst(arr, 0, -1, i, 1);
      if (n == ModelOutput::m) fill_rect_ref(dst, all, 1.f);
      else if (n == ModelOutput::E || n == ModelOutput::flow) fill_rect_ref(dst, all, 0.f);
      else copy_rect_ref(HostSlice(n == ModelOutput::warped ? rs : standing, 0, -1, per_target(n) ? i * per : i, 1), dst, all, 0, 0);
    }
  }
}

// A group's tiles as rectangles of whole tiles: from its first tile in row-major order, as far
// right as the row holds group tiles, then as far down as the rows below hold that whole run.
std::vector<Rect> group_rects(const TilePlan& plan, const std::vector<size_t>& comp, int64_t cols) {
  std::set<size_t> left(comp.begin(), comp.end());
  std::vector<Rect> rects;
  while (!left.empty()) {
    const int64_t t0 = int64_t(*left.begin()), r0 = t0 / cols, c0 = t0 % cols;
    int64_t w = 1, h = 1;
    while (c0 + w < cols && left.count(size_t(t0 + w))) ++w;
    auto row_held = [&](int64_t r) {
      for (int64_t c = c0; c < c0 + w; ++c)
        if (!left.count(size_t(r * cols + c))) return false;
      return true;
    };
    while (row_held(r0 + h)) ++h;
    const Rect& a = plan.tiles[size_t(t0)].interior;
    const Rect& b = plan.tiles[size_t((r0 + h - 1) * cols + c0 + w - 1)].interior;
    rects.push_back({a.y, a.x, b.y + b.h - a.y, b.x + b.w - a.x});
    for (int64_t r = r0; r < r0 + h; ++r)
      for (int64_t c = c0; c < c0 + w; ++c) left.erase(size_t(r * cols + c));
  }
  return rects;
}

struct RunItem {
  size_t run = 0;  // index in the run list
  int64_t target = 0;
};

// What runs: the active tiles, or (merge_active) per target the bounding box of each 4-connected
// group of active tiles as one rect with one halo, so neighbours share their halos. A group larger
// than `max_side` runs tile by tile (any image size still runs in bounded memory).
void active_runs(const TilePlan& plan, const std::vector<std::vector<bool>>& active, const TileOptions& topt, int64_t max_side,
                 std::vector<Tile>& runs, std::vector<RunItem>& work) {
  const size_t T = plan.tiles.size(), K = active.empty() ? 0 : active[0].size();
  if (topt.sparse == SparsePolicy::off || !topt.merge_active || plan.untiled()) {
    runs = plan.tiles;
    for (size_t t = 0; t < T; ++t)
      for (size_t k = 0; k < K; ++k)
        if (active[t][k]) work.push_back({t, int64_t(k)});
    return;
  }
  const int64_t cols = (plan.width + plan.tile_w - 1) / plan.tile_w;
  for (size_t k = 0; k < K; ++k) {
    std::vector<int> seen(T, 0);
    for (size_t t0 = 0; t0 < T; ++t0) {
      if (seen[t0] || !active[t0][k]) continue;
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
          if (seen[u] || !active[u][k]) continue;
          seen[u] = 1;
          comp.push_back(u);
          stack.push_back(u);
        }
      }
      Rect box = plan.tiles[comp[0]].interior;
      for (size_t t : comp) {
        const Rect& q = plan.tiles[t].interior;
        const int64_t y1 = std::max(box.y + box.h, q.y + q.h), x1 = std::max(box.x + box.w, q.x + q.w);
        box.y = std::min(box.y, q.y), box.x = std::min(box.x, q.x);
        box.h = y1 - box.y, box.w = x1 - box.x;
      }
      if (box.h <= max_side && box.w <= max_side) {
        // The box runs the group's holes too; split_groups: its tile rectangles run instead where
        // their input rects hold fewer pixels (each has its own halo: at large halos the box wins).
        const Rect box_input = input_rect(box, plan.halo, plan.height, plan.width);
        std::vector<Tile> parts{{box, box_input}};
        if (topt.split_groups) {
          std::vector<Tile> rects;
          int64_t pixels = 0;
          for (const Rect& q : group_rects(plan, comp, cols)) {
            rects.push_back({q, input_rect(q, plan.halo, plan.height, plan.width)});
            pixels += rects.back().input.area();
          }
          if (pixels < box_input.area()) parts = std::move(rects);
        }
        for (const Tile& q : parts) {
          runs.push_back(q);
          work.push_back({runs.size() - 1, int64_t(k)});
        }
      } else {
        for (size_t t : comp) {
          runs.push_back(plan.tiles[t]);
          work.push_back({runs.size() - 1, int64_t(k)});
        }
      }
    }
  }
}

// Where a batch's inputs come from and where its interiors go: the device (cut with crop, stitched
// with copy_rect into full-size buffers) or the host (crops uploaded, outputs downloaded and
// stitched in host memory: run_tiled, for inputs too large for one binding).
struct TileIO {
  // Writes the input rect `r` of source item `item` into batch item `q` of `batch`.
  std::function<void(const ModelBuffers& batch, int64_t q, int64_t item, const Rect& r)> cut;
  // Takes one batch's outputs (backend buffers) for the listed (batch item, target, tile) triples.
  std::function<void(const std::map<ModelOutput, Buffer>& out, const std::vector<std::pair<int64_t, const Tile*>>& placed)> stitch;
};

// A batch's RunOptions::unet_pad (unet_axis_padding per axis): aligned unless the halo is 0 (then
// a whole-image rect still gets the untiled run's padding).
UnetPadding batch_padding(const std::vector<Tile>& runs, const std::vector<RunItem>& items, int64_t H, int64_t W, int64_t halo,
                          int64_t stride) {
  bool top = false, bottom = false, left = false, right = false;
  for (const RunItem& it : items) {
    const Rect& r = runs[it.run].input;
    top |= r.y == 0, bottom |= r.y + r.h == H, left |= r.x == 0, right |= r.x + r.w == W;
  }
  const Rect& r = runs[items.at(0).run].input;
  const bool aligned = halo > 0 || (r.h == H && r.w == W);
  UnetPadding pad;
  std::tie(pad.top, pad.bottom) = unet_axis_padding(aligned, top, bottom, r.h, H, stride);
  std::tie(pad.left, pad.right) = unet_axis_padding(aligned, left, right, r.w, W, stride);
  return pad;
}

// The rects of `work`, grouped by input-rect shape, run in batches.
void run_batches(Model& model, int64_t H, int64_t W, const RunOptions& ro, const TileOptions& topt, const std::vector<Tile>& runs,
                 const std::vector<RunItem>& work, int64_t per, int64_t targets, const TileIO& io) {
  Backend& b = model.backend();
  const int64_t ev = model.config().ev_channels();
  std::map<std::pair<int64_t, int64_t>, std::vector<RunItem>> groups;
  for (const RunItem& w : work) groups[{runs[w.run].input.h, runs[w.run].input.w}].push_back(w);
  // Largest rects first: scratch buffers the conv kernels grow (and keep) reach their size once.
  std::vector<std::pair<std::pair<int64_t, int64_t>, std::vector<RunItem>>> ordered(groups.begin(), groups.end());
  std::stable_sort(ordered.begin(), ordered.end(),
                   [](const auto& x, const auto& y) { return x.first.first * x.first.second > y.first.first * y.first.second; });
  for (const auto& [shape, items] : ordered) {
    const auto [rh, rw] = shape;
    RunOptions batch_ro = ro;
    batch_ro.unet_pad = batch_padding(runs, items, H, W, topt.halo, model.unet_stride());
    // Unless max_batch says otherwise, one batch holds no more pixels than the untiled run of the
    // call's targets (so device memory stays near that run's, or one tile's when larger: Model::run
    // chunks it as it would the untiled run), and its input copies stay under 256 MiB. Fewer, larger
    // batches: each Model::run costs some 240 dispatches (~50 us each on lavapipe) whatever its size.
    const int64_t item_bytes = 4 * rh * rw * (3 + 3 * ev);
    const int64_t by_pixels = std::max<int64_t>(1, (targets * H * W) / (rh * rw)) * per;
    const int64_t cap_items =
        topt.max_batch > 0 ? topt.max_batch : std::max<int64_t>(per, std::min(by_pixels, (int64_t(256) << 20) / item_bytes));
    const size_t cap_targets = size_t(std::max<int64_t>(1, cap_items / per));
    // Equal batches (14 items under a cap of 13: 7 + 7, not 13 + 1).
    const size_t batches = (items.size() + cap_targets - 1) / cap_targets;
    const size_t targets_per_batch = (items.size() + batches - 1) / batches;
    for (size_t w0 = 0; w0 < items.size(); w0 += targets_per_batch) {
      const size_t nw = std::min(targets_per_batch, items.size() - w0);
      const int64_t nb = int64_t(nw) * per;
      ModelBuffers tin;
      BufferSlice* cut[5] = {&tin.rs, &tin.ev1, &tin.ev2, &tin.ev3, &tin.phys};
      const int64_t channels[5] = {3, ev, ev, ev, 3};
      const char* names[5] = {"tile rs", "tile ev1", "tile ev2", "tile ev3", "tile phys"};
      const int inputs = model.config().physics_input ? 5 : 4;
      std::vector<Buffer> cut_buffers;
      for (int a = 0; a < inputs; ++a) {
        cut_buffers.push_back(b.alloc({nb, channels[a], rh, rw}, names[a]));
        *cut[a] = cut_buffers.back().whole();
      }
      std::vector<std::pair<int64_t, const Tile*>> placed;
      for (size_t q = 0; q < nw; ++q) {
        const RunItem& it = items[w0 + q];
        for (int64_t j = 0; j < per; ++j) io.cut(tin, int64_t(q) * per + j, it.target * per + j, runs[it.run].input);
        placed.push_back({it.target, &runs[it.run]});
      }
      const std::map<ModelOutput, Buffer> out = model.run_on_backend(tin, batch_ro);
      cut_buffers.clear();  // before the stitch: the host path's flush then frees them
      io.stitch(out, placed);
    }
  }
}

// Plan, activity and the runs of a tiled execution: what the device and the host executors share.
struct TiledPlan {
  TileStats stats;
  RunOptions ro;
  int64_t B = 0, H = 0, W = 0, per = 1, K = 0;
  bool direct = false;  // untiled and dense: the model itself
  std::vector<std::vector<bool>> active;
  std::vector<Tile> runs;
  std::vector<RunItem> work;
};

TiledPlan plan_tiled(Model& model, int64_t B, int64_t rs_channels, int64_t H, int64_t W, const RunOptions& opt,
                     const TileOptions& topt, const ActivityTables* activity) {
  TiledPlan p;
  Backend& b = model.backend();
  const auto t_plan = Clock::now();
  const bool m_mode = opt.mode == Mode::m;
  p.B = B, p.H = H, p.W = W, p.per = m_mode ? 2 : 1;
  if (rs_channels != 3 || B < 1 || (m_mode && B % 2))
    throw DataError("run_tiled: input 'rs' is " + Shape{B, rs_channels, H, W}.str() + ", expected [B,3,H,W] (B even in mode m)");
  if (topt.sparse == SparsePolicy::fast && !(topt.threshold >= 0))
    throw UsageError("run_tiled: sparse threshold " + std::to_string(topt.threshold) + " (expected >= 0 events per pixel)");
  const uint64_t limit = topt.max_buffer_bytes ? std::min(topt.max_buffer_bytes, b.max_buffer_bytes()) : b.max_buffer_bytes();
  const int64_t tile = topt.tile > 0 ? topt.tile : choose_tile(model, H, W, opt.mode, topt.halo, limit);
  TileStats& st = p.stats;
  st.plan = make_tile_plan(H, W, tile, tile, topt.halo);
  p.K = B / p.per;
  p.ro = opt;
  p.ro.outputs = Model::resolve_outputs(opt.outputs, opt.mode);
  p.direct = st.plan.untiled() && topt.sparse == SparsePolicy::off;
  if (p.direct) {
    st.tiles = st.tiles_run = p.K;
    st.target_active_fraction.assign(size_t(p.K), 1.0);
    st.stage_ms["plan"] = ms_since(t_plan);
    return p;
  }
  const ModelConfig& cfg = model.config();
  p.active = tile_activity(st.plan, topt, activity, B, p.per, cfg.physics_input ? cfg.physics_gate : -1);
  const size_t T = st.plan.tiles.size();
  st.tiles = int64_t(T) * p.K;
  std::vector<int64_t> target_runs(size_t(p.K), 0);
  for (size_t t = 0; t < T; ++t)
    for (int64_t k = 0; k < p.K; ++k)
      if (p.active[t][size_t(k)]) st.tiles_run++, target_runs[size_t(k)]++;
  st.active_fraction = st.tiles ? double(st.tiles_run) / double(st.tiles) : 0.0;
  for (int64_t r : target_runs) st.target_active_fraction.push_back(double(r) / double(T));
  const int64_t max_side = topt.max_region > 0 ? std::max(tile, topt.max_region)
                           : topt.tile > 0     ? choose_tile(model, H, W, opt.mode, topt.halo, limit)
                                               : tile;  // `tile` is already that choice
  active_runs(st.plan, p.active, topt, max_side, p.runs, p.work);
  double run_pixels = 0;
  for (const RunItem& w : p.work) run_pixels += double(p.runs[w.run].input.area());
  st.work_ratio = run_pixels / (double(p.K) * double(H * W));
  st.stage_ms["plan"] = ms_since(t_plan);
  return p;
}


}  // namespace

ActivityTables activity_tables(const ModelInputs& in) {
  const int64_t B = in.ev1.shape.n, C = in.ev1.shape.c, H = in.ev1.shape.h, W = in.ev1.shape.w;
  ActivityTables tables;
  for (int64_t item = 0; item < B; ++item) {
    std::vector<double> plane(size_t(H * W), 0.0);
    for (const HostTensor* a : {&in.ev1, &in.ev2})
      for (int64_t c = 0; c < C; ++c) {
        const float* s = a->data.data() + (item * C + c) * H * W;
        for (int64_t i = 0; i < H * W; ++i) plane[size_t(i)] += std::fabs(s[i]);
      }
    tables.push_back(summed_area(plane, H, W));
  }
  return tables;
}

ActivityTables activity_tables(const std::vector<std::vector<uint32_t>>& counts, int64_t height, int64_t width) {
  ActivityTables tables;
  for (const auto& c : counts) {
    if (static_cast<int64_t>(c.size()) != height * width)
      throw InternalError("activity_tables: " + std::to_string(c.size()) + " counts for a " + std::to_string(width) + "x" +
                  std::to_string(height) + " image");
    tables.push_back(summed_area(std::vector<double>(c.begin(), c.end()), height, width));
  }
  return tables;
}

TiledBuffers run_tiled_on_backend(Model& model, const ModelBuffers& in, const RunOptions& opt, const TileOptions& topt,
                                  const ActivityTables* activity) {
  Backend& b = model.backend();
  TiledPlan p = plan_tiled(model, in.rs.n, in.rs.c, b.shape(in.rs.buf).h, b.shape(in.rs.buf).w, opt, topt, activity);
  TiledBuffers res;
  static_cast<TileStats&>(res) = p.stats;
  const auto t_record = Clock::now();
  if (p.direct) {
    res.outputs = model.run_on_backend(in, p.ro);
    res.stage_ms["record"] = ms_since(t_record);
    return res;
  }
  for (const auto& n : p.ro.outputs) res.outputs[n] = b.alloc({per_target(n) ? p.K : p.B, output_channels(n), p.H, p.W}, output_name(n));
  // The variant: inactive tiles take clamp(phys, 0, 1), what its gate gives away from events.
  if (any_inactive(p.active)) fill_standing(b, in.rs, model.config().physics_input ? &in.phys : nullptr, p.H, p.W, res.outputs, p.per);
  const BufferSlice* full[5] = {&in.rs, &in.ev1, &in.ev2, &in.ev3, &in.phys};
  const int inputs = model.config().physics_input ? 5 : 4;
  TileIO io;
  io.cut = [&](const ModelBuffers& batch, int64_t q, int64_t item, const Rect& r) {
    const BufferSlice* cut[5] = {&batch.rs, &batch.ev1, &batch.ev2, &batch.ev3, &batch.phys};
    for (int a = 0; a < inputs; ++a) b.crop(item_of(*full[a], item), item_of(*cut[a], q), int(r.y), int(r.x));
  };
  io.stitch = [&](const std::map<ModelOutput, Buffer>& out, const std::vector<std::pair<int64_t, const Tile*>>& placed) {
    for (size_t q = 0; q < placed.size(); ++q) {
      const auto [target, t] = placed[q];
      const Rect src{t->interior.y - t->input.y, t->interior.x - t->input.x, t->interior.h, t->interior.w};
      for (const auto& [n, buf] : out) {
        const int64_t count = per_target(n) ? 1 : p.per;
        for (int64_t j = 0; j < count; ++j)
          b.copy_rect(item_of(buf, int64_t(q) * count + j), item_of(res.outputs.at(n), target * count + j), src,
                      t->interior.y, t->interior.x);
      }
    }
  };
  run_batches(model, p.H, p.W, p.ro, topt, p.runs, p.work, p.per, p.K, io);
  res.stage_ms["record"] = ms_since(t_record);
  return res;
}

TiledResult run_tiled(Model& model, const ModelInputs& in, const RunOptions& opt, const TileOptions& topt) {
  Backend& b = model.backend();
  const Shape ev_shape{in.rs.shape.n, model.config().ev_channels(), in.rs.shape.h, in.rs.shape.w};
  for (const auto& [a, name] : {std::pair{&in.ev1, "ev1"}, std::pair{&in.ev2, "ev2"}, std::pair{&in.ev3, "ev3"}})
    if (!(a->shape == ev_shape) || static_cast<int64_t>(a->data.size()) != ev_shape.count())
      throw DataError(std::string("run_tiled: input '") + name + "' has shape " + a->shape.str() + ", expected " + ev_shape.str());
  if (static_cast<int64_t>(in.rs.data.size()) != in.rs.shape.count())
    throw DataError("run_tiled: input 'rs' holds " + std::to_string(in.rs.data.size()) + " values for shape " + in.rs.shape.str());
  const ActivityTables activity = topt.sparse == SparsePolicy::off ? ActivityTables{} : activity_tables(in);
  TiledPlan p = plan_tiled(model, in.rs.shape.n, in.rs.shape.c, in.rs.shape.h, in.rs.shape.w, opt, topt, &activity);
  TiledResult res;
  static_cast<TileStats&>(res) = p.stats;
  const auto t_run = Clock::now();
  if (p.direct) {
    res.outputs = model.run(in, p.ro);
    res.stage_ms["record"] = ms_since(t_run);
    return res;
  }
  for (const auto& n : p.ro.outputs)
    res.outputs[n] = HostTensor(Shape{per_target(n) ? p.K : p.B, output_channels(n), p.H, p.W});
  const HostTensor* full[5] = {&in.rs, &in.ev1, &in.ev2, &in.ev3, &in.phys};
  const int inputs = model.config().physics_input ? 5 : 4;
  if (inputs == 5 && !(in.phys.shape == Shape{in.rs.shape.n, 3, in.rs.shape.h, in.rs.shape.w}))
    throw DataError("run_tiled: input 'phys' has shape " + in.phys.shape.str() + ", expected that of 'rs' (the physics-informed variant)");
  HostTensor standing;  // the variant: inactive tiles take clamp(phys, 0, 1), what its gate gives away from events
  if (inputs == 5) {
    standing = HostTensor(in.phys.shape);
    clamp01_ref(HostSlice(in.phys), HostSliceOut(standing));
  }
  if (any_inactive(p.active)) fill_standing_host(in.rs, inputs == 5 ? standing : in.rs, res.outputs, p.per);
  TileIO io;
  io.cut = [&](const ModelBuffers& batch, int64_t q, int64_t item, const Rect& r) {
    const BufferSlice* cut[5] = {&batch.rs, &batch.ev1, &batch.ev2, &batch.ev3, &batch.phys};
    for (int a = 0; a < inputs; ++a) {
      HostTensor crop(Shape{1, full[a]->shape.c, r.h, r.w});
      crop_ref(HostSlice(*full[a], 0, -1, item, 1), HostSliceOut(crop), r.y, r.x);
      b.upload(item_of(*cut[a], q), crop.data);
    }
  };
  io.stitch = [&](const std::map<ModelOutput, Buffer>& out, const std::vector<std::pair<int64_t, const Tile*>>& placed) {
    std::map<ModelOutput, HostTensor> host;
    for (const auto& [n, buf] : out) {
      host[n] = HostTensor(buf.shape());
      b.download(buf.whole(), host[n].data);
    }
    b.flush();
    for (size_t q = 0; q < placed.size(); ++q) {
      const auto [target, t] = placed[q];
      const Rect src{t->interior.y - t->input.y, t->interior.x - t->input.x, t->interior.h, t->interior.w};
      for (const auto& [n, tile_out] : host) {
        const int64_t count = per_target(n) ? 1 : p.per;
        for (int64_t j = 0; j < count; ++j)
          copy_rect_ref(HostSlice(tile_out, 0, -1, int64_t(q) * count + j, 1),
                        HostSliceOut(res.outputs.at(n), 0, -1, target * count + j, 1), src, t->interior.y, t->interior.x);
      }
    }
  };
  run_batches(model, p.H, p.W, p.ro, topt, p.runs, p.work, p.per, p.K, io);
  res.stage_ms["record"] = ms_since(t_run);
  return res;
}

}  // namespace vkunroll
