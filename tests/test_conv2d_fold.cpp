// Folded convs (ConvFold: input pieces concatenated, reflection-padded or space-to-depth; output
// cropped, tanh-scaled) in the GPU family against the composed CPU reference: both precisions, the
// scalar tiles, split-K and the emulated cooperative matrices, with canaries around the output.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
struct FoldCase {
  std::string what;
  int k, s;
  std::vector<int64_t> piece_channels;
  int64_t cout, h, w, batch;
  ConvFold fold;
  Act act;
  bool residual = false;
  int64_t out_h = 0, out_w = 0;  // the output slice (0: the conv's whole output)
};

ConvFold d2s_tanh(ConvFold f) {
  f.tanh_scale = 1.f;
  return f;
}

std::vector<FoldCase> cases() {
  ConvFold unet;  // the size adapter: 13x10 padded to 32x16, the odd remainder bottom/right
  unet.map = InputMap::reflect_pad, unet.padded_h = 32, unet.padded_w = 16, unet.top = 9, unet.left = 3;
  ConvFold pred;  // the UNet's last conv: cropped back, the flow's 100 tanh
  pred.crop_top = 9, pred.crop_left = 3, pred.tanh_scale = 100.f;
  ConvFold crop_only = pred;
  crop_only.tanh_scale = 0;
  ConvFold s2d;
  s2d.map = InputMap::space_to_depth;
  ConvFold d2s;
  d2s.map = InputMap::depth_to_space;
  ConvFold wide_pad = unet;  // a pad larger than the image keeps reflecting (3x2 to 16x16)
  wide_pad.padded_h = 16, wide_pad.padded_w = 16, wide_pad.top = 6, wide_pad.left = 7;
  return {
      {"unet head: 3 pieces reflect-padded", 3, 1, {2, 5, 3}, 8, 13, 10, 2, unet, Act{}},
      {"5 pieces reflect-padded, residual", 3, 1, {3, 3, 2, 4, 3}, 6, 13, 10, 1, unet, leaky_relu(0.1f), true},
      {"pad past the image", 3, 1, {2, 1}, 5, 3, 2, 1, wide_pad, Act{}},
      {"pred: crop and 100 tanh", 3, 1, {8}, 2, 32, 16, 2, pred, Act{}, false, 13, 10},
      {"crop with a residual", 3, 1, {8}, 3, 32, 16, 1, crop_only, leaky_relu(0.1f), true, 13, 10},
      {"sfenet1: 5 pieces space-to-depth, 5x5", 5, 1, {3, 4, 4, 4, 3}, 24, 12, 10, 2, s2d, Act{}},
      {"upnet.2: depth-to-space, tanh", 3, 1, {16}, 3, 6, 5, 2, d2s_tanh(d2s), Act{}},
      {"concatenation only, stride 2", 3, 2, {4, 6}, 9, 11, 9, 1, ConvFold{}, leaky_relu(0.1f)},
  };
}

optest::OpCase fold_case(const FoldCase& c, ConvAlgo algo, int splits, bool emulated, std::mt19937& rng) {
  int64_t cin = 0;
  for (int64_t pc : c.piece_channels) cin += c.fold.piece_channels(pc);
  const Conv2dParams p{c.k, c.s, c.k / 2, c.act};
  const float ws = 1.f / std::sqrt(static_cast<float>(cin * c.k * c.k));
  const HostTensor w = random_tensor({c.cout, cin, c.k, c.k}, rng, -ws, ws), b = random_tensor({1, 1, 1, c.cout}, rng, -0.5f, 0.5f);
  std::vector<Shape> shapes;
  for (int64_t pc : c.piece_channels) shapes.push_back({c.batch, pc, c.h, c.w});
  const Shape is = c.fold.conv_input(shapes, "case");
  const int64_t oh = conv_output_size(is.h, c.k, c.s, c.k / 2), ow = conv_output_size(is.w, c.k, c.s, c.k / 2);
  const Shape os{c.batch, c.cout, c.out_h ? c.out_h : oh, c.out_w ? c.out_w : ow};
  optest::OpCase k;
  k.what = c.what;
  for (const Shape& s : shapes) k.inputs.push_back(random_tensor({s.n, s.c + 1, s.h, s.w}, rng));  // + 1: a slice at channel 1
  k.inputs.push_back(random_tensor(os, rng));
  k.outputs = {{os, 1, 2, c.fold.tanh_scale > 0 ? c.fold.tanh_scale : 1.0}};
  const size_t np = shapes.size();
  k.reference = [c, w, b, p, np](optest::HostRun& r) {
    std::vector<HostSlice> pieces;
    for (size_t i = 0; i < np; ++i) pieces.emplace_back(r.inputs[i], 1, c.piece_channels[i]);
    conv2d_folded_ref(pieces, c.fold, r.out(0), w, b, p, c.residual ? std::optional<HostSlice>(HostSlice(r.inputs[np])) : std::nullopt);
  };
  k.record = [c, w, b, p, np, algo, splits, emulated](optest::DeviceRun& d) {
    ConvOptions o;
    o.precision = d.precision;
    auto conv = std::make_shared<Conv2d>(d.ctx, w, b, p, "folded", nullptr, o);
    conv->set_igemm_splits(splits);
    if (emulated) conv->set_coopmat_emulation(true);
    if (!conv->supports(algo)) return false;
    std::vector<Slice> pieces;
    for (size_t i = 0; i < np; ++i) pieces.emplace_back(d.inputs[i], 1, c.piece_channels[i]);
    conv->record_folded(d.stream, pieces, c.fold, d.out(0), c.residual ? std::optional<Slice>(Slice(d.inputs[np])) : std::nullopt, algo);
    EXPECT_EQ(d.stream.recorded(), splits > 1 ? 2u : 1u) << c.what;  // one dispatch (split-K: and its reduce)
    d.keep_alive = conv;
    return true;
  };
  return k;
}

void run(ConvAlgo algo, int splits = 0, bool emulated = false, std::vector<Precision> precisions = {Precision::fp32, Precision::fp16}) {
  std::mt19937 rng(17);
  optest::OpTest test{std::string("conv2d folded ") + conv_algo_name(algo) + (splits > 1 ? " split-K" : "") +
                          (emulated ? " emulated" : ""),
                      {}, {1e-4, 1e-2, true}, precisions};
  for (const FoldCase& c : cases()) test.cases.push_back(fold_case(c, algo, splits, emulated, rng));
  optest::run_op_test(vktest::context(), test);
}
}  // namespace

TEST(Conv2dFold, IgemmMatchesTheComposedReference) {
  run(ConvAlgo::igemm_m);
  run(ConvAlgo::igemm_n, 0, false, {Precision::fp32});
}

TEST(Conv2dFold, SplitKMatchesTheComposedReference) { run(ConvAlgo::igemm_s, 2); }

TEST(Conv2dFold, EmulatedCoopmatMatchesTheComposedReference) {
  run(ConvAlgo::coopmat, 0, true, {Precision::fp16});
}

TEST(Conv2dFold, RefusesWhatItCannotFold) {
  Context& ctx = vktest::context();
  std::mt19937 rng(3);
  Conv2d conv(ctx, random_tensor({4, 6, 3, 3}, rng), HostTensor(), {3, 1, 1, leaky_relu(0.1f)}, "c");
  Tensor a(ctx, {1, 3, 8, 8}), b(ctx, {1, 3, 8, 6}), y(ctx, {1, 4, 8, 8});
  CommandStream cs(ctx);
  ConvFold none;
  try {
    conv.record_folded(cs, {Slice(a), Slice(b)}, none, Slice(y));
    ADD_FAILURE() << "pieces of different widths folded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("input piece 1 is"), std::string::npos) << e.what();
  }
  Tensor b8(ctx, {1, 3, 8, 8});
  EXPECT_THROW(conv.record_folded(cs, {Slice(a), Slice(b8)}, none, Slice(y), std::nullopt, ConvAlgo::winograd), Error);
  ConvFold tanh;
  tanh.tanh_scale = 1.f;  // the conv has its own activation
  EXPECT_THROW(conv.record_folded(cs, {Slice(a), Slice(b8)}, tanh, Slice(y)), Error);
  ConvFold pad;
  pad.map = InputMap::reflect_pad, pad.padded_h = 8, pad.padded_w = 8, pad.top = 1;  // the input would not fit
  EXPECT_THROW(conv.record_folded(cs, {Slice(a), Slice(b8)}, pad, Slice(y)), Error);
  EXPECT_EQ(cs.recorded(), 0u);
}
