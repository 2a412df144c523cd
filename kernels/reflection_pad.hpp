// Reflection padding and cropping with the UNet size adapter's semantics: pad H and W up to a
// multiple of 32 (the reference: (ceil(H/32)*32 - H)/2 on each side); when the difference is odd
// the extra row/column goes to the bottom/right (the reference would fail there).
// Reflection excludes the edge (PyTorch ReflectionPad2d). Where the pad is larger than the image
// (pad >= size, e.g. a 1xN image padded to 32 rows, which PyTorch refuses) the reflection keeps
// folding back and forth (index period 2(size-1)), and an axis of size 1 repeats its one value.
#pragma once
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

struct Pads {
  int64_t top = 0, bottom = 0, left = 0, right = 0;
  bool operator==(const Pads&) const = default;
};

// The size adapter's pads for an h x w image (multiple = 32 in the published UNets).
Pads size_adapter_pads(int64_t h, int64_t w, int64_t multiple = 32);

// The source index a padded index maps to (the rule above), for an axis of `size` values.
int64_t reflect_index(int64_t i, int64_t size);

// out (h + top + bottom, w + left + right) = reflection padding of in.
void reflection_pad(CommandStream& cs, Slice in, Slice out, const Pads& pads, const TexelReadOptions& opt = {});
void reflection_pad_ref(HostSlice in, HostSliceOut out, const Pads& pads);

// out = in[top : top + out.h, left : left + out.w]; the window must lie inside in.
void crop(CommandStream& cs, Slice in, Slice out, int64_t top, int64_t left, const TexelReadOptions& opt = {});
void crop_ref(HostSlice in, HostSliceOut out, int64_t top, int64_t left);

}  // namespace vkunroll
