#include "vkunroll/kernels/igemm.hpp"

#include <algorithm>

#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr int64_t kKAlign = 16;     // the deepest stage (BK) of any tile: cin_pad's multiple
constexpr int kMinStagesPerSplit = 4;
constexpr uint32_t kMaxSplits = 16;
// Shader cores assumed where the device does not say (DeviceInfo::compute_units): an H100 has 132 SMs.
constexpr uint32_t kDefaultGpuCores = 128;

int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }
uint32_t u32(int64_t v) { return static_cast<uint32_t>(v); }

// shaders/igemm_common.glsl's push constants (the 128 bytes every device offers).
struct IgemmPush {
  uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint32_t h, w, cout, pad;
  uint32_t kpad, cin, n;
  uint32_t gh, gw, ksplit;
  uint32_t out_h, out_w, crop_y, crop_x;
  uint32_t src_h, src_w, src_y, src_x;
  uint32_t piece_off[4], piece_bs[4];
};
static_assert(sizeof(IgemmPush) <= 128);

int64_t pixel_tiles(const IgemmTile& t, const IgemmProblem& pb) { return (pb.npix() + t.bn - 1) / t.bn; }
int64_t channel_tiles(const IgemmTile& t, const IgemmProblem& pb) { return (pb.cout + t.bm - 1) / t.bm; }

// The reduction per split: a whole number of stages, the splits covering kpad.
int64_t split_depth(const IgemmProblem& pb, uint32_t splits) {
  const int64_t stages = igemm_kpad(pb) / kKAlign;
  return (stages + splits - 1) / splits * kKAlign;
}

// The fold's spec constants 17-23: MAP, PIECES, the channel starts of pieces 1-4, SCALE.
void append_fold_spec(std::vector<uint32_t>& spec, const IgemmProblem& pb) {
  spec.resize(17, 0);
  const size_t pieces = pb.piece_channels.empty() ? 1 : pb.piece_channels.size();
  spec.push_back(static_cast<uint32_t>(pb.map));
  spec.push_back(static_cast<uint32_t>(pieces));
  int64_t start = 0;
  for (size_t i = 1; i < 5; ++i) {
    if (i < pieces) start += pb.piece_channels[i - 1];
    spec.push_back(i < pieces ? static_cast<uint32_t>(start) : 0xffffffffu);
  }
  spec.push_back(spec_float(pb.scale));
}

std::vector<uint32_t> igemm_spec(const IgemmTile& t, const IgemmProblem& pb, bool has_res, bool partial) {
  std::vector<uint32_t> spec{pb.kh, pb.kw, pb.stride, static_cast<uint32_t>(pb.act.kind), spec_float(pb.act.slope),
                             has_res ? 1u : 0u};
  if (t.coopmat)
    spec.insert(spec.end(), {t.lm, t.ln, t.lk, t.fm, t.fn, pb.transposed ? 1u : 0u, t.threads(), partial ? 1u : 0u,
                             t.warp, t.wm, t.wn});
  else
    spec.insert(spec.end(), {t.bm, t.bn, t.bk, t.tm, t.tn, pb.transposed ? 1u : 0u, t.threads(), partial ? 1u : 0u});
  append_fold_spec(spec, pb);
  return spec;
}

IgemmPush make_push(const IgemmProblem& pb, const IgemmBindings& b, uint32_t ksplit) {
  const bool folded = pb.map != InputMap::none;
  IgemmPush push{b.in.offset, b.in.batch_stride, b.res.offset, b.res.batch_stride, b.out.offset, b.out.batch_stride,
                 u32(pb.in.h), u32(pb.in.w), u32(pb.cout), pb.pad, u32(igemm_kpad(pb)), u32(pb.cin), u32(pb.in.n), u32(pb.gh), u32(pb.gw),
                 ksplit, u32(pb.out.h), u32(pb.out.w), u32(pb.crop_y), u32(pb.crop_x),
                 u32(folded ? pb.src_h : pb.in.h), u32(folded ? pb.src_w : pb.in.w), u32(pb.src_y), u32(pb.src_x),
                 {0, 0, 0, 0}, {0, 0, 0, 0}};
  for (size_t i = 0; i < b.more_pieces.size() && i < 4; ++i) {
    push.piece_off[i] = b.more_pieces[i].offset;
    push.piece_bs[i] = b.more_pieces[i].batch_stride;
  }
  return push;
}

// Bindings 6-9: input pieces 1-4 (piece 0 again where there are fewer).
std::vector<Arg> piece_args(const IgemmBindings& b) {
  std::vector<Arg> a;
  for (size_t i = 0; i < 4; ++i) a.push_back(i < b.more_pieces.size() ? b.more_pieces[i].arg : b.in.arg);
  return a;
}

// What the shader's loads assume of the tile (each invocation keeps fixed X columns).
bool tile_divides(const IgemmTile& t) {
  if (t.coopmat) return t.threads() % (t.bn / 8) == 0 && t.bk % 8 == 0 && (t.lm * t.ln) % t.warp == 0;
  // X: each invocation keeps one column, and the rows its passes cover (threads / BN a pass) fill the stage.
  return t.threads() % t.bn == 0 && t.bk % (t.threads() / t.bn) == 0 && t.bm % t.tm == 0 && t.bn % t.tn == 0 &&
         t.tm % 4 == 0 && t.tn % 4 == 0 && t.tm * t.tn <= 64;
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

int64_t igemm_cin_pad(int64_t cin) { return round_up(cin, kKAlign); }
int64_t igemm_kpad(const IgemmProblem& pb) { return pb.taps() * igemm_cin_pad(pb.cin); }
int64_t igemm_cout_pad(int64_t cout) { return round_up(cout, 4); }

std::vector<float> igemm_pack(int64_t phases, int64_t cin, int64_t taps, int64_t cout, const IgemmWeight& weight) {
  const int64_t cinp = igemm_cin_pad(cin), kpad = taps * cinp, cpad = igemm_cout_pad(cout);
  std::vector<float> a(static_cast<size_t>(phases * kpad * cpad), 0.f);
  for (int64_t ph = 0; ph < phases; ++ph)
    for (int64_t t = 0; t < taps; ++t)
      for (int64_t ci = 0; ci < cin; ++ci)
        for (int64_t co = 0; co < cout; ++co)
          a[static_cast<size_t>((ph * kpad + t * cinp + ci) * cpad + co)] = weight(ph, ci, t, co);
  return a;
}

std::vector<float> igemm_pack_rows(int64_t cin, int64_t taps, int64_t cout, int64_t cout_pad, const IgemmWeight& weight) {
  const int64_t cinp = igemm_cin_pad(cin), kpad = taps * cinp;
  std::vector<float> a(static_cast<size_t>(cout_pad * kpad), 0.f);
  for (int64_t co = 0; co < cout; ++co)
    for (int64_t t = 0; t < taps; ++t)
      for (int64_t ci = 0; ci < cin; ++ci) a[static_cast<size_t>(co * kpad + t * cinp + ci)] = weight(0, ci, t, co);
  return a;
}

uint32_t igemm_splits(const DeviceInfo& info, const IgemmTile& tile, const IgemmProblem& pb, uint64_t scratch_limit,
                      int forced) {
  const int64_t stages = igemm_kpad(pb) / kKAlign;
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
  const size_t pieces = pb.piece_channels.empty() ? 1 : pb.piece_channels.size();
  if (pieces > size_t(kMaxInputPieces) || b.more_pieces.size() + 1 != pieces)
    throw Error(info.name + ": " + std::to_string(pieces) + " input pieces, " + std::to_string(b.more_pieces.size() + 1) +
                " bound (at most " + std::to_string(kMaxInputPieces) + ")");
  const IgemmPush push = make_push(pb, b, u32(split_depth(pb, splits)));
  std::vector<Arg> args{b.in.arg, b.weight, b.bias, b.res.arg, b.out.arg, b.bias};
  const std::vector<Arg> more = piece_args(b);
  args.insert(args.end(), more.begin(), more.end());
  const std::string shader = tile.coopmat ? (tile.emulated ? "conv2d_igemm_coopmat_emulated" : "conv2d_igemm_coopmat")
                                          : shader_for(ctx, "conv2d_igemm", pb.precision, info.name);
  // The real coopmat form assumes warps of exactly one subgroup: it asks for that width (full subgroups).
  const uint32_t width = tile.coopmat && !tile.emulated ? tile.warp : 0;
  const Groups groups{u32(pixel_tiles(tile, pb)), u32(channel_tiles(tile, pb)), u32(pb.phases() * splits)};
  if (splits == 1) {
    cs.dispatch(kernel_pipeline(ctx, shader, igemm_spec(tile, pb, b.has_res, false), sizeof push, width), args, push,
                groups, info);
    return;
  }
  const uint64_t part_bytes = static_cast<uint64_t>(splits) * pb.phases() * pb.cout * pb.npix() * 4;
  const Tensor& part = workspace.get(ctx, 2, part_bytes);
  const BufferRange pr = part.range(0, part_bytes);
  const double part_traffic = static_cast<double>(part_bytes);
  args[5] = {pr, Access::write};
  cs.dispatch(kernel_pipeline(ctx, shader, igemm_spec(tile, pb, b.has_res, true), sizeof push, width), args, push, groups,
              {info.name, info.flop, info.bytes + part_traffic});
  const std::string reduce = shader_for(ctx, "conv2d_igemm_reduce", pb.precision, info.name);
  std::vector<uint32_t> rspec{0, 0, pb.stride, static_cast<uint32_t>(pb.act.kind), spec_float(pb.act.slope),
                              b.has_res ? 1u : 0u, 0, 0, 0, 0, 0, pb.transposed ? 1u : 0u};
  append_fold_spec(rspec, pb);
  cs.dispatch(kernel_pipeline(ctx, reduce, rspec, sizeof push), {{pr, Access::read}, b.bias, b.res.arg, b.out.arg}, push,
              flat_groups(pb.phases() * pb.cout * pb.npix(), 1), {info.name + "_splitk", 0, part_traffic});
}

ConvCost igemm_cost(const IgemmTile& t, const IgemmProblem& pb, uint32_t splits) {
  const double e = static_cast<double>(dtype_size(precision_dtype(pb.precision)));
  const double groups = static_cast<double>(pixel_tiles(t, pb) * channel_tiles(t, pb) * pb.phases());
  const double kpad = static_cast<double>(igemm_kpad(pb));
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
