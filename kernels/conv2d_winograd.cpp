// conv2d, Winograd F(4x4, 3x3) (winograd_input, winograd_gemm, winograd_output), F(4x4, 5x5)
// (winograd45_input, winograd_gemm with 64 positions, winograd45_output) and the 1x1 GEMM
// (conv1x1_pack, winograd_gemm with one position, conv1x1_output), with their scratch sizes.
// fp16: Winograd reads and writes float16 activations but keeps U, V and M fp32 (its transforms
// amplify their rounding: docs/kernels.md, "Precision"); the 1x1 GEMM's packed input and weights are
// float16, M fp32.
#include <algorithm>
#include <functional>

#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
struct WinogradSizes {
  int64_t tiles_x_pad, tiles_y, ngroups, tiles_pad;  // groups of 4 horizontally adjacent tiles
};
// Output tiles of `to` x `to` pixels (4 or 6) over the output `in`.
WinogradSizes winograd_sizes(const Shape& in, int64_t to) {
  WinogradSizes s{};
  s.tiles_x_pad = ((in.w + to - 1) / to + 3) / 4 * 4;
  s.tiles_y = (in.h + to - 1) / to;
  s.ngroups = in.n * s.tiles_y * s.tiles_x_pad / 4;
  s.tiles_pad = (s.ngroups * 4 + 15) / 16 * 16;  // whole GEMM blocks of up to 16 tiles
  return s;
}

int64_t gemm_pix_pad(const Shape& in) { return (in.n * in.h * in.w + 15) / 16 * 16; }

// U = G g G^T of one k x k kernel (k <= 5) for an n-position form (n <= 8), in double: store(i, j, u)
// receives position (i, j). G(i, t) and g(y, x) are the transform's and the kernel's entries.
template <class GF, class KF, class Store>
void transform_kernel(int n, int k, GF G, KF g, Store store) {
  double gg[8][5];
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < k; ++j) {
      double acc = 0;
      for (int t = 0; t < k; ++t) acc += G(i, t) * g(t, j);
      gg[i][j] = acc;
    }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      double acc = 0;
      for (int t = 0; t < k; ++t) acc += gg[i][t] * G(j, t);
      store(i, j, acc);
    }
}
}  // namespace

// G of the 8-point forms (points 0, +-1, +-2, +-1/2, inf; B^T and A^T are in the shaders): row i < 7,
// column t is a_i^t / prod_{l != i} (a_i - a_l); the last row picks the kernel's last tap. F(4x4, 5x5)
// uses all 5 columns, F(6x6, 3x3) the first 3.
const double kG8[7][5] = {{1, 0, 0, 0, 0},
                           {-2.0 / 9, -2.0 / 9, -2.0 / 9, -2.0 / 9, -2.0 / 9},
                           {-2.0 / 9, 2.0 / 9, -2.0 / 9, 2.0 / 9, -2.0 / 9},
                           {1.0 / 90, 1.0 / 45, 2.0 / 45, 4.0 / 45, 8.0 / 45},
                           {1.0 / 90, -1.0 / 45, 2.0 / 45, -4.0 / 45, 8.0 / 45},
                           {32.0 / 45, 16.0 / 45, 8.0 / 45, 4.0 / 45, 2.0 / 45},
                           {32.0 / 45, -16.0 / 45, 8.0 / 45, -4.0 / 45, 2.0 / 45}};

void Conv2d::pack_winograd8() {
  // U = G g G^T in double: [64][cin][cout_pad], fp32 in both precisions.
  const int k = params_.kernel;
  const auto G = [k](int i, int t) { return i < 7 ? kG8[i][t] : (t == k - 1 ? 1.0 : 0.0); };
  std::vector<float> u(static_cast<size_t>(64 * cin_ * gemm_cout_pad_), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t ci = 0; ci < cin_; ++ci)
      transform_kernel(8, k, G, [&](int y, int x) -> double { return weight_host_.at(co, ci, y, x); },
                       [&](int i, int j, double v) {
                         u[static_cast<size_t>(((i * 8 + j) * cin_ + ci) * gemm_cout_pad_ + co)] = static_cast<float>(v);
                       });
  winograd_ks_ = 1;
  weight_winograd_ = vkunroll::upload_weights(ctx_, u, Precision::fp32, name_);
}

void Conv2d::pack_winograd() {
  if (winograd_tile8()) return pack_winograd8();
  const int k = params_.kernel;
  const bool wino_s2 = k == 3 && params_.stride == 2 && params_.pad == 1;
  // Winograd F(4x4, 3x3): U = G g G^T in double, [36][KS*KS*cin][cout_pad]. A 5x5 kernel is split
  // into four 3x3 blocks at offsets (0|3, 0|3) (zero beyond 5): four 3x3 convs on shifted inputs,
  // summed by the GEMM as KS*KS*cin virtual input channels.
  // Stride 2: four phase images (a, b); tap (i', j') of the 3x3 kernel on phase a reads kernel row
  // 1 (a = 0, i' = 1) or rows 0 and 2 (a = 1, i' = 0 and 1); every other tap is zero.
  winograd_ks_ = (k == 5 || wino_s2) ? 2 : 1;
  const int64_t cv = winograd_ks_ * winograd_ks_ * cin_;
  static const double Gm[6][3] = {{1.0 / 4, 0, 0},           {-1.0 / 6, -1.0 / 6, -1.0 / 6}, {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                  {1.0 / 24, 1.0 / 12, 1.0 / 6}, {1.0 / 24, -1.0 / 12, 1.0 / 6}, {0, 0, 1}};
  std::vector<float> u(static_cast<size_t>(36 * cv * gemm_cout_pad_), 0.f);
  for (int64_t sblk = 0; sblk < winograd_ks_ * winograd_ks_; ++sblk) {
    const int64_t oy = 3 * (sblk / winograd_ks_), ox = 3 * (sblk % winograd_ks_);
    const int64_t pa = sblk / 2, pb = sblk % 2;
    auto phase_tap = [](int64_t phase, int64_t t) -> int64_t {
      if (phase == 0) return t == 1 ? 1 : -1;  // row 2u: kernel row 1 at u = oy
      return t == 0 ? 0 : (t == 1 ? 2 : -1);   // row 2u+1: kernel row 0 at u = oy-1, row 2 at u = oy
    };
    for (int64_t co = 0; co < cout_; ++co)
      for (int64_t ci = 0; ci < cin_; ++ci) {
        auto g = [&](int64_t y, int64_t x) -> double {
          if (wino_s2) {
            const int64_t ky = phase_tap(pa, y), kx = phase_tap(pb, x);
            return (ky >= 0 && kx >= 0) ? weight_host_.at(co, ci, ky, kx) : 0.0;
          }
          return (oy + y < k && ox + x < k) ? weight_host_.at(co, ci, oy + y, ox + x) : 0.0;
        };
        const int64_t vc = sblk * cin_ + ci;
        transform_kernel(6, 3, [](int i, int t) { return Gm[i][t]; }, g, [&](int i, int j, double v) {
          u[static_cast<size_t>(((i * 6 + j) * cv + vc) * gemm_cout_pad_ + co)] = static_cast<float>(v);
        });
      }
  }
  weight_winograd_ = vkunroll::upload_weights(ctx_, u, Precision::fp32, name_);  // fp32 in both precisions
}

void Conv2d::pack_gemm() {
  std::vector<float> u(static_cast<size_t>(cin_ * gemm_cout_pad_), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t ci = 0; ci < cin_; ++ci)
      u[static_cast<size_t>(ci * gemm_cout_pad_ + co)] = weight_host_.data[static_cast<size_t>(co * cin_ + ci)];
  weight_gemm_ = upload_weights(u);
}

int64_t Conv2d::winograd_chunk(const Shape& in) const {
  const uint64_t limit = std::min<uint64_t>(ctx_.info().max_storage_buffer_range, winograd_scratch_limit_);
  if (!weight_gemm_.empty()) {  // 1x1 gemm path: one position, pixels padded to 16
    const uint64_t per_channel = static_cast<uint64_t>(gemm_pix_pad(in)) * elem_bytes();
    return std::min<int64_t>(cin_, static_cast<int64_t>(limit / per_channel));
  }
  const WinogradSizes ws = winograd_sizes(output_shape(in), winograd_tile_out());
  const uint64_t per_channel = static_cast<uint64_t>(winograd_npos() * ws.tiles_pad) * 4;  // V is fp32
  const int64_t cv = winograd_ks_ * winograd_ks_ * cin_;
  return std::min<int64_t>(cv, static_cast<int64_t>(limit / per_channel));
}

bool Conv2d::supports(ConvAlgo algo, const Shape& in) const {
  if (!supports(algo)) return false;
  if (algo == ConvAlgo::coopmat) return coopmat_fits(in);
  if (is_igemm(algo)) return igemm_fits_shape(algo, in);
  // M (fp32 in both precisions, all output channels) must fit one binding; V runs in chunks.
  if (algo == ConvAlgo::gemm)
    return static_cast<uint64_t>(gemm_cout_pad_ * gemm_pix_pad(in)) * 4 <= ctx_.info().max_storage_buffer_range &&
           winograd_chunk(in) >= 1;
  if (algo != ConvAlgo::winograd) return true;
  // A batch runs in groups of items (record_winograd): one item's M must fit.
  Shape one = in;
  one.n = 1;
  return winograd_m_fits(one) && winograd_chunk(one) >= 1;
}

bool Conv2d::winograd_m_fits(const Shape& in) const {
  const WinogradSizes ws = winograd_sizes(output_shape(in), winograd_tile_out());
  const uint64_t m_bytes = static_cast<uint64_t>(winograd_npos() * gemm_cout_pad_ * ws.tiles_pad) * 4;
  return m_bytes <= ctx_.info().max_storage_buffer_range;
}

void Conv2d::record_winograd(CommandStream& cs, const Recording& r) const {
  // A batch runs in groups of items where its M does not fit one binding, or where its transformed
  // input needs channel chunks while a group's would not: each group's GEMM then takes every
  // channel at once and writes M once, where chunks read and write the whole batch's M again per
  // chunk (a batch of 8 GS targets' SFENet1 ran in 6 chunks over a 94 MB M).
  const int64_t cv = winograd_ks_ * winograd_ks_ * cin_, n = r.os.n;
  if (n > 1 && (!winograd_m_fits(r.is) || winograd_chunk(r.is) < cv)) {
    // The largest group whose GEMM takes every channel; else, where the whole M does not fit, the
    // largest group whose M does (channel chunks inside it).
    const auto largest = [&](const std::function<bool(const Shape&)>& ok) {
      Shape s = r.is;
      for (s.n = n - 1; s.n >= 1 && !ok(s); --s.n) {
      }
      return s;
    };
    Shape part = largest([&](const Shape& s) { return winograd_m_fits(s) && winograd_chunk(s) >= cv; });
    if (part.n < 1 && !winograd_m_fits(r.is)) part = largest([&](const Shape& s) { return winograd_m_fits(s); });
    if (part.n >= 1) {
      for (int64_t n0 = 0; n0 < n; n0 += part.n) {
        Recording g = r;
        g.is.n = g.os.n = std::min(part.n, n - n0);
        const auto at = [n0](uint32_t offset, uint32_t stride) { return static_cast<uint32_t>(offset + n0 * stride); };
        g.in.offset = at(r.in.offset, r.in.batch_stride);
        g.out.offset = at(r.out.offset, r.out.batch_stride);
        if (r.has_res) g.res.offset = at(r.res.offset, r.res.batch_stride);
        g.info.flop = r.info.flop * static_cast<double>(g.os.n) / static_cast<double>(n);
        g.shared_v = nullptr;
        record_winograd_items(cs, g);
      }
      return;
    }
  }
  record_winograd_items(cs, r);
}

void Conv2d::record_winograd_items(CommandStream& cs, const Recording& r) const {
  if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
  const WinogradSizes wz = winograd_sizes(r.os, winograd_tile_out());  // tiles of the output
  const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
  const int64_t cv = winograd_ks_ * winograd_ks_ * cin_, chunk = winograd_chunk(r.is);
  // V, U and M fp32 in both precisions; only the input and output slices are float16 in fp16.
  const int64_t npos = winograd_npos();
  const uint64_t e = 4, m_bytes = static_cast<uint64_t>(npos * gemm_cout_pad_ * wz.tiles_pad) * 4;
  const bool s2 = params_.stride == 2;
  const Tensor& mt = workspace_->get(ctx_, 1, m_bytes);
  const BufferRange mr = mt.range(0, m_bytes);
  const std::string& name = r.info.name;
  // Texel views where every range fits one (the storage forms otherwise): input, V and U, M.
  const auto v_bytes_of = [&](int64_t rows) { return static_cast<uint64_t>(npos * rows * wz.tiles_pad) * e; };
  const auto v_fits = [&](int64_t rows) {
    return texel_fits(v_bytes_of(rows), 16) && v_bytes_of(rows) <= ctx_.info().max_storage_buffer_range;
  };
  const bool texel_in = texel_fits(r.in.arg.range.size, elem_bytes());
  const bool texel_gemm = v_fits(chunk) && texel_fits(weight_winograd_.bytes(), 16);
  const bool texel_m = texel_fits(m_bytes, 16);
  const Arg in_arg = input_texel_arg(r);
  // Virtual channels [c0, c0 + cn) into rows [v0, v0 + cn) of a V of `rows` rows.
  const auto transform = [&](const BufferRange& vr, int64_t c0, int64_t cn, int64_t v0, int64_t rows, bool ilv) {
    struct InPush {
      uint32_t in_off, in_bs, cin, h, w, tiles_x_pad, tiles_y, ngroups, tiles_pad, ks, c_begin, chunk, s_in, off_mul;
      int32_t off_base;
      uint32_t ilv, rows, v0;
    } ip{r.in.offset, r.in.batch_stride, u32(cin_), u32(r.is.h), u32(r.is.w), u32(wz.tiles_x_pad), u32(wz.tiles_y),
         u32(wz.ngroups), u32(wz.tiles_pad), u32(winograd_ks_), u32(c0), u32(cn), s2 ? 2u : 1u, s2 ? 1u : 3u,
         winograd_tile8() ? -params_.pad : (params_.kernel == 5 ? -1 : 0), ilv ? gemm_tv_ : 0u, u32(rows), u32(v0)};  // ilv: the texel GEMM's order
    const Groups g = ilv ? flat_groups((wz.tiles_pad / (4 * gemm_tv_)) * cn, 1) : Groups{u32((wz.ngroups + 63) / 64), u32(cn), 1};
    const std::string in_shader = std::string(winograd_shader_stem()) + "_input" + (texel_in ? "_texel" : "");
    const double tile_in = winograd_tile8() ? 8.0 * (3 * winograd_tile_out() + 8) / 4 : 6.0 * 18 / 4;  // input values loaded per tile
    cs.dispatch(kernel_pipeline(ctx_, shader(in_shader.c_str()), {}, sizeof ip), {in_arg, {vr, Access::write}}, ip, g,
                {name + "_wino_in", 0, static_cast<double>(e) * static_cast<double>(npos + tile_in) * static_cast<double>(cn * wz.tiles_pad)});
  };
  // M (+)= U V over virtual channels [c0, c0 + cn), held in the first cn rows of a V of `rows` rows.
  const auto gemm = [&](const BufferRange& vr, int64_t c0, int64_t cn, int64_t rows, bool texel) {
    struct GemmPush {
      uint32_t chunk, tiles_pad, cout_pad, cin_total, c_begin, rows;
    } gp{u32(cn), u32(wz.tiles_pad), u32(gemm_cout_pad_), u32(cv), u32(c0), u32(rows)};
    const uint32_t tv = gemm_tv_;
    const Arg va{vr, Access::read, VK_FORMAT_R32G32B32A32_SFLOAT};
    const Arg ua{weight_winograd_.range(), Access::read, VK_FORMAT_R32G32B32A32_SFLOAT};
    const double v_bytes = static_cast<double>(e) * static_cast<double>(npos * cn * wz.tiles_pad);
    cs.dispatch(kernel_pipeline(ctx_, texel ? "winograd_gemm_texel" : "winograd_gemm", {u32(gemm_cob_), c0 > 0 ? 1u : 0u, u32(npos), tv},
                                sizeof gp),
                {va, ua, {mr, c0 > 0 ? Access::read_write : Access::write}}, gp,
                flat_groups(npos * (gemm_cout_pad_ / gemm_cob_) * (wz.tiles_pad / (4 * tv)), 1),
                {name + "_wino_gemm", r.info.flop * static_cast<double>(cn) / static_cast<double>(cv),
                 v_bytes + 4.0 * static_cast<double>(npos * gemm_cout_pad_ * (c0 > 0 ? 2 : 1) * wz.tiles_pad)});
  };
  WinogradInputCache* shared = r.shared_v;
  if (shared && texel_gemm && params_.kernel == 3 && !s2 && cin_ <= shared->capacity_ && v_fits(shared->capacity_)) {
    // A dense block's conv: its input's first channels were transformed by the block's earlier convs.
    const uint64_t bytes = v_bytes_of(shared->capacity_);
    const Tensor& vt = workspace_->get(ctx_, 2, bytes);
    const WinogradInputCache::Key key{r.in.arg.range.buffer, vt.range().buffer, r.in.arg.range.offset, r.in.offset,
                                      r.in.batch_stride, r.is.n, r.is.h, r.is.w};
    if (!(shared->key_ == key) || cin_ < shared->channels_) shared->key_ = key, shared->channels_ = 0;
    const BufferRange vr = vt.range(0, bytes);
    if (cin_ > shared->channels_) transform(vr, shared->channels_, cin_ - shared->channels_, shared->channels_, shared->capacity_, true);
    shared->channels_ = cin_;
    gemm(vr, 0, cin_, shared->capacity_, true);
  } else {
    const Tensor& vt = workspace_->get(ctx_, 0, static_cast<uint64_t>(npos * chunk * wz.tiles_pad) * e);
    // Input channels in chunks whose transformed tiles fit the scratch; the GEMM accumulates.
    for (int64_t c0 = 0; c0 < cv; c0 += chunk) {
      const int64_t cn = std::min(chunk, cv - c0);
      const BufferRange vr = vt.range(0, static_cast<size_t>(npos * cn * wz.tiles_pad) * e);
      transform(vr, c0, cn, 0, cn, texel_gemm);
      gemm(vr, c0, cn, cn, texel_gemm);
    }
  }
  struct OutPush {
    uint32_t res_off, res_bs, out_off, out_bs, cout, oh, ow, tiles_x_pad, tiles_y, ngroups, tiles_pad, cout_pad;
  } op{r.res.offset, r.res.batch_stride, r.out.offset, r.out.batch_stride, u32(cout_), u32(r.os.h), u32(r.os.w),
       u32(wz.tiles_x_pad), u32(wz.tiles_y), u32(wz.ngroups), u32(wz.tiles_pad), u32(gemm_cout_pad_)};
  const std::string out_shader = std::string(winograd_shader_stem()) + "_output" + (texel_m ? "_texel" : "");
  cs.dispatch(kernel_pipeline(ctx_, shader(out_shader.c_str()), {r.spec[2], r.spec[3], r.spec[4]},
                              sizeof op),
              {{mr, Access::read, VK_FORMAT_R32G32B32A32_SFLOAT}, {bias_.range(), Access::read}, r.res.arg, r.out.arg}, op,
              Groups{u32((wz.ngroups + 63) / 64), u32(cout_), 1},
              {name + "_wino_out", 0,
               static_cast<double>(m_bytes) + static_cast<double>(elem_bytes()) * static_cast<double>(r.os.count())});
}

void Conv2d::record_gemm(CommandStream& cs, const Recording& r) const {
  if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
  const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
  const int64_t pix_pad = gemm_pix_pad(r.is), chunk = winograd_chunk(r.is);
  const uint64_t e = elem_bytes(), m_bytes = static_cast<uint64_t>(gemm_cout_pad_ * pix_pad) * 4;
  const Tensor& vt = workspace_->get(ctx_, 0, static_cast<uint64_t>(chunk * pix_pad) * e);
  const Tensor& mt = workspace_->get(ctx_, 1, m_bytes);
  const BufferRange mr = mt.range(0, m_bytes);
  const std::string& name = r.info.name;
  // Texel views (input R32 / R16, V and U RGBA32F / RGBA16F: the packed operands are float16 in
  // fp16) where every range fits one; V then in winograd_gemm_texel's order.
  const bool texel = texel_fits(r.in.arg.range.size, e) && texel_fits(static_cast<uint64_t>(chunk * pix_pad) * e, 4 * e) &&
                     texel_fits(weight_gemm_.bytes(), 4 * e);
  const VkFormat f4 = precision_ == Precision::fp16 ? VK_FORMAT_R16G16B16A16_SFLOAT : VK_FORMAT_R32G32B32A32_SFLOAT;
  const Arg in_arg = input_texel_arg(r);
  for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
    const int64_t cn = std::min(chunk, cin_ - c0);
    const double v_bytes = static_cast<double>(e) * static_cast<double>(cn * pix_pad);
    const BufferRange vr = vt.range(0, static_cast<size_t>(cn * pix_pad) * e);
    if (texel) {
      struct PackPush {
        uint32_t in_off, in_bs, plane, npix, pix_pad, c_begin, chunk;
      } pp{r.in.offset, r.in.batch_stride, u32(r.is.h * r.is.w), u32(r.is.n * r.is.h * r.is.w), u32(pix_pad), u32(c0), u32(cn)};
      cs.dispatch(kernel_pipeline(ctx_, shader("conv1x1_pack_texel"), {gemm_tv_}, sizeof pp), {in_arg, {vr, Access::write}}, pp,
                  flat_groups(pix_pad / (4 * gemm_tv_) * cn, 1), {name + "_gemm_pack", 0, 2.0 * v_bytes});
    } else {
      record_1x1_pack(cs, r, vr, c0, cn, cn, pix_pad, "_gemm");
    }
    struct GemmPush {
      uint32_t chunk, tiles_pad, cout_pad, cin_total, c_begin, rows;
    } gp{u32(cn), u32(pix_pad), u32(gemm_cout_pad_), u32(cin_), u32(c0), u32(cn)};
    const uint32_t tv = gemm_tv_;
    const std::string gemm = texel ? "winograd_gemm_texel" : shader("winograd_gemm");
    cs.dispatch(kernel_pipeline(ctx_, gemm, {u32(gemm_cob_), c0 > 0 ? 1u : 0u, 1u, tv}, sizeof gp),
                {{vr, Access::read, f4}, {weight_gemm_.range(), Access::read, f4},
                 {mr, c0 > 0 ? Access::read_write : Access::write}},
                gp, flat_groups((gemm_cout_pad_ / gemm_cob_) * (pix_pad / (4 * tv)), 1),
                {name + "_gemm", r.info.flop * static_cast<double>(cn) / static_cast<double>(cin_),
                 v_bytes + 4.0 * static_cast<double>(gemm_cout_pad_ * (c0 > 0 ? 2 : 1) * pix_pad)});
  }
  record_1x1_output(cs, r, mr, pix_pad, "_gemm");
}

void Conv2d::record_1x1_pack(CommandStream& cs, const Recording& r, const BufferRange& v, int64_t c0, int64_t cn,
                             int64_t rows, int64_t pix_pad, const std::string& tag) const {
  const auto u32 = [](int64_t x) { return static_cast<uint32_t>(x); };
  const int64_t npix = r.is.n * r.is.h * r.is.w;
  const double v_bytes = static_cast<double>(elem_bytes()) * static_cast<double>(rows * pix_pad);
  struct PackPush {
    uint32_t in_off, in_bs, plane, npix, pix_pad, c_begin, c_valid;
  } pp{r.in.offset, r.in.batch_stride, u32(r.is.h * r.is.w), u32(npix), u32(pix_pad), u32(c0), u32(cn)};
  cs.dispatch(kernel_pipeline(ctx_, shader("conv1x1_pack"), {}, sizeof pp), {r.in.arg, {v, Access::write}}, pp,
              Groups{u32((pix_pad / 4 + 63) / 64), u32(rows), 1}, {r.info.name + tag + "_pack", 0, 2.0 * v_bytes});
}

void Conv2d::record_1x1_output(CommandStream& cs, const Recording& r, const BufferRange& m, int64_t pix_pad,
                               const std::string& tag) const {
  const auto u32 = [](int64_t x) { return static_cast<uint32_t>(x); };
  const int64_t npix = r.is.n * r.is.h * r.is.w;
  struct OutPush {
    uint32_t res_off, res_bs, out_off, out_bs, plane, npix, pix_pad;
  } op{r.res.offset, r.res.batch_stride, r.out.offset, r.out.batch_stride, u32(r.is.h * r.is.w), u32(npix), u32(pix_pad)};
  cs.dispatch(kernel_pipeline(ctx_, shader("conv1x1_output"), {r.spec[2], r.spec[3], r.spec[4]}, sizeof op),
              {{m, Access::read}, {bias_.range(), Access::read}, r.res.arg, r.out.arg}, op,
              Groups{u32((pix_pad / 4 + 63) / 64), u32(cout_), 1},
              {r.info.name + tag + "_out", 0, (4.0 + static_cast<double>(elem_bytes())) * static_cast<double>(r.os.count())});
}

}  // namespace vkunroll
