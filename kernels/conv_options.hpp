// Precision and tuning knobs of the conv kernels (Conv2d, ConvTranspose2d), validated at
// construction. A knob at 0 keeps the kernel's own choice for the shape (docs/kernels.md, "Conv
// options"); the knobs change speed, never the result beyond rounding.
#pragma once
#include <string>

#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

struct ConvOptions {
  // The one field that changes results: fp16 stores weights and activations as float16 (measured
  // errors and the per-op arithmetic: docs/kernels.md, "Precision").
  Precision precision = Precision::fp32;
  int blocked_cob = 0;  // conv2d blocked: output channels per invocation, 4, 8 or 16 (0: 16 where 16 | cout, else 8)
  int blocked_px = 0;   // conv2d blocked: output pixels per invocation, 1-16 (0: 8)
  int direct_cob = 0;   // direct (conv2d, conv_transpose2d): output channels per invocation, a multiple of 4 up to 64
  int direct_px = 0;    // conv2d direct: output pixels per row and invocation, 1-16
  int direct_py = 0;    // conv2d direct: output rows per invocation, 1-8
  int gemm_cob = 0;     // conv2d winograd and gemm: output channels per GEMM invocation, 4, 8 or 16 (0: 16 where 16 | cout, else 8)
  int gemm_tv = 0;      // conv2d winograd and gemm: vec4s of tiles (pixels) per GEMM invocation, 1, 2 or 4 (0: 4)
  // conv2d winograd, stride-1 kernels: the input tile. 5x5: 8 = F(4x4, 5x5) (64 positions; the
  // default), 6 = the kernel split into four F(4x4, 3x3) convs on shifted inputs (4 x 36 positions:
  // 2.25x the GEMM). 3x3: 6 = F(4x4, 3x3) (the default), 8 = F(6x6, 3x3) (0.79x the GEMM's multiplies,
  // but on lavapipe its transforms cost more than that saves: docs/kernels.md). 0: the default.
  int winograd_tile = 0;
  int pointwise_cob = 0;  // conv2d pointwise: output channels per invocation, 1-32 (0: the kernel's choice)
  int pointwise_px = 0;   // conv2d pointwise: pixels per invocation, 1-8 (0: the kernel's choice)
  // `automatic` takes the GPU family's choice (igemm, coopmat in fp16 where the device has it) on any
  // device, lavapipe included: `--conv-choice gpu`, its tests and dispatch counts (GPUs take it anyway).
  bool gpu_family = false;

  // Throws Error naming the field, its value and the allowed values; `who` (the conv's name) leads.
  void validate(const std::string& who) const;
};

}  // namespace vkunroll
