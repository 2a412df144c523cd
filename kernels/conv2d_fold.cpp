// conv2d with its input and output folded into the GPU family's addressing (ConvFold): the UNets'
// reflection pad and crop, SFENet1's space-to-depth, UPNet.2's depth-to-space, the concatenation of
// their input pieces and a tanh after the conv cost no dispatch and no buffer of their own. The CPU reference composes the
// separate ops' references.
#include <cmath>
#include <utility>

#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"

namespace vkunroll {

Shape ConvFold::conv_input(const std::vector<Shape>& pieces, const std::string& who) const {
  if (pieces.empty() || pieces.size() > size_t(kMaxInputPieces))
    throw Error(who + ": a folded conv takes 1 to " + std::to_string(kMaxInputPieces) + " input pieces, " +
                std::to_string(pieces.size()) + " given");
  Shape in = pieces[0];
  in.c = 0;
  for (size_t i = 0; i < pieces.size(); ++i) {
    const Shape& s = pieces[i];
    if (s.n != in.n || s.h != in.h || s.w != in.w)
      throw Error(who + ": input piece " + std::to_string(i) + " is " + s.str() + ", piece 0 " + pieces[0].str() +
                  ": the pieces must agree in batch and extent");
    in.c += s.c;
  }
  if (map == InputMap::reflect_pad) {
    if (padded_h < in.h || padded_w < in.w || top < 0 || left < 0 || top + in.h > padded_h || left + in.w > padded_w)
      throw Error(who + ": reflection pad to " + std::to_string(padded_h) + "x" + std::to_string(padded_w) + " at (" +
                  std::to_string(top) + ", " + std::to_string(left) + ") does not hold the " + std::to_string(in.h) +
                  "x" + std::to_string(in.w) + " input");
    in.h = padded_h, in.w = padded_w;
  } else if (map == InputMap::space_to_depth) {
    if (in.h % 2 || in.w % 2)
      throw Error(who + ": space-to-depth of a " + std::to_string(in.h) + "x" + std::to_string(in.w) +
                  " input, expected even height and width");
    in.c *= 4, in.h /= 2, in.w /= 2;
  } else if (map == InputMap::depth_to_space) {
    for (size_t i = 0; i < pieces.size(); ++i)
      if (pieces[i].c % 4)
        throw Error(who + ": depth-to-space of input piece " + std::to_string(i) + " with " + std::to_string(pieces[i].c) +
                    " channels, expected a multiple of 4");
    in.c /= 4, in.h *= 2, in.w *= 2;
  }
  return in;
}

void conv2d_folded_ref(const std::vector<HostSlice>& pieces, const ConvFold& fold, HostSliceOut out,
                       const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
                       std::optional<HostSlice> residual) {
  std::vector<Shape> shapes;
  for (const HostSlice& p : pieces) shapes.push_back(p.shape());
  const Shape cin = fold.conv_input(shapes, "conv2d_folded_ref");
  HostTensor x({cin.n, cin.c, cin.h, cin.w});
  int64_t c0 = 0;
  for (const HostSlice& p : pieces) {
    const int64_t c = fold.piece_channels(p.channels());
    const HostSliceOut dst(x, c0, c);
    if (fold.map == InputMap::reflect_pad)
      reflection_pad_ref(p, dst, {fold.top, fold.padded_h - fold.top - p.height(), fold.left, fold.padded_w - fold.left - p.width()});
    else if (fold.map == InputMap::space_to_depth)
      space_to_depth_ref(p, dst);
    else if (fold.map == InputMap::depth_to_space)
      depth_to_space_ref(p, dst);
    else
      crop_ref(p, dst, 0, 0);
    c0 += c;
  }
  Conv2dParams q = params;
  if (fold.tanh_scale > 0) q.act = {};
  const int64_t oh = conv_output_size(cin.h, q.kernel, q.stride, q.pad), ow = conv_output_size(cin.w, q.kernel, q.stride, q.pad);
  HostTensor full({cin.n, weight.shape.n, oh, ow});
  conv2d_ref(HostSlice(x), HostSliceOut(full), weight, bias, q);
  HostTensor cropped({out.batch(), out.channels(), out.height(), out.width()});
  crop_ref(HostSlice(full), HostSliceOut(cropped), fold.crop_top, fold.crop_left);
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < out.height(); ++y)
        for (int64_t xx = 0; xx < out.width(); ++xx) {
          float v = cropped.at(n, c, y, xx);
          if (fold.tanh_scale > 0) v = fold.tanh_scale * std::tanh(v);
          out.at(n, c, y, xx) = v + (residual ? residual->at(n, c, y, xx) : 0.f);
        }
}

ConvAlgo Conv2d::record_folded(CommandStream& cs, const std::vector<Slice>& pieces, const ConvFold& fold, Slice out,
                               std::optional<Slice> residual, ConvAlgo algo) const {
  std::vector<Shape> shapes;
  for (size_t i = 0; i < pieces.size(); ++i) {
    check_slice(pieces[i], name_, "input piece " + std::to_string(i));
    check_precision(pieces[i], precision_, name_, "input piece " + std::to_string(i));
    shapes.push_back(pieces[i].shape());
  }
  const Shape is = fold.conv_input(shapes, name_), full = output_shape(is);
  check_slice(out, name_, "output");
  check_precision(out, precision_, name_, "output");
  const Shape os = out.shape();
  if (is.c != cin_)
    throw Error(name_ + ": the folded input has " + std::to_string(is.c) + " channels, the weights expect " + std::to_string(cin_));
  if (os.n != full.n || os.c != full.c || fold.crop_top < 0 || fold.crop_left < 0 || fold.crop_top + os.h > full.h ||
      fold.crop_left + os.w > full.w)
    throw Error(name_ + ": output slice " + os.str() + " at (" + std::to_string(fold.crop_top) + ", " +
                std::to_string(fold.crop_left) + ") does not lie in the conv's output " + full.str());
  if (residual) {
    check_slice(*residual, name_, "residual");
    check_precision(*residual, precision_, name_, "residual");
    if (residual->shape() != os) throw Error(name_ + ": residual slice " + residual->shape().str() + ", expected " + os.str());
  }
  if (fold.tanh_scale > 0 && params_.act.kind != Activation::none)
    throw Error(name_ + ": a folded tanh after a conv that has its own activation");
  if (algo == ConvAlgo::automatic) algo = gpu_choice(is);
  if (!(is_igemm(algo) || algo == ConvAlgo::coopmat) || !supports(algo, is))
    throw Error(name_ + ": a folded input or output needs the GPU family (igemm, coopmat), not " + conv_algo_name(algo));
  IgemmProblem pb = igemm_problem(is);
  pb.out = os;
  pb.map = fold.map;
  for (const Shape& s : shapes) pb.piece_channels.push_back(fold.piece_channels(s.c));
  pb.src_h = shapes[0].h, pb.src_w = shapes[0].w;
  if (fold.map == InputMap::reflect_pad) pb.src_y = fold.top, pb.src_x = fold.left;
  pb.crop_y = fold.crop_top, pb.crop_x = fold.crop_left;
  if (fold.tanh_scale > 0) pb.act = {Activation::tanh, 0.f}, pb.scale = fold.tanh_scale;
  IgemmBindings b{bind_slice(pieces[0], Access::read), bind_slice(out, Access::write),
                  residual ? bind_slice(*residual, Access::read) : BoundSlice{{bias_.range(), Access::read}, 0, 0},
                  residual.has_value(), {}, {bias_.range(), Access::read}, {}};
  for (size_t i = 1; i < pieces.size(); ++i) b.more_pieces.push_back(bind_slice(pieces[i], Access::read));
  const double e = static_cast<double>(elem_bytes());
  const DispatchInfo info{name_ + "_" + std::to_string(params_.kernel) + "x" + std::to_string(params_.kernel) + "_" +
                              conv_algo_name(algo) + "_folded",
                          flop(is), e * static_cast<double>(is.count() + os.count() * (residual ? 2 : 1))};
  record_gpu_family(cs, algo, pb, std::move(b), info);
  return algo;
}

}  // namespace vkunroll
