#version 450
// backward_warp: out(x, y) = bilinear sample of the image at (x + flow_x, y + flow_y), the position
// clamped to [0, W-1] x [0, H-1] first: grid_sample(align_corners=True, padding_mode='border').
// fp16 variant: image, flow and output as float16_t, the sampling in fp32.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Img { SFLOAT img[]; };
layout(std430, binding = 1) readonly buffer Flow { SFLOAT flow[]; };
layout(std430, binding = 2) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint img_off, img_bs, flow_off, flow_bs, out_off, out_bs, c, h, w; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, n = gl_GlobalInvocationID.z;
  uint plane = p.h * p.w;
  if (i >= plane) return;
  uint py = i / p.w, px = i % p.w;
  uint fb = p.flow_off + n * p.flow_bs;
  float sx = clamp(float(px) + float(flow[fb + i]), 0.0, float(p.w - 1u));
  float sy = clamp(float(py) + float(flow[fb + plane + i]), 0.0, float(p.h - 1u));
  if (isnan(sx)) sx = 0.0;  // a NaN flow samples the first row/column instead of reading out of range
  if (isnan(sy)) sy = 0.0;
  float fx0 = floor(sx), fy0 = floor(sy);
  float ax = sx - fx0, ay = sy - fy0;
  uint x0 = uint(fx0), y0 = uint(fy0);
  uint x1 = min(x0 + 1u, p.w - 1u), y1 = min(y0 + 1u, p.h - 1u);
  for (uint c = 0; c < p.c; ++c) {
    uint b = p.img_off + n * p.img_bs + c * plane;
    float v00 = float(img[b + y0 * p.w + x0]), v01 = float(img[b + y0 * p.w + x1]);
    float v10 = float(img[b + y1 * p.w + x0]), v11 = float(img[b + y1 * p.w + x1]);
    float v = (v00 * (1.0 - ax) + v01 * ax) * (1.0 - ay) + (v10 * (1.0 - ax) + v11 * ax) * ay;
    y[p.out_off + n * p.out_bs + c * plane + i] = to_s(v);
  }
}
