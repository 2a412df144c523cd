// The weight-free physics unroller: the event-based double integral (EDI) per pixel.
//
//   I(t*) = I_rs * T / integral over the row's exposure [S_y, E_y] of exp(c * E(t* -> s)) ds
//
// with E(t* -> s) the signed event count of the pixel from t* to s (the sum of polarities in
// (t*, s] for s > t*, minus the sum over (s, t*] for s < t*) and c the contrast threshold.
// Computed in the log domain (log-sum-exp over the constant segments between events), so
// thousands of events neither overflow nor underflow, and black pixels stay 0 without NaN.
#pragma once
#include <cstdint>
#include <vector>

#include "vkunroll/base/events.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/tensor.hpp"
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

// Per-pixel event lists for one target, in CSR form, times relative to t* (µs, as float for
// the GPU: 100 ms spans keep a resolution below 0.01 µs).
struct PixelEventLists {
  int width = 0, height = 0;
  std::vector<uint32_t> offsets;  // width*height + 1 entries
  std::vector<float> tau;         // event time - t*, in µs, per pixel in time order
  std::vector<int32_t> polarity;  // +1 / -1
  std::vector<float> row_start;   // S_y - t*, µs (height entries)
  std::vector<float> row_end;     // E_y - t*, µs
};

// Selects, for every row y, the events of the pixels of that row in [min(t*, S_y), max(t*, E_y)]
// from a time-sorted stream (binary search on t), and buckets them per pixel. `row_start` and
// `row_end` are absolute µs per sensor row; (x0, y0) is the crop origin of the image.
PixelEventLists gather_pixel_events(const EventStream& events, double t_star_us,
                                    const std::vector<double>& row_start_us, const std::vector<double>& row_end_us,
                                    int x0, int y0, int width, int height);

struct PhysicsUnrollParams {
  float contrast = 0.2f;  // c: log-intensity change per event
  float gamma = 1.0f;     // the image is decoded with x^gamma before and encoded after
  float max_value = 1e4f; // cap on the linear result, so a wildly wrong c cannot produce inf
  // eps: the events measure log(lin + eps), a sensor's dark offset (v2e's and the simulator's eps);
  // the ratio then applies to lin + eps and eps comes off after. 0: plain log(lin).
  float log_offset = 0.0f;
};

// Throws Error unless `rs` holds C x H x W finite values (names the first bad (channel, y, x)).
// physics_unroll_ref calls it; call it before PhysicsUnroll::record (whose image is on the device).
void check_physics_image(const std::vector<float>& rs, int channels, const PixelEventLists& ev);

// CPU reference (double precision): rs and the result are [C, H, W] planes in [0, 1]. Guards:
// rs <= 0 gives 0 (no log of 0), an empty exposure (S == E) returns rs, and the linear result is
// capped at max_value in the log domain (never inf); writers clamp to [0, 1].
std::vector<float> physics_unroll_ref(const std::vector<float>& rs, int channels, const PixelEventLists& ev,
                                      const PhysicsUnrollParams& params);

// GPU version: uploads the lists and records two dispatches: every pixel keeps its value (what the
// formula gives without events), then the pixels with events get the formula.
class PhysicsUnroll {
 public:
  // Most events one pixel may have: the shader loops twice over them, and lavapipe silently ends
  // an invocation's loops after 65535 iterations in all (a wrong image, no error).
  static constexpr uint32_t kMaxPixelEvents = 29000;
  // Whether every pixel fits kMaxPixelEvents; the CPU reference has no such limit.
  static bool fits(const PixelEventLists& ev);
  // Throws Error naming the first pixel over the limit when !fits(ev). With `cs`, the lists' uploads
  // are recorded into it (ordered with its work, no wait); the op must then outlive that submission.
  PhysicsUnroll(Context& ctx, const PixelEventLists& ev, CommandStream* cs = nullptr);
  // rs and result: one item [1, C, H, W] of the lists' size each, f32 (an f16 tensor is an Error);
  // result may be an item of a batch, written in place.
  void record(CommandStream& cs, Slice rs, Slice result, const PhysicsUnrollParams& params) const;

 private:
  Context& ctx_;
  int width_, height_;
  size_t events_;
  Tensor offsets_, tau_, polarity_, rows_, listed_;  // listed_: the pixels with events
  size_t listed_count_ = 0;
};

}  // namespace vkunroll
