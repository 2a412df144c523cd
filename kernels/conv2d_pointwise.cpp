// conv2d, the pointwise algorithm (shaders/conv2d_pointwise.glsl): 1x1 stride-1 convs in one pass
// over the input slice per block of output channels and chunk of input channels, with the weights
// of the block in a uniform slab and the chunk's channel loop unrolled (constant weight indices).
#include <algorithm>

#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
// Input channels one dispatch unrolls at most: bounds the shader's size (and its compile time)
// while each extra chunk costs one more read and write of the block's output.
constexpr int64_t kPointwiseMaxChunk = 128;
}  // namespace

bool Conv2d::pointwise_applies() const {
  return params_.kernel == 1 && params_.stride == 1 && params_.pad == 0 && pointwise_chunks().chunk >= 1;
}

UniformSlabChunks Conv2d::pointwise_chunks() const {
  UniformSlabChunks c = uniform_slab_chunks(ctx_.info(), cin_, pointwise_cob_ * static_cast<int64_t>(elem_bytes()),
                                            pointwise_chunk_limit_);
  if (c.chunk < 1) return c;
  // Even chunks (the last one may be shorter by less than a quantum), none over the unroll cap.
  const int64_t cap = std::min(c.chunk, std::max(c.quantum, kPointwiseMaxChunk / c.quantum * c.quantum));
  const int64_t parts = (cin_ + cap - 1) / cap, even = (cin_ + parts - 1) / parts;
  c.chunk = std::min(cap, (even + c.quantum - 1) / c.quantum * c.quantum);
  return c;
}

void Conv2d::pack_pointwise() const {
  if (!weight_pointwise_.empty()) return;
  // [cout/COB][cin_pad][COB] (direct's layout at k = 1), plus one chunk of zeros at the end so that
  // every dispatch can bind a whole slab (the uniform block has a fixed size).
  const UniformSlabChunks ch = pointwise_chunks();
  weight_pointwise_ = upload_weights(pack_channel_blocks(pointwise_cob_, ch.cin_pad, ch.chunk));
}

void Conv2d::record_pointwise(CommandStream& cs, const Recording& r) const {
  pack_pointwise();
  const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
  const int64_t cob = pointwise_cob_, e = static_cast<int64_t>(elem_bytes());
  const UniformSlabChunks ch = pointwise_chunks();
  const int64_t chunk = ch.chunk, blocks = (cout_ + cob - 1) / cob, plane = r.is.h * r.is.w;
  const bool texel_input = texel_fits(r.in.arg.range.size, static_cast<uint64_t>(e));
  // Pixel pairs (one RG texel each) where no pair straddles two channels or batch items.
  const bool pairs = texel_input && pointwise_pairs_ && plane % 2 == 0 && r.in.offset % 2 == 0 &&
                     r.in.batch_stride % 2 == 0 && r.in.arg.range.size % static_cast<uint64_t>(2 * e) == 0;
  const int64_t units = pairs ? plane / 2 : plane;
  const int64_t g = (units + 64 * pointwise_px_ - 1) / (64 * pointwise_px_), gx = std::min<int64_t>(g, 65535);
  const Groups groups{u32(gx), u32((g + gx - 1) / gx), u32(r.os.n)};
  Arg input = r.in.arg;
  if (precision_ == Precision::fp16) input.texel_format = pairs ? VK_FORMAT_R16G16_SFLOAT : VK_FORMAT_R16_SFLOAT;
  else if (pairs) input.texel_format = VK_FORMAT_R32G32_SFLOAT;
  const char* base = pairs ? "conv2d_pointwise_pairs" : texel_input ? "conv2d_pointwise_texel" : "conv2d_pointwise";
  struct PointwisePush {
    uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs, plane, cout, co0;
  };
  const double px = static_cast<double>(r.os.n * plane);
  for (int64_t b = 0; b < blocks; ++b)
    for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
      const int64_t cn = std::min(chunk, cin_ - c0), nco = std::min(cob, cout_ - b * cob);
      const bool first = c0 == 0, last = c0 + chunk >= cin_;
      const int64_t slab_entries = (cn * cob * e + 15) / 16;
      const std::vector<uint32_t> spec{r.spec[2], r.spec[3],         r.spec[4],         pointwise_px_,    u32(cob),
                                       u32(cn),   first ? 1u : 0u, last ? 1u : 0u, u32(slab_entries)};
      const PointwisePush pp{u32(r.in.offset + c0 * plane), r.in.batch_stride, r.res.offset, r.res.batch_stride,
                             r.out.offset, r.out.batch_stride, u32(plane), u32(cout_), u32(b * cob)};
      const BufferRange wr = weight_pointwise_.range(static_cast<size_t>((b * ch.cin_pad + c0) * cob * e),
                                                     static_cast<size_t>(slab_entries) * 16);
      // Bytes: the chunk's input, the block's output (read back after the first chunk), the residual, the slab.
      const double bytes = static_cast<double>(e) * px *
                               static_cast<double>(cn + nco * (first ? 1 : 2) + (last && r.has_res ? nco : 0)) +
                           static_cast<double>(cn * cob * e);
      cs.dispatch(kernel_pipeline(ctx_, shader(base), spec, sizeof pp),
                  {input, {wr, Access::read}, {bias_.range(), Access::read}, r.res.arg,
                   {r.out.arg.range, first ? Access::write : Access::read_write}},
                  pp, groups,
                  {r.info.name, r.info.flop * static_cast<double>(cn * nco) / static_cast<double>(cin_ * cout_), bytes});
    }
}

}  // namespace vkunroll
