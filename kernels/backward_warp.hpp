// backward_warp: out(x, y) = bilinear sample of `image` at (x + flow_x, y + flow_y), the position
// first clamped to [0, W-1] x [0, H-1]. This is grid_sample(align_corners=True,
// padding_mode='border') of the reference; W or H = 1 is fine (that axis always samples index 0).
// flow: 2 channels in pixels, channel 0 = x (column) displacement, channel 1 = y (row).
// A NaN flow component samples index 0 of its axis (never out of range).
// Image, flow and output are all f32 or all f16 (fp16: sampled in fp32; a flow stored in fp16 has
// a resolution of 2^-5 px at |flow| >= 32 and 2^-4 px at >= 64, docs/kernels.md "Precision").
#pragma once
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

void backward_warp(CommandStream& cs, Slice image, Slice flow, Slice out);
void backward_warp_ref(HostSlice image, HostSlice flow, HostSliceOut out);

}  // namespace vkunroll
