// Tiled and sparse execution (host/model/tiling.hpp): plan geometry, receptive radii, a tiled CPU run
// with halo >= the exact halo equal to the untiled run bit for bit, a smaller halo's measured
// error, sparse policies (no events: RS and zero tiles; events in a corner: only nearby tiles),
// lavapipe tiled vs CPU tiled, and tile choice under buffer limits (small and published model at
// 1280x720 planned; a capped lavapipe backend forced to tile).
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "model_test_util.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::modeltest;

namespace {

// A tiny model with shallow UNets (receptive radius 84, so tiles with halo 96 see less than a
// 320-wide image) whose flownet output is scaled down: flow of a few pixels, not up to 100.
// gated: the physics-informed variant with an event gate of radius 1 (as the default model).
Weights shallow_weights(bool gated = false) {
  ModelConfig cfg;
  cfg.physics_input = gated;
  cfg.physics_gate = gated ? 1 : -1;
  cfg.D = 1;
  cfg.C = 1;
  cfg.G = 4;
  cfg.G0 = 8;
  cfg.N = 2;
  cfg.upnet_width = 16;
  cfg.flownet = {4, 2};
  cfg.fusion_net = {4, 2};
  cfg.attfusion_net = {4, 2};
  Weights w = random_weights(cfg, 7);
  for (const char* k : {"flownet.pred.weight", "flownet.pred.bias"})
    for (auto& v : w.tensors.at(k).data) v *= 0.02f;
  return w;
}

double max_abs(const HostTensor& a) {
  double m = 0;
  for (float v : a.data) m = std::max(m, double(std::fabs(v)));
  return m;
}

// Zeroes the events of ev1/ev2 outside rows [y0, y0+h) x cols [x0, x0+w) (all of them when h = 0).
void keep_events_in(ModelInputs& in, int64_t y0, int64_t x0, int64_t h, int64_t w) {
  for (HostTensor* a : {&in.ev1, &in.ev2}) {
    const Shape s = a->shape;
    for (int64_t i = 0; i < s.n * s.c; ++i)
      for (int64_t y = 0; y < s.h; ++y)
        for (int64_t x = 0; x < s.w; ++x)
          if (!(y >= y0 && y < y0 + h && x >= x0 && x < x0 + w)) a->data[size_t((i * s.h + y) * s.w + x)] = 0.f;
  }
}

}  // namespace

TEST(TilingPlan, TilesPartitionTheImageAndHalosAreClipped) {
  const TilePlan p = make_tile_plan(100, 70, 32, 32, 32);
  ASSERT_EQ(p.tiles.size(), 4u * 3u);
  std::vector<int> covered(100 * 70, 0);
  for (const Tile& t : p.tiles) {
    for (int64_t y = t.interior.y; y < t.interior.y + t.interior.h; ++y)
      for (int64_t x = t.interior.x; x < t.interior.x + t.interior.w; ++x) covered[size_t(y * 70 + x)]++;
    EXPECT_EQ(t.input.y, std::max<int64_t>(0, t.interior.y - 32));
    EXPECT_EQ(t.input.y + t.input.h, std::min<int64_t>(100, t.interior.y + t.interior.h + 32));
    EXPECT_EQ(t.input.x % 32, 0);
  }
  for (int c : covered) ASSERT_EQ(c, 1);
  EXPECT_EQ(p.tiles.back().interior, (Rect{96, 64, 4, 6}));
  EXPECT_TRUE(make_tile_plan(100, 70, 128, 128, 32).untiled());
  EXPECT_THROW(make_tile_plan(100, 70, 40, 40, 32), Error);  // not a multiple of 32
  EXPECT_THROW(make_tile_plan(100, 70, 32, 32, 20), Error);
  EXPECT_THROW(make_tile_plan(1, 70, 32, 32, 32), Error);
}

// The tiles' UNet padding at 346x260 (the untiled run pads to 288 x 352: 14 rows on top, 14 below,
// 3 columns left, 3 right), UNet stride 8: an inner rect pads only to the stride on the untiled
// grid; a rect at the border pads that side as the untiled run; halo 0 centers up to the stride.
TEST(TilingPlan, UnetPaddingReachesOnlyTheStrideAwayFromTheBorder) {
  using P = std::pair<int, int>;
  EXPECT_EQ(unet_axis_padding(true, false, false, 96, 260, 8), (P{6, 2}));    // 96 rows -> 104, not 128
  EXPECT_EQ(unet_axis_padding(true, true, false, 96, 260, 8), (P{14, 2}));    // top rect: the untiled 14 rows
  EXPECT_EQ(unet_axis_padding(true, false, true, 100, 260, 8), (P{6, 14}));   // bottom rect: the untiled 14 rows
  EXPECT_EQ(unet_axis_padding(true, true, true, 260, 260, 8), (P{14, 14}));   // the whole image: the untiled run
  EXPECT_EQ(unet_axis_padding(true, false, true, 121, 345, 8), (P{3, 3}));    // odd width 345 (even 346 -> 352), from 224
  EXPECT_EQ(unet_axis_padding(false, false, true, 100, 260, 8), (P{2, 2}));   // halo 0: centered, 100 -> 104
  EXPECT_EQ(unet_axis_padding(false, false, false, 96, 260, 8), (P{0, 0}));
  // Any rect length away from the end, and the lengths that end at row 260 from a 32-grid origin.
  for (bool at_end : {false, true})
    for (int64_t n : at_end ? std::vector<int64_t>{36, 68, 100, 132} : std::vector<int64_t>{32, 64, 96, 100, 131})
      for (bool at_start : {false, true}) {
        const auto [before, after] = unet_axis_padding(true, at_start, at_end, n, 260, 8);
        EXPECT_EQ((n + n % 2 + before + after) % 8, 0) << n << at_start << at_end;
        EXPECT_EQ(before % 8, 14 % 8) << "the untiled stride grid";
      }
}

TEST(TilingPlan, ReceptiveRadii) {
  const ReceptiveRadius pub = receptive_radius(ModelConfig::published());
  EXPECT_EQ(pub.synthesis, 112);   // 2 (2 + 1 + 50 + 1 + 1) + 2
  EXPECT_EQ(pub.flownet, 186);     // depth 4: 12 * 16 - 6
  EXPECT_EQ(pub.fusion_net, 90);   // depth 3
  EXPECT_EQ(pub.fused, 276);
  EXPECT_EQ(pub.out, 276);
  EXPECT_EQ(exact_halo(ModelConfig::published(), Mode::s, 0.0), 288);
  EXPECT_EQ(exact_halo(ModelConfig::published(), Mode::s, 250.0), 352);  // 90 + 251 -> 341
  const Weights w = shallow_weights();
  const ReceptiveRadius r = receptive_radius(w.config);
  EXPECT_EQ(r.synthesis, 14);
  EXPECT_EQ(r.flownet, 42);
  EXPECT_EQ(r.fused, 84);
}

// halo >= exact_halo: every stitched output equals the untiled run exactly (CPU backend: the
// same arithmetic per output pixel; H and W multiples of 32, so no UNet padding anywhere).
TEST(TilingCpu, HaloAtExactHaloEqualsUntiledBitForBit) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  const ModelInputs in = random_inputs(2, 64, 256, w.config.N, 5);
  RunOptions opt;
  opt.mode = Mode::m;
  const auto full = model.run(in, opt);
  const double max_flow = max_abs(full.at(ModelOutput::flow));
  TileOptions t;
  t.tile = 64;
  t.halo = exact_halo(w.config, Mode::m, max_flow);
  ASSERT_EQ(t.halo, 96) << "max |flow| " << max_flow;
  const TiledResult tiled = run_tiled(model, in, opt, t);
  ASSERT_EQ(tiled.plan.tiles.size(), 4u);
  // The halo really cuts: every tile sees less than the image.
  EXPECT_EQ(tiled.plan.tiles[0].input, (Rect{0, 0, 64, 160}));
  EXPECT_EQ(tiled.plan.tiles[2].input, (Rect{0, 32, 64, 224}));
  EXPECT_EQ(tiled.tiles_run, 4);
  ASSERT_EQ(tiled.outputs.size(), full.size());
  for (const auto& [name, arr] : full) EXPECT_EQ(max_abs_diff(tiled.outputs.at(name), arr), 0.0) << name;
}

// Sizes that are not multiples of 32 (odd height too): the tiles' UNets place their input at the
// untiled run's offset, so the result is still bit for bit the untiled one.
TEST(TilingCpu, UnalignedOddSizeAtExactHaloEqualsUntiledBitForBit) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  const ModelInputs in = random_inputs(2, 61, 226, w.config.N, 6);  // UNet offsets 1 (rows), 15 (columns)
  RunOptions opt;
  opt.mode = Mode::m;
  opt.outputs = {ModelOutput::flow, ModelOutput::warped, ModelOutput::fused, ModelOutput::out};
  const auto full = model.run(in, opt);
  TileOptions t;
  t.tile = 64;
  t.halo = exact_halo(w.config, Mode::m, max_abs(full.at(ModelOutput::flow)));
  ASSERT_EQ(t.halo, 96);
  const TiledResult tiled = run_tiled(model, in, opt, t);
  ASSERT_EQ(tiled.plan.tiles.size(), 4u);
  EXPECT_EQ(tiled.plan.tiles[3].input, (Rect{0, 96, 61, 130}));
  for (const auto& [name, arr] : full) EXPECT_EQ(max_abs_diff(tiled.outputs.at(name), arr), 0.0) << name;
}

// A halo below the receptive radius: measured error, bounded, and not zero.
TEST(TilingCpu, SmallHaloHasABoundedMeasuredError) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  const ModelInputs in = random_inputs(1, 64, 192, w.config.N, 9);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused, ModelOutput::flow};
  const auto full = model.run(in, opt);
  TileOptions t;
  t.tile = 64;
  t.halo = 32;
  const TiledResult tiled = run_tiled(model, in, opt, t);
  const double err = max_abs_diff(tiled.outputs.at(ModelOutput::fused), full.at(ModelOutput::fused));
  const double flow_err = max_abs_diff(tiled.outputs.at(ModelOutput::flow), full.at(ModelOutput::flow));
  std::printf("[ tiling   ] halo 32 (exact 96): fused max abs err %.3g (max |fused| %.3g), flow %.3g px\n", err,
              max_abs(full.at(ModelOutput::fused)), flow_err);
  EXPECT_GT(err, 0.0);
  EXPECT_LT(err, 0.005);  // measured 1.66e-3
}

TEST(TilingCpu, SparseExactWithoutEventsReturnsRsAndRunsNoTile) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(2, 64, 96, w.config.N, 3);
  keep_events_in(in, 0, 0, 0, 0);
  for (Mode mode : {Mode::s, Mode::m}) {
    RunOptions opt;
    opt.mode = mode;
    opt.outputs = {mode == Mode::m ? ModelOutput::out : ModelOutput::fused};
    TileOptions t;
    t.tile = 32;
    t.halo = 32;
    t.sparse = SparsePolicy::exact;
    const TiledResult r = run_tiled(model, in, opt, t);
    EXPECT_EQ(r.tiles_run, 0);
    EXPECT_EQ(r.active_fraction, 0.0);
    const HostTensor& o = r.outputs.at(opt.outputs[0]);
    const HostTensor rs = mode == Mode::m ? take(in.rs, 0, 1) : in.rs;
    EXPECT_EQ(max_abs_diff(o, rs), 0.0);
  }
}

TEST(TilingCpu, SparseRunsOnlyTilesNearTheEvents) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(1, 96, 96, w.config.N, 4);
  keep_events_in(in, 0, 0, 8, 8);  // events only in the top-left corner
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  TileOptions t;
  t.tile = 32;
  t.halo = 32;
  t.merge_active = false;  // each active tile with its own halo (merging: the next test)
  const TiledResult dense = run_tiled(model, in, opt, t);
  t.sparse = SparsePolicy::exact;
  const TiledResult sparse = run_tiled(model, in, opt, t);
  // Tiles whose input rect (interior + 32) reaches the corner: interiors (0,0), (0,32), (32,0), (32,32).
  EXPECT_EQ(sparse.tiles, 9);
  EXPECT_EQ(sparse.tiles_run, 4);
  EXPECT_DOUBLE_EQ(sparse.active_fraction, 4.0 / 9);
  // Input rects 64x64, 64x96, 96x64, 96x96 (clipped at the image border) of a 96x96 image.
  EXPECT_DOUBLE_EQ(sparse.work_ratio, (64.0 * 64 + 2 * 64 * 96 + 96 * 96) / (96 * 96));
  const HostTensor& a = sparse.outputs.at(ModelOutput::fused);
  const HostTensor& d = dense.outputs.at(ModelOutput::fused);
  for (const Tile& tl : sparse.plan.tiles) {
    const bool near = tl.interior.y < 64 && tl.interior.x < 64;
    double diff_dense = 0, diff_rs = 0;
    for (int64_t c = 0; c < 3; ++c)
      for (int64_t y = tl.interior.y; y < tl.interior.y + tl.interior.h; ++y)
        for (int64_t x = tl.interior.x; x < tl.interior.x + tl.interior.w; ++x) {
          const size_t i = size_t((c * 96 + y) * 96 + x);
          diff_dense = std::max(diff_dense, double(std::fabs(a.data[i] - d.data[i])));
          diff_rs = std::max(diff_rs, double(std::fabs(a.data[i] - in.rs.data[i])));
        }
    if (near) EXPECT_EQ(diff_dense, 0.0) << tl.interior.y << "," << tl.interior.x;
    else EXPECT_EQ(diff_rs, 0.0) << tl.interior.y << "," << tl.interior.x;
  }
  // fast: a threshold above the corner's density runs nothing.
  t.sparse = SparsePolicy::fast;
  t.threshold = 1e6;
  EXPECT_EQ(run_tiled(model, in, opt, t).tiles_run, 0);
  t.threshold = 0.0;
  EXPECT_EQ(run_tiled(model, in, opt, t).tiles_run, 4);
}

TEST(TilingCpu, SparseMergesNeighbouringActiveTilesIntoOneRect) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(1, 160, 160, w.config.N, 4);
  keep_events_in(in, 0, 0, 8, 8);  // events only in the top-left corner
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  TileOptions t;
  t.tile = 32;
  t.halo = 32;
  t.sparse = SparsePolicy::exact;
  t.merge_active = false;
  const TiledResult apart = run_tiled(model, in, opt, t);
  t.merge_active = true;
  const TiledResult merged = run_tiled(model, in, opt, t);
  // The same four active tiles; merged they run as one 64x64 interior with one halo (input 96x96)
  // instead of four inputs of 64x64, 64x96, 96x64 and 96x96 pixels.
  EXPECT_EQ(merged.tiles_run, 4);
  EXPECT_EQ(apart.tiles_run, 4);
  EXPECT_DOUBLE_EQ(apart.work_ratio, (64.0 * 64 + 2 * 64 * 96 + 96 * 96) / (160 * 160));
  EXPECT_DOUBLE_EQ(merged.work_ratio, 96.0 * 96 / (160 * 160));
  // The merged rect is exactly one 64-pixel tile with halo 32: the same input, the same output.
  TileOptions big;
  big.tile = 64;
  big.halo = 32;
  const TiledResult one = run_tiled(model, in, opt, big);
  const HostTensor& a = merged.outputs.at(ModelOutput::fused);
  const HostTensor& b = one.outputs.at(ModelOutput::fused);
  double inside = 0, outside_rs = 0;
  for (int64_t c = 0; c < 3; ++c)
    for (int64_t y = 0; y < 160; ++y)
      for (int64_t x = 0; x < 160; ++x) {
        const size_t i = size_t((c * 160 + y) * 160 + x);
        if (y < 64 && x < 64) inside = std::max(inside, double(std::fabs(a.data[i] - b.data[i])));
        else outside_rs = std::max(outside_rs, double(std::fabs(a.data[i] - in.rs.data[i])));
      }
  EXPECT_EQ(inside, 0.0);
  EXPECT_EQ(outside_rs, 0.0);
  // A cap on the region side below the group's size runs the group tile by tile again.
  t.max_region = 32;
  EXPECT_DOUBLE_EQ(run_tiled(model, in, opt, t).work_ratio, apart.work_ratio);
}

// The gated variant on a static background with one small moving object (events in rows 40..45,
// columns 64..69): sparse exact runs only the tiles with an event within the gate radius (1) of
// their interior, (1,1) and (1,2), though every input rect (halo 96) reaches the object; the
// others take clamp(phys, 0, 1), what the gate gives where no event is near.
namespace {
struct GatedScene {
  Weights w = shallow_weights(true);
  ModelInputs in = random_inputs(1, 96, 128, w.config.N, 8);
  GatedScene() {
    in.phys = in.rs;
    for (float& v : in.phys.data) v = 1.5f * v - 0.25f;  // outside [0, 1] too: the clamp matters
    keep_events_in(in, 40, 64, 6, 6);
  }
  static bool active_tile(const Tile& tl) { return tl.interior.y == 32 && (tl.interior.x == 32 || tl.interior.x == 64); }
};

// Max |a - b| over the interiors of the tiles that are (active) or are not (!active) active.
double tiles_diff(const TilePlan& plan, const HostTensor& a, const HostTensor& b, bool active) {
  double m = 0;
  for (const Tile& tl : plan.tiles) {
    if (GatedScene::active_tile(tl) != active) continue;
    for (int64_t c = 0; c < 3; ++c)
      for (int64_t y = tl.interior.y; y < tl.interior.y + tl.interior.h; ++y)
        for (int64_t x = tl.interior.x; x < tl.interior.x + tl.interior.w; ++x) {
          const size_t i = size_t((c * 96 + y) * 128 + x);
          m = std::max(m, std::isnan(a.data[i] - b.data[i]) ? INFINITY : double(std::fabs(a.data[i] - b.data[i])));
        }
  }
  return m;
}

HostTensor clamped(const HostTensor& a) {
  HostTensor r = a;
  for (float& v : r.data) v = std::clamp(v, 0.f, 1.f);
  return r;
}
}  // namespace

TEST(TilingCpu, SparseExactOfTheGatedVariantEqualsDenseBitForBit) {
  const GatedScene g;
  CpuBackend cpu;
  Model model(cpu, g.w);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused, ModelOutput::flow};
  const auto full = model.run(g.in, opt);
  TileOptions t;
  t.tile = 32;
  t.halo = exact_halo(g.w.config, Mode::s, max_abs(full.at(ModelOutput::flow)));
  ASSERT_EQ(t.halo, 96);
  t.sparse = SparsePolicy::exact;
  opt.outputs = {ModelOutput::fused};
  const TiledResult sparse = run_tiled(model, g.in, opt, t);
  EXPECT_EQ(sparse.tiles, 12);
  EXPECT_EQ(sparse.tiles_run, 2);
  for (const Tile& tl : sparse.plan.tiles)  // every input rect reaches the object
    ASSERT_TRUE(tl.input.y < 46 && tl.input.y + tl.input.h > 40 && tl.input.x < 70 && tl.input.x + tl.input.w > 64);
  const HostTensor& f = sparse.outputs.at(ModelOutput::fused);
  EXPECT_EQ(max_abs_diff(f, full.at(ModelOutput::fused)), 0.0);
  EXPECT_EQ(tiles_diff(sparse.plan, f, clamped(g.in.phys), false), 0.0);
  EXPECT_GT(tiles_diff(sparse.plan, f, clamped(g.in.phys), true), 0.01);  // the network ran there
  // The ungated model keeps the input-rect rule: every tile sees the object within its halo.
  CpuBackend cpu2;
  Model plain(cpu2, shallow_weights());
  ModelInputs no_phys = g.in;
  no_phys.phys = HostTensor();
  EXPECT_EQ(run_tiled(plain, no_phys, opt, t).tiles_run, 12);
}

// The same on lavapipe in fp32 and fp16: sparse exact against the dense tiled run, the inactive
// tiles equal to it (fp16: to its rounding), the active ones within the precision's tolerance.
TEST(TilingVulkan, SparseExactOfTheGatedVariantMatchesDenseInFp32AndFp16) {
  const GatedScene g;
  for (Precision p : {Precision::fp32, Precision::fp16}) {
    VulkanBackend vk(vktest::context(), nullptr, kPoolFlushBytes, p);
    Model model(vk, g.w);
    RunOptions opt;
    opt.precision = p;
    opt.outputs = {ModelOutput::fused};
    TileOptions t;
    t.tile = 32;
    t.halo = 96;
    const TiledResult dense = run_tiled(model, g.in, opt, t);
    t.sparse = SparsePolicy::exact;
    const TiledResult sparse = run_tiled(model, g.in, opt, t);
    EXPECT_EQ(sparse.tiles_run, 2) << precision_name(p);
    const HostTensor& d = dense.outputs.at(ModelOutput::fused);
    const HostTensor& s = sparse.outputs.at(ModelOutput::fused);
    // Inactive tiles: the host's clamp(phys) itself; the dense fp16 run rounds it to fp16 (half an
    // ulp below 1: 2^-11).
    EXPECT_EQ(tiles_diff(sparse.plan, s, clamped(g.in.phys), false), 0.0) << precision_name(p);
    EXPECT_LE(tiles_diff(sparse.plan, s, d, false), p == Precision::fp32 ? 0.0 : 1.0 / 2048) << precision_name(p);
    EXPECT_LE(tiles_diff(sparse.plan, s, d, true), p == Precision::fp32 ? 1e-4 : 1e-2) << precision_name(p);
  }
}

// split_groups: an L of three active tiles (halo 0) runs as its two tile rectangles, 32x64 and
// 32x32, instead of its 64x64 box; the lone rectangle is tile (1, 0) as run apart, and the box's
// inactive tile keeps the RS pixels.
TEST(TilingCpu, SparseSplitRunsAnLShapedGroupAsItsTileRectangles) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(1, 128, 128, w.config.N, 11);
  keep_events_in(in, 0, 0, 64, 64);
  for (HostTensor* a : {&in.ev1, &in.ev2})
    for (int64_t c = 0; c < a->shape.c; ++c)
      for (int64_t y = 32; y < 64; ++y)
        for (int64_t x = 32; x < 64; ++x) a->data[size_t((c * 128 + y) * 128 + x)] = 0.f;
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  TileOptions t;
  t.tile = 32;
  t.halo = 0;
  t.sparse = SparsePolicy::exact;
  const TiledResult box = run_tiled(model, in, opt, t);
  t.split_groups = true;
  const TiledResult split = run_tiled(model, in, opt, t);
  t.merge_active = false;
  const TiledResult apart = run_tiled(model, in, opt, t);
  EXPECT_EQ(box.tiles_run, 3);
  EXPECT_EQ(split.tiles_run, 3);
  EXPECT_DOUBLE_EQ(box.work_ratio, 64.0 * 64 / (128 * 128));
  EXPECT_DOUBLE_EQ(split.work_ratio, (32.0 * 64 + 32 * 32) / (128 * 128));
  const HostTensor& b = box.outputs.at(ModelOutput::fused);
  const HostTensor& sp = split.outputs.at(ModelOutput::fused);
  const HostTensor& ap = apart.outputs.at(ModelOutput::fused);
  double lone = 0, hole_rs = 0, hole_box = 0;
  for (int64_t c = 0; c < 3; ++c)
    for (int64_t y = 32; y < 64; ++y)
      for (int64_t x = 0; x < 64; ++x) {
        const size_t i = size_t((c * 128 + y) * 128 + x);
        if (x < 32) lone = std::max(lone, double(std::fabs(sp.data[i] - ap.data[i])));
        else hole_rs = std::max(hole_rs, double(std::fabs(sp.data[i] - in.rs.data[i]))),
             hole_box = std::max(hole_box, double(std::fabs(b.data[i] - in.rs.data[i])));
      }
  EXPECT_EQ(lone, 0.0);
  EXPECT_EQ(hole_rs, 0.0);
  EXPECT_GT(hole_box, 0.0);  // the box ran its hole through the network
}

// At the exact halo a split group is still exact: the gated variant, an L of active tiles along
// the top and left edges of a 384x384 image, split into two rectangles whose input rects hold
// fewer pixels than the box's (the whole image), equals the dense run bit for bit.
TEST(TilingCpu, SparseSplitAtTheExactHaloEqualsDenseBitForBit) {
  const Weights w = shallow_weights(true);
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(1, 384, 384, w.config.N, 12);
  in.phys = in.rs;
  for (float& v : in.phys.data) v = 1.5f * v - 0.25f;
  for (HostTensor* a : {&in.ev1, &in.ev2})  // events 2 px inside the L of tiles row 0 and column 0, x, y < 320
    for (int64_t c = 0; c < a->shape.c; ++c)
      for (int64_t y = 0; y < 384; ++y)
        for (int64_t x = 0; x < 384; ++x) {
          const bool arm = (y >= 2 && y < 30 && x >= 2 && x < 318) || (x >= 2 && x < 30 && y >= 2 && y < 318);
          if (!arm) a->data[size_t((c * 384 + y) * 384 + x)] = 0.f;
        }
  RunOptions opt;
  opt.outputs = {ModelOutput::fused, ModelOutput::flow};
  const auto full = model.run(in, opt);
  TileOptions t;
  t.tile = 32;
  t.halo = exact_halo(w.config, Mode::s, max_abs(full.at(ModelOutput::flow)));
  ASSERT_LE(t.halo, 128);
  t.sparse = SparsePolicy::exact;
  t.split_groups = true;
  opt.outputs = {ModelOutput::fused};
  const TiledResult split = run_tiled(model, in, opt, t);
  EXPECT_EQ(split.tiles_run, 19);
  const double arm = double(32 + t.halo) * 384;  // each rectangle's input rect: one arm and its halo
  EXPECT_DOUBLE_EQ(split.work_ratio, 2 * arm / (384.0 * 384));
  EXPECT_EQ(max_abs_diff(split.outputs.at(ModelOutput::fused), full.at(ModelOutput::fused)), 0.0);
}

// Halo 0 with events only in the 4x6 corner tile of a 100x70 image: the merged region reads at
// least 32 pixels a side, as the plan's own tile does (it once read 4x6 and the UNets refused it).
TEST(TilingCpu, SparseHaloZeroCornerRegionReadsAtLeast32Pixels) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ModelInputs in = random_inputs(1, 70, 100, w.config.N, 9);
  keep_events_in(in, 66, 97, 4, 3);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  TileOptions t;
  t.tile = 32;
  t.halo = 0;
  t.sparse = SparsePolicy::exact;
  const TiledResult merged = run_tiled(model, in, opt, t);
  EXPECT_EQ(merged.tiles_run, 1);
  EXPECT_EQ(merged.plan.tiles.back().input, (Rect{32, 64, 38, 36}));  // on the 32-grid
  t.merge_active = false;
  const TiledResult apart = run_tiled(model, in, opt, t);
  EXPECT_EQ(max_abs_diff(merged.outputs.at(ModelOutput::fused), apart.outputs.at(ModelOutput::fused)), 0.0);
  EXPECT_GT(max_abs_diff(merged.outputs.at(ModelOutput::fused), in.rs), 0.0);  // the corner ran
}

TEST(TilingCpu, BadOptionsAreClearErrors) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  const ModelInputs in = random_inputs(1, 64, 64, w.config.N, 1);
  RunOptions opt;
  TileOptions t;
  t.tile = 48;
  EXPECT_THROW(run_tiled(model, in, opt, t), Error);
  t.tile = 32;
  t.halo = 10;
  EXPECT_THROW(run_tiled(model, in, opt, t), Error);
  EXPECT_THROW(parse_sparse_policy("maybe", "--sparse"), Error);
}

// RunOptions::unet_pad: spelling out the authors' centered padding reproduces the default bit for
// bit; a smaller one on the stride runs; a padded size off the UNets' stride, a pad as large as the
// input, or a bottom pad without a top one is an error naming the rule.
TEST(TilingCpu, ExplicitUnetPaddingIsCheckedAndTheCenteredOneReproducesTheDefault) {
  const Weights w = shallow_weights();
  CpuBackend cpu;
  Model model(cpu, w);
  ASSERT_EQ(model.unet_stride(), 4);  // depth-2 UNets
  const ModelInputs in = random_inputs(1, 40, 52, w.config.N, 3);  // padded to 64 x 64: rows 12 + 12, columns 6 + 6
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  const HostTensor ref = model.run(in, opt).at(ModelOutput::fused);
  opt.unet_pad = {12, 6, 12, 6};  // top, left, bottom, right
  EXPECT_EQ(model.run(in, opt).at(ModelOutput::fused).data, ref.data);
  opt.unet_pad = {2, 2, 2, 2};  // 44 x 56
  EXPECT_NE(model.run(in, opt).at(ModelOutput::fused).data, ref.data);
  auto error_of = [&](const UnetPadding& pad) {
    opt.unet_pad = pad;
    try {
      model.run(in, opt);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error_of({1, 2, 2, 2}).find("multiple of the UNets' stride 4"), std::string::npos);
  EXPECT_NE(error_of({40, 2, 0, 2}).find("smaller than the input"), std::string::npos);
  EXPECT_NE(error_of({2, -1, 2, 2}).find("needs an explicit top / left"), std::string::npos);
}

// lavapipe, tiled, against the CPU tiled run (golden tiny model; tolerance of the model tests).
TEST(TilingVulkan, TiledMatchesCpuTiled) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  const ModelInputs in = random_inputs(2, 64, 96, w.config.N, 12);
  RunOptions opt;
  opt.mode = Mode::m;
  TileOptions t;
  t.tile = 32;
  t.halo = 32;
  VulkanBackend vk(vktest::context());
  Model gm(vk, w);
  const TiledResult g = run_tiled(gm, in, opt, t);
  CpuBackend cpu;
  Model cm(cpu, w);
  const TiledResult c = run_tiled(cm, in, opt, t);
  ASSERT_EQ(g.plan.tiles.size(), 6u);
  for (const auto& [name, arr] : c.outputs) {
    const double tol = name == ModelOutput::flow ? 1e-4 * std::max(1.0, max_abs(arr))
                       : name == ModelOutput::warped ? 1e-4 + 2 * max_abs_diff(g.outputs.at(ModelOutput::flow), c.outputs.at(ModelOutput::flow))
                                          : 1e-4;
    EXPECT_LE(max_abs_diff(g.outputs.at(name), arr), tol) << name;
  }
}

// The tile choice keeps every buffer under the limit: planned runs at 1280x720 (shipped small
// model's configuration and the published one) on a 128 MiB PlanningBackend.
TEST(TilingPlan, AutomaticTileFitsTheBufferLimitAt1280x720) {
  ModelConfig small;
  small.D = 2, small.C = 3, small.G = 12, small.G0 = 24, small.N = 4, small.upnet_width = 48;
  small.flownet = small.fusion_net = small.attfusion_net = {8, 3};
  for (const ModelConfig& cfg : {small, ModelConfig::published()}) {
    const Weights w = random_weights(cfg, 1);
    const ModelInputs in = random_inputs(2, 720, 1280, cfg.N, 1, /*values=*/false);
    PlanningBackend plan;
    Model model(plan, w);
    RunOptions opt;
    opt.mode = Mode::m;
    TileOptions t;
    t.halo = 64;
    const TiledResult r = run_tiled(model, in, opt, t);
    EXPECT_LE(plan.largest_buffer(), plan.max_buffer_bytes());
    std::printf("[ tiling   ] %s at 1280x720 M, halo 64: tile %lld (%zu tiles), largest buffer %.1f MiB (%s), peak %.1f MiB\n",
                cfg.D == 10 ? "published" : "small", (long long)r.plan.tile_h, r.plan.tiles.size(),
                plan.largest_buffer() / 1048576.0, plan.largest_buffer_name().c_str(), plan.device_peak_bytes() / 1048576.0);
    if (cfg.D != 10) {
      EXPECT_TRUE(r.plan.untiled());  // the small model fits lavapipe untiled
      continue;
    }
    EXPECT_FALSE(r.plan.untiled());
    // The published model's exact halo (288: input rects of 608 x 608 at least) needs a 146 MB
    // space_to_depth buffer, above lavapipe's 128 MiB; 256 is the largest halo that fits there.
    EXPECT_EQ(exact_halo(cfg, Mode::m, 100.0), 288);
    EXPECT_THROW(choose_tile(model, 720, 1280, Mode::m, 288, plan.max_buffer_bytes()), Error);
    const int64_t tile = choose_tile(model, 720, 1280, Mode::m, 256, plan.max_buffer_bytes());
    EXPECT_EQ(tile, 64);
    PlanningBackend plan_one;
    Model one(plan_one, w);
    one.run(random_inputs(2, tile + 512, tile + 512, cfg.N, 1, false), opt);  // an unclipped tile
    EXPECT_LE(plan_one.largest_buffer(), plan_one.max_buffer_bytes());
  }
}

// A lavapipe backend capped at 4 MiB per buffer: the automatic tile fits it and the run completes
// (without tiling the same run throws), equal to the CPU run with the same tiles.
TEST(TilingVulkan, CappedBufferLimitForcesTiles) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  const ModelInputs in = random_inputs(1, 96, 128, w.config.N, 21);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  VulkanBackend vk(vktest::context());
  vk.set_max_buffer_bytes(1u << 20);
  Model gm(vk, w);
  EXPECT_THROW(gm.run(in, opt), Error);
  TileOptions t;
  t.halo = 32;
  const TiledResult g = run_tiled(gm, in, opt, t);
  EXPECT_FALSE(g.plan.untiled());
  EXPECT_LE(vk.device_peak_bytes(), 64ull << 20);
  CpuBackend cpu;
  Model cm(cpu, w);
  t.tile = g.plan.tile_h;
  const TiledResult c = run_tiled(cm, in, opt, t);
  EXPECT_LE(max_abs_diff(g.outputs.at(ModelOutput::fused), c.outputs.at(ModelOutput::fused)), 1e-4);
}

// The shipped default model on one 1280x720 SelfUnroll-S target on lavapipe, tiled (tile 256,
// halo 64) with sparse exact: events only in a band, so part of the tiles run.
TEST(TilingVulkan, SmallModel1280x720STarget) {
  const Weights w = load_weights(std::string(VKUNROLL_SOURCE_DIR) + "/models/" + kDefaultModelFile);
  ModelInputs in = random_inputs(1, 720, 1280, w.config.N, 31);
  if (w.config.physics_input) in.phys = in.rs;  // physics where no event fired returns its input
  keep_events_in(in, 256, 0, 128, 1280);
  VulkanBackend vk(vktest::context());
  Model model(vk, w);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  TileOptions t;
  t.tile = 256;
  t.halo = 64;
  t.sparse = SparsePolicy::exact;
  const Stopwatch running;
  const TiledResult r = run_tiled(model, in, opt, t);
  const double s = running.seconds();
  std::printf("[ tiling   ] small model 1280x720 S, tile 256 halo 64 sparse exact: %lld of %lld tiles run, %.1f s\n",
              (long long)r.tiles_run, (long long)r.tiles, s);
  EXPECT_EQ(r.tiles, 15);
  EXPECT_EQ(r.tiles_run, 10);  // tile rows 0 (input rows 0..319) and 1 reach the band 256..383
  const HostTensor& f = r.outputs.at(ModelOutput::fused);
  for (float v : f.data) ASSERT_TRUE(std::isfinite(v));
  // Tile row 2 (rows 512..719, input from row 448) saw no event: the RS pixels.
  for (int64_t c = 0; c < 3; ++c)
    for (int64_t y = 512; y < 720; y += 7)
      for (int64_t x = 0; x < 1280; x += 5) ASSERT_EQ(f.data[size_t((c * 720 + y) * 1280 + x)], in.rs.data[size_t((c * 720 + y) * 1280 + x)]);
}

// `vkunroll unroll` with --mode choose, --tile, --halo, --sparse: the per-target mode choice and the
// tiling record in summary.json.
TEST(TilingUnroll, ChooseModeAndTiledSparseSummary) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("vkunroll-test-tiling-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  sim::SimulationConfig cfg = sim::simulation_preset("clean");
  cfg.seed = 11;
  cfg.width = 64;
  cfg.height = 48;
  cfg.frames = 3;
  cfg.gt_per_frame = 1;
  sim::write_sequence(cfg, sim::simulate(cfg), (dir / "seq").string());
  UnrollOptions o;
  o.sequence = (dir / "seq").string();
  o.out_dir = (dir / "out").string();
  o.quiet = true;
  o.output.write_video = false;
  o.session.backend = BackendKind::cpu;
  o.session.model_path = fixture("selfunroll_tiny.safetensors");
  o.mode = UnrollMode::choose;
  o.times = parse_target_times("-0.25,0.5");  // before the frame's exposure span, inside it
  o.frames = {1, 2};                          // frame 2 is the last: M impossible there
  o.tile = 32;
  o.halo = 32;
  o.sparse = SparsePolicy::exact;
  const auto s = run_unroll(o);
  EXPECT_EQ(s["runs"]["m"].get<int>(), 1);  // frame 1: -0.25
  EXPECT_EQ(s["runs"]["s"].get<int>(), 3);  // frame 1: 0.5; frame 2: both
  const auto& t = s["tiling"];
  EXPECT_EQ(t["tile"].get<int>(), 32);
  EXPECT_EQ(t["tile_used"].get<int>(), 32);
  EXPECT_EQ(t["halo"].get<int>(), 32);
  EXPECT_EQ(t["sparse"].get<std::string>(), "exact");
  EXPECT_EQ(t["tiles_per_target"].get<int>(), 4);  // 64x48 in 32-pixel tiles
  EXPECT_EQ(t["tiles"].get<int>(), 4 * 4);
  const double f = t["active_tile_fraction"].get<double>();
  EXPECT_NEAR(f, t["tiles_run"].get<double>() / 16.0, 1e-12);
  EXPECT_GT(f, 0.0);  // the clean scene moves: events in some tiles
  bool noted = false;
  for (const auto& n : s["notes"]) noted = noted || n.get<std::string>().find("outside its frame's exposure span") != std::string::npos;
  EXPECT_TRUE(noted);
  o.tile = 40;
  try {
    run_unroll(o);
    ADD_FAILURE() << "tile 40 accepted";
  } catch (const OptionError& e) {
    EXPECT_EQ(e.field(), "tile");
    EXPECT_NE(std::string(e.what()).find("tile 40"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_sparse_policy("sometimes", "sparse"), OptionError);
  fs::remove_all(dir);
}
