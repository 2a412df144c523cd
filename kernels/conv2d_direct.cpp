// conv2d, the direct algorithm (shaders/conv2d_direct.glsl): weights in uniform slabs, one dispatch
// per block of output channels and chunk of input channels, the input through a texel buffer.
#include <algorithm>

#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

UniformSlabChunks Conv2d::direct_chunks() const {
  const int64_t per_channel = static_cast<int64_t>(params_.kernel) * params_.kernel * direct_cob_;
  return uniform_slab_chunks(ctx_.info(), cin_, per_channel * static_cast<int64_t>(elem_bytes()), direct_chunk_limit_);
}

std::vector<float> Conv2d::pack_channel_blocks(int64_t cob, int64_t cin_pad, int64_t tail_channels) const {
  const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel, blocks = (cout_ + cob - 1) / cob;
  // + 8 values: an fp16 slab is bound in whole 16-byte entries (8 halves), possibly 8 bytes past its end.
  std::vector<float> w(static_cast<size_t>((blocks * cin_pad + tail_channels) * kk * cob + 8), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t ci = 0; ci < cin_; ++ci)
      for (int64_t t = 0; t < kk; ++t)
        w[static_cast<size_t>((((co / cob) * cin_pad + ci) * kk + t) * cob + co % cob)] =
            weight_host_.data[static_cast<size_t>((co * cin_ + ci) * kk + t)];
  return w;
}

void Conv2d::pack_direct() const {
  if (!weight_direct_.empty()) return;
  // Each block's channels are padded to cin_pad so every chunk's slab starts aligned; one chunk of
  // zeros at the end so that every dispatch can bind a whole slab (the uniform block has a fixed size).
  const UniformSlabChunks ch = direct_chunks();
  weight_direct_ = upload_weights(pack_channel_blocks(direct_cob_, ch.cin_pad, ch.max));
}

void Conv2d::record_direct(CommandStream& cs, const Recording& r) const {
  pack_direct();
  const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
  const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel, cob = direct_cob_;
  const int64_t e = static_cast<int64_t>(elem_bytes());
  const UniformSlabChunks ch = direct_chunks();
  const int64_t chunk = ch.chunk, blocks = (cout_ + cob - 1) / cob;
  // The slab in whole 16-byte uniform entries (vec4s in fp32, 8 halves each in fp16).
  const int64_t slab_entries = (chunk * kk * cob * e + 15) / 16;
  const size_t slab_bytes = static_cast<size_t>(slab_entries) * 16;
  // A 1x1 stride-1 conv without padding is one row of H*W pixels per channel plane.
  const bool flat = params_.kernel == 1 && params_.stride == 1 && params_.pad == 0;
  Push dp = r.push;
  if (flat) {
    dp.h = dp.oh = 1;
    dp.w = dp.ow = u32(r.is.h * r.is.w);
  }
  const int64_t px = direct_px_, py = flat ? 1 : direct_py_;
  const int64_t tasks = ((dp.oh + py - 1) / py) * ((dp.ow + px - 1) / px);
  const int64_t g = (tasks + 15) / 16, gx = std::min<int64_t>(g, 65535);
  const Groups groups{u32(gx), u32((g + gx - 1) / gx), u32(r.os.n)};
  const bool texel_input = texel_fits(r.in.arg.range.size, static_cast<uint64_t>(e));
  const Arg input = input_texel_arg(r);
  for (int64_t b = 0; b < blocks; ++b)
    for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
      const bool first = c0 == 0, last = c0 + chunk >= cin_;
      std::vector<uint32_t> dspec = r.spec;
      dspec.insert(dspec.end(), {direct_px_, u32(cob / 4), first ? 1u : 0u, last ? 1u : 0u, u32(slab_entries), u32(py),
                                 u32(cob == 4 ? std::min<int64_t>(4, cout_ - b * cob) : 4)});
      Push cp = dp;
      cp.in_off = u32(r.in.offset + c0 * r.is.h * r.is.w);
      cp.cin = u32(std::min(chunk, cin_ - c0));
      cp.pad = params_.pad;
      cp.co0 = u32(b * cob);
      const BufferRange wr = weight_direct_.range(static_cast<size_t>((b * ch.cin_pad + c0) * kk * cob * e), slab_bytes);
      cs.dispatch(kernel_pipeline(ctx_, shader(texel_input ? "conv2d_direct_texel" : "conv2d_direct"), dspec, sizeof(Push)),
                  {input, {wr, Access::read}, {bias_.range(), Access::read}, r.res.arg,
                   {r.out.arg.range, first ? Access::write : Access::read_write}},
                  cp, groups, dispatch_part(r.info, cp.cin, std::min(cob, cout_ - b * cob), cin_, cout_, blocks));
    }
}

}  // namespace vkunroll
