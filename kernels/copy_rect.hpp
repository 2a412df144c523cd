// Rectangle copies and fills between slices of equal batch and channels: how tiles are cut out of
// and stitched back into full-size tensors on the device (host/model/tiling.cpp), and how the
// pixels a sparse run skips get their value.
#pragma once
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

// out[n, c, dst_y + i, dst_x + j] = in[n, c, src.y + i, src.x + j] for i < src.h, j < src.w; both
// rectangles must lie inside their slices.
void copy_rect(CommandStream& cs, Slice in, Slice out, const Rect& src, int64_t dst_y, int64_t dst_x);
void copy_rect_ref(HostSlice in, HostSliceOut out, const Rect& src, int64_t dst_y, int64_t dst_x);

// out[n, c, y, x] = value inside `rect`.
void fill_rect(CommandStream& cs, Slice out, const Rect& rect, float value);
void fill_rect_ref(HostSliceOut out, const Rect& rect, float value);

}  // namespace vkunroll
