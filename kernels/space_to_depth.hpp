// space_to_depth(2) and depth_to_space(2) with PyTorch's channel orders (PixelUnshuffle(2) and
// PixelShuffle(2)): channel c*4 + i*2 + j of the deep tensor is row offset i, column offset j of
// channel c of the shallow one.
// Odd sizes: space_to_depth zero-pads the input to even height/width at the bottom/right, so the
// output is ceil(H/2) x ceil(W/2) and the missing positions are 0. depth_to_space is always exact.
#pragma once
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

Shape space_to_depth_shape(const Shape& in);  // {n, 4c, ceil(h/2), ceil(w/2)}
Shape depth_to_space_shape(const Shape& in);  // {n, c/4, 2h, 2w}; c must be a multiple of 4

void space_to_depth(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt = {});
void depth_to_space(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt = {});

void space_to_depth_ref(HostSlice in, HostSliceOut out);
void depth_to_space_ref(HostSlice in, HostSliceOut out);

}  // namespace vkunroll
