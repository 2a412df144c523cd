#include "vkunroll/host/model/model.hpp"

#include <algorithm>
#include <cmath>
#include <ostream>
#include <set>
#include <tuple>

#include "vkunroll/base/int_math.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {

// The padded size of n (even) input rows or columns with `before` / `after` pads (UnetPadding).
int64_t unet_padded(int64_t n, int before, int after) {
  if (before < 0) return round_up(n, 32);
  if (after < 0) return round_up(n + before, 32);
  return n + before + after;
}

BufferSlice whole(Backend& b, int buf) {
  const Shape s = b.shape(buf);
  return {buf, 0, s.n, 0, s.c};
}
BufferSlice items(Backend& b, int buf, int64_t n0, int64_t n) {
  const Shape s = b.shape(buf);
  return {buf, n0, n, 0, s.c};
}
BufferSlice chans(const BufferSlice& v, int64_t c0, int64_t c) { return {v.buf, v.n0, v.n, v.c0 + c0, c}; }
BufferSlice sub(const BufferSlice& v, int64_t i0, int64_t n) { return {v.buf, v.n0 + i0, n, v.c0, v.c}; }

// A host input's values: as many as its shape says, all finite. NaN/Inf would spread through every
// conv and come out as a NaN image; name the first bad value instead (one pass, negligible).
void check_values(const HostTensor& a, const char* name) {
  if (static_cast<int64_t>(a.data.size()) != a.shape.count())
    throw DataError(std::string("model input '") + name + "' holds " + std::to_string(a.data.size()) + " values for shape " +
                a.shape.str());
  const int64_t plane = a.shape.h * a.shape.w, item = a.shape.c * plane;
  for (size_t i = 0; i < a.data.size(); ++i)
    if (!std::isfinite(a.data[i])) {
      const int64_t k = static_cast<int64_t>(i);
      throw DataError(std::string("model input '") + name + "' holds " + (std::isnan(a.data[i]) ? "NaN" : "an infinite value") +
                  " at (batch " + std::to_string(k / item) + ", channel " + std::to_string(k % item / plane) + ", y " +
                  std::to_string(k % plane / a.shape.w) + ", x " + std::to_string(k % a.shape.w) +
                  "); inputs must be finite");
    }
}

}  // namespace

struct Model::Chunk {
  int64_t n = 0, nt = 0;  // batch items; targets (M)
  int64_t he = 0, we = 0; // even working size
  UnetPadding pad;  // RunOptions::unet_pad
  BufferSlice rs, ev1, ev2, ev3, phys;  // inputs: slices of the caller's buffers, or even-size copies
  int E = -1, sys = -1, flow = -1, warped = -1, fused = -1, m = -1, out = -1;
};

const char* output_name(ModelOutput o) {
  switch (o) {
    case ModelOutput::sys: return "sys";
    case ModelOutput::E: return "E";
    case ModelOutput::flow: return "flow";
    case ModelOutput::warped: return "warped";
    case ModelOutput::fused: return "fused";
    case ModelOutput::m: return "m";
    case ModelOutput::out: return "out";
  }
  return "?";
}

std::ostream& operator<<(std::ostream& os, ModelOutput o) { return os << output_name(o); }

ModelOutput parse_output(const std::string& name) {
  for (ModelOutput o : kModelOutputs)
    if (name == output_name(o)) return o;
  const std::string expected = "expected sys, E, flow, warped, fused, m, out";
  throw OptionError("outputs", "'" + name.substr(0, 64) + "'", expected,
                    opt("outputs") + ": unknown output '" + name.substr(0, 64) + "' (" + expected + ")");
}

void Model::add_conv(const Weights& w, const ConvDesc& desc) {
  const int id = backend_.prepare_conv(desc, w.get(desc.name + ".weight"), w.get(desc.name + ".bias"));
  convs_[desc.name] = Conv{id, desc};
}

void Model::add_unet(const Weights& w, const std::string& p, int cin, int cout, const UnetConfig& u) {
  const float s = cfg_.unet_slope;
  add_conv(w, {.name = p + ".head", .cin = cin, .cout = u.base});
  auto res = [&](const std::string& q, int c) {
    add_conv(w, {.name = q + ".conv.0.0", .cin = c, .cout = c, .leaky = true, .slope = s});
    add_conv(w, {.name = q + ".conv.1", .cin = c, .cout = c});
  };
  for (int i = 0; i < u.depth; ++i) {
    const int c = u.base << i;
    const std::string d = p + ".down_path." + std::to_string(i);
    res(d + ".conv1", c);
    add_conv(w, {.name = d + ".conv2.0", .cin = c, .cout = c, .k = 1, .pad = 0, .leaky = true, .slope = s});
    add_conv(w, {.name = d + ".down.0", .cin = c, .cout = 2 * c, .stride = 2, .leaky = true, .slope = s});
  }
  res(p + ".bottom.0", u.base << u.depth);
  res(p + ".bottom.1", u.base << u.depth);
  for (int i = 0; i < u.depth; ++i) {
    const int c = u.base << i;
    const std::string q = p + ".up_path." + std::to_string(i);
    add_conv(w, {.name = q + ".deconv.0", .cin = 2 * c, .cout = c, .k = 4, .stride = 2, .transposed = true, .leaky = true, .slope = s});
    add_conv(w, {.name = q + ".conv_skip.0", .cin = c, .cout = c, .k = 1, .pad = 0, .leaky = true, .slope = s});
    add_conv(w, {.name = q + ".conv1.0", .cin = 2 * c, .cout = c, .leaky = true, .slope = s});
    res(q + ".conv2", c);
  }
  add_conv(w, {.name = p + ".pred", .cin = u.base, .cout = cout});
}

Model::Model(Backend& backend, const Weights& w) : backend_(backend), cfg_(w.config) {
  cfg_.validate();
  add_conv(w, {.name = "SFENet1", .cin = 4 * cfg_.synthesis_channels(), .cout = cfg_.G0, .k = 5, .pad = 2});
  add_conv(w, {.name = "SFENet2", .cin = cfg_.G0, .cout = cfg_.G0});
  for (int d = 0; d < cfg_.D; ++d) {
    const std::string p = "RDBs." + std::to_string(d);
    for (int c = 0; c < cfg_.C; ++c)
      add_conv(w, {.name = p + ".convs." + std::to_string(c) + ".conv.0", .cin = cfg_.G0 + c * cfg_.G, .cout = cfg_.G,
                   .leaky = true, .slope = cfg_.rdb_slope});
    add_conv(w, {.name = p + ".LFF", .cin = cfg_.G0 + cfg_.C * cfg_.G, .cout = cfg_.G0, .k = 1, .pad = 0});
  }
  // GFF.0 (1x1 over the D block outputs) as D partial 1x1 convs accumulated block by block, so the
  // D * G0-channel concatenation never exists (it is 82 MiB per frame at 346x260 and above the
  // 128 MiB binding limit of lavapipe at 640x360).
  const WeightTensor& gw = w.get("GFF.0.weight");
  const WeightTensor& gb = w.get("GFF.0.bias");
  for (int d = 0; d < cfg_.D; ++d) {
    WeightTensor pw{{cfg_.G0, cfg_.G0, 1, 1}, std::vector<float>(size_t(cfg_.G0) * cfg_.G0)};
    for (int co = 0; co < cfg_.G0; ++co)
      for (int ci = 0; ci < cfg_.G0; ++ci)
        pw.data[size_t(co) * cfg_.G0 + ci] = gw.data[size_t(co) * cfg_.D * cfg_.G0 + size_t(d) * cfg_.G0 + ci];
    WeightTensor pb{{cfg_.G0}, d == 0 ? gb.data : std::vector<float>(size_t(cfg_.G0), 0.f)};
    const std::string name = "GFF.0.part" + std::to_string(d);
    const ConvDesc desc{.name = name, .cin = cfg_.G0, .cout = cfg_.G0, .k = 1, .pad = 0};
    convs_[name] = Conv{backend_.prepare_conv(desc, pw, pb), desc};
  }
  add_conv(w, {.name = "GFF.1", .cin = cfg_.G0, .cout = cfg_.G0});
  add_conv(w, {.name = "UPNet.0", .cin = cfg_.G0, .cout = cfg_.upnet_width});
  add_conv(w, {.name = "UPNet.2", .cin = cfg_.upnet_width / 4, .cout = 3});
  add_unet(w, "flownet", cfg_.flownet_input_channels(), 2, cfg_.flownet);
  add_unet(w, "fusion_net", cfg_.fusion_input_channels(), cfg_.fusion_channels(), cfg_.fusion_net);
  if (cfg_.moa) add_unet(w, "attfusion_net", cfg_.attfusion_input_channels(), 1, cfg_.attfusion_net);
  if (cfg_.physics_gate >= 0) add_physics_gate();
}

// The event gate's two box sums, one per event tensor, as convs with fixed weights: score =
// 6 * (events of ev1 and ev2 in the (2r+1)^2 square) - 3, so hardsigmoid(score) = clamp(count, 0, 1)
// and the gate is the MOA's blend op.
void Model::add_physics_gate() {
  const int r = cfg_.physics_gate, k = 2 * r + 1, ev = cfg_.ev_channels();
  WeightTensor weight{{1, ev, k, k}, std::vector<float>(size_t(ev) * k * k, 6.f)};
  for (const auto& [name, bias] : {std::pair{"physics_gate.ev1", -3.f}, {"physics_gate.ev2", 0.f}}) {
    const ConvDesc d{.name = name, .cin = ev, .cout = 1, .k = k, .pad = r};
    convs_[name] = Conv{backend_.prepare_conv(d, weight, WeightTensor{{1}, {bias}}), d};
  }
}

std::vector<ModelOutput> Model::resolve_outputs(const std::vector<ModelOutput>& requested, Mode mode) {
  const bool m_mode = mode == Mode::m;
  std::vector<ModelOutput> outs;
  if (requested.empty()) {
    for (ModelOutput o : kModelOutputs)
      if (m_mode || !per_target(o)) outs.push_back(o);
    return outs;
  }
  for (ModelOutput o : requested) {
    if (!m_mode && per_target(o))
      throw OptionError("outputs", output_name(o), "mode m only", opt("outputs") + ": output '" + output_name(o) + "' exists in mode m only");
    if (std::find(outs.begin(), outs.end(), o) == outs.end()) outs.push_back(o);
  }
  return outs;
}

const Model::Conv& Model::conv(const std::string& name) const {
  auto it = convs_.find(name);
  if (it == convs_.end()) throw UsageError("model: no layer '" + name + "'");
  return it->second;
}

// ---- sizes -----------------------------------------------------------------------------------

int64_t Model::synthesis_item_bytes(int64_t he, int64_t we) const {
  const int64_t plane = (he / 2) * (we / 2);
  return 4 * std::max({int64_t(cfg_.G0 + cfg_.C * cfg_.G) * plane, 4 * int64_t(cfg_.synthesis_channels()) * plane,  // RDB, s2d
                       int64_t(cfg_.upnet_width) * plane});
}

int64_t Model::unet_item_bytes(const UnetConfig& u, int cin, int64_t he, int64_t we, const UnetPadding& pad) const {
  const int64_t plane = unet_padded(he, pad.top, pad.bottom) * unet_padded(we, pad.left, pad.right);
  return 4 * plane * std::max<int64_t>(cin, 2 * u.base);
}

int Model::sub_items(int64_t item_bytes, uint64_t memory_budget) const {
  const int64_t limit = static_cast<int64_t>(backend_.max_buffer_bytes());
  if (item_bytes > limit)
    throw DataError("model: one batch item needs a " + std::to_string(item_bytes >> 20) + " MiB buffer, above the device's " +
                std::to_string(limit >> 20) + " MiB storage-buffer limit; use a smaller image");
  int64_t n = limit / item_bytes;
  // A stage holds about three buffers of its largest size at once.
  if (memory_budget) n = std::min<int64_t>(n, int64_t(memory_budget) / (3 * item_bytes));
  return static_cast<int>(std::max<int64_t>(1, n));
}

int Model::items_per_chunk(int64_t h, int64_t w, Mode mode, uint64_t memory_budget) const {
  const int64_t he = round_up(h, 2), we = round_up(w, 2);
  // Per item the whole-chunk buffers (inputs and outputs) and the largest working set of a stage.
  const int64_t ev = cfg_.ev_channels();
  const int64_t plane = he * we * 4;
  // The chunk's inputs and its outputs (m and out: one per target, half an item each).
  int64_t output_planes = 0, target_planes = 0;
  for (ModelOutput o : resolve_outputs({}, mode)) (per_target(o) ? target_planes : output_planes) += output_channels(o);
  const int64_t persistent = plane * (cfg_.synthesis_channels() + output_planes + target_planes / 2);
  const int64_t limit = static_cast<int64_t>(backend_.max_buffer_bytes());
  int64_t per_item = std::max<int64_t>(1, plane * ev);  // the largest whole-chunk buffer must fit one binding
  int64_t n = std::max<int64_t>(1, limit / per_item);
  if (memory_budget) {
    // A stage's working set is about 3x its largest buffer (see docs/model.md, memory plan).
    const int64_t work = 3 * std::max({synthesis_item_bytes(he, we),
                                       unet_item_bytes(cfg_.flownet, cfg_.flownet_input_channels(), he, we, UnetPadding{}),
                                       unet_item_bytes(cfg_.fusion_net, cfg_.fusion_input_channels(), he, we, UnetPadding{})});
    n = std::max<int64_t>(1, std::min<int64_t>(n, (int64_t(memory_budget) - work) / std::max<int64_t>(1, persistent)));
  }
  if (mode == Mode::m) n = std::max<int64_t>(2, n & ~int64_t(1));
  return static_cast<int>(std::min<int64_t>(n, 1 << 20));
}

int64_t Model::item_buffer_bytes(int64_t h, int64_t w, Mode mode, const UnetPadding& pad) const {
  const int64_t he = round_up(h, 2), we = round_up(w, 2), ev = cfg_.ev_channels();
  int64_t b = std::max({4 * he * we * ev, synthesis_item_bytes(he, we),
                        unet_item_bytes(cfg_.flownet, cfg_.flownet_input_channels(), he, we, pad),
                        unet_item_bytes(cfg_.fusion_net, cfg_.fusion_input_channels(), he, we, pad)});
  if (mode == Mode::m && cfg_.moa)
    b = std::max(b, unet_item_bytes(cfg_.attfusion_net, cfg_.attfusion_input_channels(), he, we, pad));
  return b;
}

int64_t Model::unet_stride() const {
  int depth = std::max(cfg_.flownet.depth, cfg_.fusion_net.depth);
  if (cfg_.moa) depth = std::max(depth, cfg_.attfusion_net.depth);
  return int64_t(1) << depth;
}

// ---- stages ----------------------------------------------------------------------------------

Buffer Model::resblock(const std::string& p, Buffer x) {
  Backend& b = backend_;
  const Shape s = x.shape();
  Buffer t = b.alloc(s, p + ".conv.0");
  b.conv(conv(p + ".conv.0.0").id, x.whole(), t.whole(), nullptr);
  Buffer y = b.alloc(s, p);
  const BufferSlice res = x.whole();
  b.conv(conv(p + ".conv.1").id, t.whole(), y.whole(), &res);
  t.reset();
  x.reset();
  return y;
}

void Model::unet(const std::string& p, const UnetConfig& u, const std::vector<BufferSlice>& pieces, const BufferSlice& out,
                 const UnetPadding& pad, float out_tanh_scale) {
  Backend& b = backend_;
  const Shape s0 = b.shape(pieces.at(0).buf);
  const int64_t n = pieces[0].n, h = s0.h, w = s0.w;
  // Size adapter: reflection pad to multiples of 32, the odd remainder at the bottom/right (or as
  // RunOptions::unet_pad says: tiles, host/model/tiled_run.cpp).
  const int64_t hp = unet_padded(h, pad.top, pad.bottom), wp = unet_padded(w, pad.left, pad.right);
  const int top = pad.top >= 0 ? pad.top : static_cast<int>((hp - h) / 2);
  const int left = pad.left >= 0 ? pad.left : static_cast<int>((wp - w) / 2);
  // The pad and the pieces' concatenation fold into the head conv's reads (Backend::conv_folded).
  ConvFold padded;
  padded.map = InputMap::reflect_pad, padded.padded_h = hp, padded.padded_w = wp, padded.top = top, padded.left = left;
  Buffer x = b.alloc({n, u.base, hp, wp}, p + ".head");
  const Conv& head = conv(p + ".head");
  b.conv_folded(head.id, head.desc, pieces, padded, x.whole());
  std::vector<Buffer> skips;
  for (int i = 0; i < u.depth; ++i) {
    const std::string d = p + ".down_path." + std::to_string(i);
    const Shape s = x.shape();
    x = resblock(d + ".conv1", std::move(x));
    Buffer sk = b.alloc(s, d + ".skip");
    b.conv(conv(d + ".conv2.0").id, x.whole(), sk.whole(), nullptr);
    skips.push_back(std::move(sk));
    Buffer dn = b.alloc({n, s.c * 2, s.h / 2, s.w / 2}, d + ".down");
    b.conv(conv(d + ".down.0").id, x.whole(), dn.whole(), nullptr);
    x = std::move(dn);  // releases the level's input
  }
  x = resblock(p + ".bottom.0", std::move(x));
  x = resblock(p + ".bottom.1", std::move(x));
  for (int i = u.depth - 1; i >= 0; --i) {
    const std::string q = p + ".up_path." + std::to_string(i);
    const Shape s = skips[i].shape();
    Buffer cat = b.alloc({n, 2 * s.c, s.h, s.w}, q + ".cat");
    b.conv(conv(q + ".deconv.0").id, x.whole(), chans(cat.whole(), 0, s.c), nullptr);
    x.reset();
    b.conv(conv(q + ".conv_skip.0").id, skips[i].whole(), chans(cat.whole(), s.c, s.c), nullptr);
    skips[i].reset();
    x = b.alloc(s, q + ".conv1");
    b.conv(conv(q + ".conv1.0").id, cat.whole(), x.whole(), nullptr);
    cat.reset();
    x = resblock(q + ".conv2", std::move(x));
  }
  // The crop back to h x w (and the flow's tanh) fold into the last conv's writes.
  ConvFold cropped;
  cropped.crop_top = top, cropped.crop_left = left, cropped.tanh_scale = out_tanh_scale;
  const Conv& pred = conv(p + ".pred");
  b.conv_folded(pred.id, pred.desc, {x.whole()}, cropped, out);
}

void Model::stage_synthesis(Chunk& ch, int64_t i0, int64_t n) {
  Backend& b = backend_;
  const int64_t h2 = ch.he / 2, w2 = ch.we / 2;
  // SFENet1 reads space_to_depth(cat(rs, ev1, ev2, ev3[, p])) through its folded input: input
  // channel c of a piece is channels 4c..4c+3 of the conv's input, and the 99-channel tensor never exists.
  // The variant: p = clamp(phys, 0, 1) is the last piece of E-IC_T's input and the base of sys.
  Buffer phys_clamped;
  std::vector<BufferSlice> pieces{sub(ch.rs, i0, n), sub(ch.ev1, i0, n), sub(ch.ev2, i0, n), sub(ch.ev3, i0, n)};
  if (cfg_.physics_input) {
    phys_clamped = b.alloc({n, 3, ch.he, ch.we}, "phys clamped");
    b.clamp01(sub(ch.phys, i0, n), phys_clamped.whole());
    pieces.push_back(phys_clamped.whole());
  }
  ConvFold s2d;
  s2d.map = InputMap::space_to_depth;
  Buffer f1 = b.alloc({n, cfg_.G0, h2, w2}, "SFENet1");
  const Conv& sfenet1 = conv("SFENet1");
  b.conv_folded(sfenet1.id, sfenet1.desc, pieces, s2d, f1.whole());
  // Each block works in one buffer whose first G0 channels are its input and whose growing tail
  // holds its convs' outputs; LFF (+ block input) writes the block output to a G0-channel buffer,
  // GFF.0 accumulates it, and it is copied back into the head of the block buffer for the next
  // block. Only one block buffer and two G0-channel accumulators are live.
  Buffer blk = b.alloc({n, cfg_.G0 + int64_t(cfg_.C) * cfg_.G, h2, w2}, "RDB");
  Buffer block_out = b.alloc({n, cfg_.G0, h2, w2}, "RDB output");
  Buffer acc = b.alloc({n, cfg_.G0, h2, w2}, "GFF.0");
  Buffer acc2 = b.alloc({n, cfg_.G0, h2, w2}, "GFF.0");
  b.conv(conv("SFENet2").id, f1.whole(), chans(blk.whole(), 0, cfg_.G0), nullptr);
  for (int d = 0; d < cfg_.D; ++d) {
    const std::string p = "RDBs." + std::to_string(d);
    b.begin_dense_block(cfg_.G0 + int64_t(cfg_.C - 1) * cfg_.G);  // conv c reads the first G0 + c G channels
    for (int c = 0; c < cfg_.C; ++c)
      b.conv(conv(p + ".convs." + std::to_string(c) + ".conv.0").id, chans(blk.whole(), 0, cfg_.G0 + c * cfg_.G),
             chans(blk.whole(), cfg_.G0 + c * cfg_.G, cfg_.G), nullptr);
    b.end_dense_block();
    const BufferSlice res = chans(blk.whole(), 0, cfg_.G0);
    b.conv(conv(p + ".LFF").id, blk.whole(), block_out.whole(), &res);
    const BufferSlice prev = acc.whole();
    b.conv(conv("GFF.0.part" + std::to_string(d)).id, block_out.whole(), acc2.whole(), d ? &prev : nullptr);
    std::swap(acc, acc2);
    if (d + 1 < cfg_.D) b.copy(block_out.whole(), chans(blk.whole(), 0, cfg_.G0));
  }
  blk.reset();
  block_out.reset();
  acc2.reset();
  Buffer g0 = std::move(acc);
  Buffer g = b.alloc({n, cfg_.G0, h2, w2}, "GFF.1");
  const BufferSlice f1v = f1.whole();
  b.conv(conv("GFF.1").id, g0.whole(), g.whole(), &f1v);
  g0.reset();
  f1.reset();
  Buffer up = b.alloc({n, cfg_.upnet_width, h2, w2}, "UPNet.0");
  b.conv(conv("UPNet.0").id, g.whole(), up.whole(), nullptr);
  g.reset();
  // UPNet.2 reads depth_to_space(up) and writes tanh of its output, both folded (Backend::conv_folded).
  ConvFold d2s;
  d2s.map = InputMap::depth_to_space, d2s.tanh_scale = 1.f;
  const Conv& upnet2 = conv("UPNet.2");
  b.conv_folded(upnet2.id, upnet2.desc, {up.whole()}, d2s, items(b, ch.E, i0, n));
  up.reset();
  b.add(phys_clamped ? phys_clamped.whole() : sub(ch.rs, i0, n), items(b, ch.E, i0, n), items(b, ch.sys, i0, n));
}

void Model::stage_flow(Chunk& ch, int64_t i0, int64_t n) {
  Backend& b = backend_;
  unet("flownet", cfg_.flownet, {sub(ch.ev1, i0, n), sub(ch.ev2, i0, n), sub(ch.rs, i0, n)},
       items(b, ch.flow, i0, n), ch.pad, 100.f);
  b.backward_warp(sub(ch.rs, i0, n), items(b, ch.flow, i0, n), items(b, ch.warped, i0, n));
}

void Model::stage_fusion(Chunk& ch, int64_t i0, int64_t n) {
  Backend& b = backend_;
  const bool gated = cfg_.physics_gate >= 0, confident = cfg_.physics_confidence;
  Buffer raw = gated || confident ? b.alloc({n, cfg_.fusion_channels(), ch.he, ch.we}, "fusion_net output") : Buffer();
  unet("fusion_net", cfg_.fusion_net,
       {items(b, ch.sys, i0, n), items(b, ch.warped, i0, n), items(b, ch.flow, i0, n), sub(ch.ev3, i0, n),
        sub(ch.rs, i0, n)},
       raw ? raw.whole() : items(b, ch.fused, i0, n), ch.pad);
  if (!raw) return;
  const Shape plane{n, 1, ch.he, ch.we};
  Buffer phys = b.alloc({n, 3, ch.he, ch.we}, "phys clamped");
  b.clamp01(sub(ch.phys, i0, n), phys.whole());
  // The learned confidence: trusted = c * fusion_net + (1 - c) * clamp(phys, 0, 1).
  Buffer trusted;
  if (confident) {
    trusted = gated ? b.alloc({n, 3, ch.he, ch.we}, "fusion confidence blend") : Buffer();
    Buffer c = b.alloc(plane, "fusion confidence");
    b.hardsigmoid_blend(chans(raw.whole(), 3, 1), chans(raw.whole(), 0, 3), phys.whole(), c.whole(),
                        gated ? trusted.whole() : items(b, ch.fused, i0, n), -1.f);
    if (!gated) return;
  }
  // fused = g * trusted + (1 - g) * clamp(phys, 0, 1), g = 1 where an ev1/ev2 event is near.
  Buffer part = b.alloc(plane, "physics gate ev1");
  b.conv(conv("physics_gate.ev1").id, sub(ch.ev1, i0, n), part.whole(), nullptr);
  Buffer score = b.alloc(plane, "physics gate");
  const BufferSlice ev1_part = part.whole();
  b.conv(conv("physics_gate.ev2").id, sub(ch.ev2, i0, n), score.whole(), &ev1_part);
  part.reset();
  Buffer g = b.alloc(plane, "physics gate m");
  b.hardsigmoid_blend(score.whole(), confident ? trusted.whole() : chans(raw.whole(), 0, 3), phys.whole(), g.whole(),
                      items(b, ch.fused, i0, n), -1.f);
}

void Model::stage_moa(Chunk& ch, int64_t t0, int64_t nt, float force_m) {
  Backend& b = backend_;
  const int64_t ev = cfg_.ev_channels();
  // Frames 1 and 2 of a target are batch items 2k and 2k+1: gather them into channel pieces.
  const int64_t cin = cfg_.attfusion_input_channels();
  Buffer gathered = b.alloc({nt, cin, ch.he, ch.we}, "attfusion_net.gather");
  for (int64_t k = 0; k < nt; ++k) {
    const int64_t f1 = 2 * (t0 + k), f2 = f1 + 1;
    const BufferSlice dst = gathered.items(k, 1);
    b.copy(items(b, ch.E, f1, 1), chans(dst, 0, 3));
    b.copy(items(b, ch.E, f2, 1), chans(dst, 3, 3));
    b.copy(sub(ch.ev1, f1, 1), chans(dst, 6, ev));
    b.copy(sub(ch.ev1, f2, 1), chans(dst, 6 + ev, ev));
    b.copy(items(b, ch.flow, f1, 1), chans(dst, 6 + 2 * ev, 2));
    b.copy(items(b, ch.flow, f2, 1), chans(dst, 8 + 2 * ev, 2));
  }
  Buffer score = b.alloc({nt, 1, ch.he, ch.we}, "attfusion_net");
  unet("attfusion_net", cfg_.attfusion_net, {gathered.whole()}, score.whole(), ch.pad);
  gathered.reset();
  for (int64_t k = 0; k < nt; ++k) {
    const int64_t f1 = 2 * (t0 + k);
    b.hardsigmoid_blend(score.items(k, 1), items(b, ch.fused, f1, 1), items(b, ch.fused, f1 + 1, 1),
                        items(b, ch.m, t0 + k, 1), items(b, ch.out, t0 + k, 1), force_m);
  }
}

// ---- run -------------------------------------------------------------------------------------

ModelBuffers Model::upload_inputs(const ModelInputs& in, int64_t c0, int64_t n, std::vector<Buffer>& owned) {
  const int64_t H = in.rs.shape.h, W = in.rs.shape.w;
  ModelBuffers buffers;
  for (const auto& [a, dst, name] : {std::tuple{&in.rs, &buffers.rs, "rs"}, std::tuple{&in.ev1, &buffers.ev1, "ev1"},
                                     std::tuple{&in.ev2, &buffers.ev2, "ev2"}, std::tuple{&in.ev3, &buffers.ev3, "ev3"},
                                     std::tuple{&in.phys, &buffers.phys, "phys"}}) {
    if (a == &in.phys && !cfg_.physics_input) continue;
    const int64_t item = a->shape.c * H * W;
    owned.push_back(backend_.alloc({n, a->shape.c, H, W}, name));
    *dst = owned.back().whole();
    backend_.upload(*dst, std::span<const float>(a->data.data() + c0 * item, size_t(n * item)));
  }
  return buffers;
}

// The inputs' extents as the checks see them: rs, ev1, ev2, ev3, phys (given: false for none).
struct Model::InputExtents {
  struct Input {
    const char* name;
    bool given;
    Shape shape;  // [items, channels, height, width] of the slice or tensor
  };
  Input rs, ev1, ev2, ev3, phys;
};

void Model::check_inputs(const InputExtents& in, const RunOptions& opt) const {
  if (opt.precision && *opt.precision != backend_.precision())
    throw UsageError(std::string("model run: precision ") + precision_name(*opt.precision) + " asked of the " + backend_.name() +
                " backend, which runs in " + precision_name(backend_.precision()) + " (choose it when creating the backend)");
  const Shape rs = in.rs.shape;
  const int64_t B = rs.n, H = rs.h, W = rs.w;
  if (rs.c != 3) throw DataError("model input 'rs' has shape " + rs.str() + ", expected 3 channels");
  if (B < 1 || H < 2 || W < 2) throw DataError("model input 'rs' has shape " + rs.str() + ", expected B >= 1, H and W >= 2");
  auto check = [&](const InputExtents::Input& v, int64_t c) {
    const Shape want{B, c, H, W};
    if (!(v.shape == want))
      throw DataError(std::string("model input '") + v.name + "' has shape " + v.shape.str() + ", expected " + want.str());
  };
  for (const auto* v : {&in.ev1, &in.ev2, &in.ev3}) check(*v, cfg_.ev_channels());
  if (cfg_.physics_input) {
    if (!in.phys.given) throw DataError("model input 'phys' (the physics estimate) is missing: the model is the physics-informed variant");
    check(in.phys, 3);
  } else if (in.phys.given) {
    throw DataError("model input 'phys' is given, but the model is not the physics-informed variant");
  }
  if (opt.mode == Mode::m && !cfg_.moa) throw UsageError("model has no attfusion_net (MOA) weights: SelfUnroll-S only (use mode s)");
  if (opt.mode == Mode::m && B % 2) throw DataError("SelfUnroll-M needs an even batch (frames 1 and 2 per target), got B = " + std::to_string(B));
}

std::map<ModelOutput, HostTensor> Model::run(const ModelInputs& in, const RunOptions& opt) {
  Backend& b = backend_;
  const int64_t B = in.rs.shape.n, H = in.rs.shape.h, W = in.rs.shape.w;
  check_inputs({{"rs", true, in.rs.shape}, {"ev1", true, in.ev1.shape}, {"ev2", true, in.ev2.shape}, {"ev3", true, in.ev3.shape},
                {"phys", !in.phys.data.empty(), in.phys.shape}},
               opt);
  for (const auto& [a, name] : {std::pair{&in.rs, "rs"}, {&in.ev1, "ev1"}, {&in.ev2, "ev2"}, {&in.ev3, "ev3"}, {&in.phys, "phys"}})
    if (a != &in.phys || cfg_.physics_input) check_values(*a, name);
  // Chunks of batch items, each uploaded, run and downloaded on its own: every input buffer stays
  // within the backend's binding limit (run_on_backend takes the inputs as they are).
  const bool m_mode = opt.mode == Mode::m;
  int64_t per_chunk = opt.max_items > 0 ? opt.max_items : items_per_chunk(H, W, opt.mode, opt.memory_budget);
  if (m_mode) per_chunk = std::max<int64_t>(2, per_chunk & ~int64_t(1));
  per_chunk = std::min(per_chunk, B);
  std::map<ModelOutput, HostTensor> result;
  for (int64_t c0 = 0; c0 < B; c0 += per_chunk) {
    const int64_t n = std::min(per_chunk, B - c0);
    std::vector<Buffer> uploaded;  // handed over: the run releases each after its last reader
    const ModelBuffers buffers = upload_inputs(in, c0, n, uploaded);
    RunOptions ro = opt;
    ro.max_items = static_cast<int>(n);
    const std::map<ModelOutput, Buffer> outs = run_on_backend(buffers, ro, std::move(uploaded));
    for (const auto& [o, buf] : outs) {
      const Shape s = buf.shape();
      HostTensor& t = result[o];
      const int64_t items = per_target(o) ? B / 2 : B, first = per_target(o) ? c0 / 2 : c0;
      if (t.data.empty()) t = HostTensor(Shape{items, s.c, s.h, s.w});
      b.download(buf.whole(), std::span<float>(t.data.data() + first * s.c * s.h * s.w, size_t(s.count())));
    }
    b.flush();
  }
  return result;
}

void Model::check_buffers(const ModelBuffers& in, const RunOptions& opt, const std::vector<Buffer>& handed_over) const {
  auto extent = [&](const BufferSlice& v, const char* name) {
    if (v.buf < 0) return InputExtents::Input{name, false, Shape{0, 0, 0, 0}};
    return InputExtents::Input{name, true, backend_.slice_shape(v)};
  };
  check_inputs({extent(in.rs, "rs"), extent(in.ev1, "ev1"), extent(in.ev2, "ev2"), extent(in.ev3, "ev3"), extent(in.phys, "phys")},
               opt);
  // A handed-over buffer is released after its input's last reader: no other input may read it.
  for (const Buffer& h : handed_over) {
    int readers = 0;
    for (const BufferSlice* v : {&in.rs, &in.ev1, &in.ev2, &in.ev3, &in.phys}) readers += h && v->buf == h.id();
    if (h && readers != 1)
      throw InternalError("model run: handed-over buffer " + std::to_string(h.id()) + " is the buffer of " + std::to_string(readers) +
                  " inputs, expected exactly one");
  }
}

struct Model::SubBatches {
  int synthesis = 1, flow = 1, fusion = 1, moa = 1;  // batch items per stage call (moa: targets)
};

Model::SubBatches Model::sub_batches(int64_t he, int64_t we, const RunOptions& opt) const {
  const uint64_t budget = opt.memory_budget;
  SubBatches sb;
  sb.synthesis = sub_items(synthesis_item_bytes(he, we), budget);
  check_unet_padding(opt.unet_pad, he, we);
  const UnetPadding& pad = opt.unet_pad;
  sb.flow = sub_items(unet_item_bytes(cfg_.flownet, cfg_.flownet_input_channels(), he, we, pad), budget);
  sb.fusion = sub_items(unet_item_bytes(cfg_.fusion_net, cfg_.fusion_input_channels(), he, we, pad), budget);
  if (opt.mode == Mode::m)
    sb.moa = sub_items(unet_item_bytes(cfg_.attfusion_net, cfg_.attfusion_input_channels(), he, we, pad), budget);
  return sb;
}

void Model::check_unet_padding(const UnetPadding& pad, int64_t he, int64_t we) const {
  const std::string what = "model: UNet padding (top " + std::to_string(pad.top) + ", bottom " + std::to_string(pad.bottom) + ", left " +
                           std::to_string(pad.left) + ", right " + std::to_string(pad.right) + ") of the " + std::to_string(we) + "x" +
                           std::to_string(he) + " input: ";
  auto axis = [&](int before, int after, int64_t n) {
    if (before >= n || after >= n) throw UsageError(what + "each pad must be smaller than the input (reflection padding)");
    if (before < 0 && after >= 0) throw UsageError(what + "an explicit bottom / right pad needs an explicit top / left one");
    if (after >= 0 && unet_padded(n, before, after) % unet_stride())
      throw UsageError(what + "the padded size " + std::to_string(unet_padded(n, before, after)) + " must be a multiple of the UNets' stride " +
                  std::to_string(unet_stride()));
  };
  axis(pad.top, pad.bottom, he);
  axis(pad.left, pad.right, we);
}

std::map<ModelOutput, Buffer> Model::run_on_backend(const ModelBuffers& in, const RunOptions& opt, std::vector<Buffer> handed_over) {
  Backend& b = backend_;
  check_buffers(in, opt, handed_over);
  const int64_t B = in.rs.n, H = b.shape(in.rs.buf).h, W = b.shape(in.rs.buf).w;
  const bool m_mode = opt.mode == Mode::m;
  const std::vector<ModelOutput> wanted = resolve_outputs(opt.outputs, opt.mode);
  const std::set<ModelOutput> want(wanted.begin(), wanted.end());
  const int64_t he = round_up(H, 2), we = round_up(W, 2);
  int64_t per_chunk = opt.max_items > 0 ? opt.max_items : items_per_chunk(H, W, opt.mode, opt.memory_budget);
  if (m_mode) per_chunk = std::max<int64_t>(2, per_chunk & ~int64_t(1));
  per_chunk = std::min(per_chunk, B);
  const SubBatches sb = sub_batches(he, we, opt);
  const int64_t K = m_mode ? B / 2 : 0;
  std::map<ModelOutput, Buffer> result;
  for (ModelOutput o : want) result[o] = b.alloc({per_target(o) ? K : B, output_channels(o), H, W}, output_name(o));
  for (int64_t c0 = 0; c0 < B; c0 += per_chunk) run_chunk(in, opt, want, c0, std::min(per_chunk, B - c0), sb, result, handed_over);
  return result;
}

namespace {
// Releases the handle of buffer `id` among `held` (none there: nothing).
void drop(std::vector<Buffer>& held, int id) {
  auto it = std::find_if(held.begin(), held.end(), [&](const Buffer& h) { return h && h.id() == id; });
  if (it != held.end()) held.erase(it);
}
}  // namespace

void Model::run_chunk(const ModelBuffers& in, const RunOptions& opt, const std::set<ModelOutput>& want, int64_t c0, int64_t n,
                      const SubBatches& sb, std::map<ModelOutput, Buffer>& result, std::vector<Buffer>& handed_over) {
  Backend& b = backend_;
  const int64_t B = in.rs.n, H = b.shape(in.rs.buf).h, W = b.shape(in.rs.buf).w;
  const bool m_mode = opt.mode == Mode::m;
  Chunk ch;
  ch.n = n;
  ch.nt = m_mode ? ch.n / 2 : 0;
  ch.he = round_up(H, 2);
  ch.we = round_up(W, 2);
  ch.pad = opt.unet_pad;
  // Inputs are read in place; at an odd size they are reflected by one row/column to even size.
  std::vector<Buffer> even_inputs;
  auto input = [&](const BufferSlice& v, const char* nme) {
    const BufferSlice part = sub(v, c0, ch.n);
    if (ch.he == H && ch.we == W) return part;
    even_inputs.push_back(b.alloc({ch.n, v.c, ch.he, ch.we}, std::string(nme) + ".even"));
    b.reflect_pad(part, even_inputs.back().whole(), 0, 0);
    return even_inputs.back().whole();
  };
  ch.rs = input(in.rs, "rs");
  ch.ev1 = input(in.ev1, "ev1");
  ch.ev2 = input(in.ev2, "ev2");
  ch.ev3 = input(in.ev3, "ev3");
  if (cfg_.physics_input) ch.phys = input(in.phys, "phys");
  // One chunk at an even size computes straight into the outputs; otherwise into chunk buffers
  // that are cropped into them.
  const bool direct = ch.n == B && ch.he == H && ch.we == W;
  std::vector<Buffer> chunk_buffers;
  auto chunk_buffer = [&](ModelOutput o) {
    if (direct && want.count(o)) return result.at(o).id();
    chunk_buffers.push_back(b.alloc({per_target(o) ? ch.nt : ch.n, output_channels(o), ch.he, ch.we}, output_name(o)));
    return chunk_buffers.back().id();
  };
  ch.E = chunk_buffer(ModelOutput::E);
  ch.sys = chunk_buffer(ModelOutput::sys);
  ch.flow = chunk_buffer(ModelOutput::flow);
  ch.warped = chunk_buffer(ModelOutput::warped);
  ch.fused = chunk_buffer(ModelOutput::fused);
  // Stages are recorded back to back; the backend submits only where memory forces it.
  // GPU time is summed per stage (the paper's E-IC_T, E-IC_S, fusion, MOA); glue ops are "model".
  b.set_stage("model.eic_t");
  for (int64_t i = 0; i < ch.n; i += sb.synthesis) stage_synthesis(ch, i, std::min<int64_t>(sb.synthesis, ch.n - i));
  // Handed-over inputs go as soon as the last chunk has read them.
  const bool last = c0 + ch.n >= B;
  auto consumed = [&](const BufferSlice& chunk_view, const BufferSlice& given) {
    if (chunk_view.buf != given.buf) drop(even_inputs, chunk_view.buf);
    if (last) drop(handed_over, given.buf);
  };
  b.set_stage("model.eic_s");
  for (int64_t i = 0; i < ch.n; i += sb.flow) stage_flow(ch, i, std::min<int64_t>(sb.flow, ch.n - i));
  // ev2 and phys are read by E-IC_T and flownet, and by the variant's event gate and learned
  // confidence after fusion_net.
  const bool fusion_reads_phys = cfg_.physics_gate >= 0 || cfg_.physics_confidence;
  auto consumed_ev2_phys = [&] {
    consumed(ch.ev2, in.ev2);
    if (cfg_.physics_input) consumed(ch.phys, in.phys);
  };
  if (!fusion_reads_phys) consumed_ev2_phys();
  b.set_stage("model.fusion");
  for (int64_t i = 0; i < ch.n; i += sb.fusion) stage_fusion(ch, i, std::min<int64_t>(sb.fusion, ch.n - i));
  consumed(ch.ev3, in.ev3);
  if (fusion_reads_phys) consumed_ev2_phys();
  if (m_mode) {
    ch.m = chunk_buffer(ModelOutput::m);
    ch.out = chunk_buffer(ModelOutput::out);
    b.set_stage("model.moa");
    for (int64_t t = 0; t < ch.nt; t += sb.moa) stage_moa(ch, t, std::min<int64_t>(sb.moa, ch.nt - t), opt.force_m);
  }
  b.set_stage("model");
  // The chunk's results, cropped to H x W, into the outputs (the chunk buffers go with the chunk).
  auto keep = [&](ModelOutput o, int buf) {
    if (want.count(o) && buf != result.at(o).id())
      b.crop(whole(b, buf), result.at(o).items(per_target(o) ? c0 / 2 : c0, b.shape(buf).n), 0, 0);
  };
  keep(ModelOutput::sys, ch.sys);
  keep(ModelOutput::E, ch.E);
  keep(ModelOutput::flow, ch.flow);
  keep(ModelOutput::warped, ch.warped);
  keep(ModelOutput::fused, ch.fused);
  if (m_mode) {
    keep(ModelOutput::m, ch.m);
    keep(ModelOutput::out, ch.out);
  }
  if (last) handed_over.clear();
}

}  // namespace vkunroll
