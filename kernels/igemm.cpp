#include "vkunroll/kernels/igemm.hpp"

#include <algorithm>

#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr int64_t kKAlign = 16;     // the deepest stage (BK) of any tile
constexpr int kMinStagesPerSplit = 4;
constexpr uint32_t kMaxSplits = 16;
// Shader cores assumed where the device does not say (DeviceInfo::compute_units): an H100 has 132 SMs.
constexpr uint32_t kDefaultGpuCores = 128;

int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }
uint32_t u32(int64_t v) { return static_cast<uint32_t>(v); }

struct IgemmPush {
  uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint32_t cin, h, w, cout, oh, ow, pad;
  uint32_t kdim, kpad, co4;
  uint32_t npix, gh, gw;
  uint32_t ksplit, nsplit;
};

int64_t pixel_tiles(const IgemmTile& t, const IgemmProblem& pb) { return (pb.npix() + t.bn - 1) / t.bn; }
int64_t channel_tiles(const IgemmTile& t, const IgemmProblem& pb) { return (pb.cout + t.bm - 1) / t.bm; }

// The reduction per split: a whole number of stages, the splits covering kpad.
int64_t split_depth(const IgemmProblem& pb, uint32_t splits) {
  const int64_t stages = igemm_kpad(pb.kdim()) / kKAlign;
  return (stages + splits - 1) / splits * kKAlign;
}

std::vector<uint32_t> igemm_spec(const IgemmTile& t, const IgemmProblem& pb, bool has_res, bool partial) {
  std::vector<uint32_t> spec{pb.kh, pb.kw, pb.stride, static_cast<uint32_t>(pb.act.kind), spec_float(pb.act.slope),
                             has_res ? 1u : 0u};
  if (t.coopmat)
    spec.insert(spec.end(), {t.lm, t.ln, t.lk, t.fm, t.fn, pb.transposed ? 1u : 0u, t.threads(), partial ? 1u : 0u,
                             t.warp, t.wm, t.wn});
  else
    spec.insert(spec.end(), {t.bm, t.bn, t.bk, t.tm, t.tn, pb.transposed ? 1u : 0u, t.threads(), partial ? 1u : 0u});
  return spec;
}

// What the shader's loads assume of the tile (each invocation keeps fixed X columns).
bool tile_divides(const IgemmTile& t) {
  if (t.coopmat) return t.threads() % (t.bn / 8) == 0 && t.bk % 8 == 0 && (t.lm * t.ln) % t.warp == 0;
  return t.threads() % t.bn == 0 && t.tm % 4 == 0 && t.tn % 4 == 0 && t.tm * t.tn <= 64;
}
}  // namespace

IgemmTile coopmat_tile(uint32_t lm, uint32_t ln, uint32_t lk, bool emulated) {
  IgemmTile t;
  t.coopmat = true, t.emulated = emulated;
  t.lm = lm, t.ln = ln, t.lk = lk;
  t.fm = 2, t.fn = 32 / ln, t.wm = 2, t.wn = 2;
  t.bm = t.wm * t.fm * lm, t.bn = t.wn * t.fn * ln, t.bk = lk;
  return t;
}

int64_t igemm_kpad(int64_t kdim) { return round_up(kdim, kKAlign); }
int64_t igemm_cout_pad(int64_t cout) { return round_up(cout, 4); }

std::vector<float> igemm_pack(int64_t phases, int64_t kdim, int64_t cout,
                              const std::function<float(int64_t, int64_t, int64_t)>& weight) {
  const int64_t kpad = igemm_kpad(kdim), cpad = igemm_cout_pad(cout);
  std::vector<float> a(static_cast<size_t>(phases * kpad * cpad), 0.f);
  for (int64_t ph = 0; ph < phases; ++ph)
    for (int64_t k = 0; k < kdim; ++k)
      for (int64_t co = 0; co < cout; ++co) a[static_cast<size_t>((ph * kpad + k) * cpad + co)] = weight(ph, k, co);
  return a;
}

uint32_t igemm_splits(const DeviceInfo& info, const IgemmTile& tile, const IgemmProblem& pb, uint64_t scratch_limit,
                      int forced) {
  const int64_t stages = igemm_kpad(pb.kdim()) / kKAlign;
  const int64_t groups = pixel_tiles(tile, pb) * channel_tiles(tile, pb) * pb.phases();
  const uint64_t per_split = static_cast<uint64_t>(pb.phases() * pb.cout * pb.npix()) * 4;
  int64_t want = 1;
  if (forced > 0) {
    want = std::min<int64_t>(forced, stages);
  } else if (info.type != VK_PHYSICAL_DEVICE_TYPE_CPU) {
    const int64_t cores = info.compute_units ? info.compute_units : kDefaultGpuCores;
    want = std::min<int64_t>({(2 * cores + groups - 1) / groups, stages / kMinStagesPerSplit, kMaxSplits});
  }
  want = std::max<int64_t>(1, std::min<int64_t>(want, static_cast<int64_t>(scratch_limit / per_split)));
  // Splits that would leave the last one empty are fewer in fact: count those the depth gives.
  const int64_t depth = split_depth(pb, static_cast<uint32_t>(want)) / kKAlign;
  return static_cast<uint32_t>((stages + depth - 1) / depth);
}

bool igemm_fits(const DeviceInfo& info, const IgemmTile& tile, const IgemmProblem& pb) {
  return pixel_tiles(tile, pb) <= info.max_workgroup_count[0] && channel_tiles(tile, pb) <= info.max_workgroup_count[1] &&
         pb.phases() * kMaxSplits <= info.max_workgroup_count[2] && tile.threads() <= info.max_workgroup_invocations;
}

void igemm_record(Context& ctx, CommandStream& cs, ConvWorkspace& workspace, const IgemmTile& tile,
                  const IgemmProblem& pb, const IgemmBindings& b, uint32_t splits, const DispatchInfo& info) {
  if (!tile_divides(tile))
    throw Error(info.name + ": igemm tile " + std::to_string(tile.bm) + "x" + std::to_string(tile.bn) +
                " does not divide among its invocations");
  const int64_t kpad = igemm_kpad(pb.kdim());
  IgemmPush push{b.in.offset, b.in.batch_stride, b.res.offset, b.res.batch_stride, b.out.offset, b.out.batch_stride,
                 u32(pb.cin), u32(pb.in.h), u32(pb.in.w), u32(pb.cout), u32(pb.out.h), u32(pb.out.w), pb.pad,
                 u32(pb.kdim()), u32(kpad), u32(igemm_cout_pad(pb.cout) / 4), u32(pb.npix()), u32(pb.gh), u32(pb.gw),
                 u32(split_depth(pb, splits)), splits};
  const std::string shader = tile.coopmat ? (tile.emulated ? "conv2d_igemm_coopmat_emulated" : "conv2d_igemm_coopmat")
                                          : shader_for(ctx, "conv2d_igemm", pb.precision, info.name);
  const Groups groups{u32(pixel_tiles(tile, pb)), u32(channel_tiles(tile, pb)), u32(pb.phases() * splits)};
  if (splits == 1) {
    cs.dispatch(kernel_pipeline(ctx, shader, igemm_spec(tile, pb, b.has_res, false), sizeof push),
                {b.in.arg, b.weight, b.bias, b.res.arg, b.out.arg, b.bias}, push, groups, info);
    return;
  }
  const uint64_t part_bytes = static_cast<uint64_t>(splits) * pb.phases() * pb.cout * pb.npix() * 4;
  const Tensor& part = workspace.get(ctx, 2, part_bytes);
  const BufferRange pr = part.range(0, part_bytes);
  const double part_traffic = static_cast<double>(part_bytes);
  cs.dispatch(kernel_pipeline(ctx, shader, igemm_spec(tile, pb, b.has_res, true), sizeof push),
              {b.in.arg, b.weight, b.bias, b.res.arg, b.out.arg, {pr, Access::write}}, push, groups,
              {info.name, info.flop, info.bytes + part_traffic});
  const std::string reduce = shader_for(ctx, "conv2d_igemm_reduce", pb.precision, info.name);
  const std::vector<uint32_t> rspec{0, 0, pb.stride, static_cast<uint32_t>(pb.act.kind), spec_float(pb.act.slope),
                                    b.has_res ? 1u : 0u, 0, 0, 0, 0, 0, pb.transposed ? 1u : 0u};
  cs.dispatch(kernel_pipeline(ctx, reduce, rspec, sizeof push), {{pr, Access::read}, b.bias, b.res.arg, b.out.arg}, push,
              flat_groups(pb.phases() * pb.cout * pb.npix(), 1), {info.name + "_splitk", 0, part_traffic});
}

ConvCost igemm_cost(const IgemmTile& t, const IgemmProblem& pb, uint32_t splits) {
  const double e = static_cast<double>(dtype_size(precision_dtype(pb.precision)));
  const double groups = static_cast<double>(pixel_tiles(t, pb) * channel_tiles(t, pb) * pb.phases());
  const double kpad = static_cast<double>(igemm_kpad(pb.kdim()));
  ConvCost c;
  c.fma = groups * t.bm * t.bn * kpad;
  // Every workgroup loads its A (BM x kpad) and X (kpad x BN) tiles once; the output once (twice with
  // split-K's fp32 partial sums, written and read back).
  const double outputs = static_cast<double>(pb.out.count());
  c.global_bytes = groups * kpad * (t.bm + t.bn) * e + outputs * e;
  if (splits > 1) c.global_bytes += 2.0 * 4.0 * splits * pb.phases() * pb.cout * pb.npix();
  if (t.coopmat) {
    // Per stage each workgroup stores (BM + BN) x BK halves and each warp loads its fragments; the
    // epilogue passes C (fp32) through shared memory once, stored and loaded.
    const double frags = double(t.wm * t.wn) * (t.fm * t.lm * t.lk + t.fn * t.lk * t.ln);
    c.shared_bytes = groups * ((kpad / t.bk) * 2.0 * ((t.bm + t.bn) * t.bk + frags) + 8.0 * t.bm * t.bn);
    return c;
  }
  // Per stage each workgroup stores (BM + BN) x BK values and each invocation loads (TM + TN) x BK.
  c.shared_bytes = groups * kpad * 4.0 * ((t.bm + t.bn) + t.threads() * double(t.tm + t.tn));
  return c;
}

}  // namespace vkunroll
