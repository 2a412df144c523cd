#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

PixelEventLists gather_pixel_events(const EventStream& events, double t_star_us,
                                    const std::vector<double>& row_start_us, const std::vector<double>& row_end_us,
                                    int x0, int y0, int width, int height) {
  if (width <= 0 || height <= 0) throw Error("gather_pixel_events: empty image");
  if (y0 < 0 || static_cast<size_t>(y0 + height) > row_start_us.size() || row_end_us.size() != row_start_us.size())
    throw Error("gather_pixel_events: rows " + std::to_string(y0) + ".." + std::to_string(y0 + height - 1) +
                " are outside the row timing of " + std::to_string(row_start_us.size()) + " rows");
  // A NaN t* or row time would make every comparison below false and select garbage silently.
  if (!std::isfinite(t_star_us)) throw Error("gather_pixel_events: target time t* is not finite");
  for (int y = 0; y < height; ++y)
    if (!std::isfinite(row_start_us[y0 + y]) || !std::isfinite(row_end_us[y0 + y]))
      throw Error("gather_pixel_events: row " + std::to_string(y0 + y) + "'s exposure start/end is not finite");
  PixelEventLists ev;
  ev.width = width;
  ev.height = height;
  ev.row_start.resize(height);
  ev.row_end.resize(height);
  double lo = std::numeric_limits<double>::max(), hi = std::numeric_limits<double>::lowest();
  for (int y = 0; y < height; ++y) {
    const double s = row_start_us[y0 + y], e = row_end_us[y0 + y];
    ev.row_start[y] = static_cast<float>(s - t_star_us);
    ev.row_end[y] = static_cast<float>(e - t_star_us);
    lo = std::min({lo, s, t_star_us});
    hi = std::max({hi, e, t_star_us});
  }
  // The events of the whole window, then counted and bucketed per pixel (stable: keeps time order).
  const auto first = std::lower_bound(events.t.begin(), events.t.end(), static_cast<int64_t>(std::floor(lo)));
  const auto last = std::upper_bound(events.t.begin(), events.t.end(), static_cast<int64_t>(std::ceil(hi)));
  const size_t i0 = first - events.t.begin(), i1 = last - events.t.begin();
  auto pixel_of = [&](size_t i) -> int64_t {
    const int x = events.x[i] - x0, y = events.y[i] - y0;
    if (x < 0 || y < 0 || x >= width || y >= height) return -1;
    const double t = static_cast<double>(events.t[i]);
    const double s = row_start_us[y0 + y], e = row_end_us[y0 + y];
    if (t < std::min(s, t_star_us) || t > std::max(e, t_star_us)) return -1;  // outside this row's window
    return static_cast<int64_t>(y) * width + x;
  };
  ev.offsets.assign(static_cast<size_t>(width) * height + 1, 0);
  for (size_t i = i0; i < i1; ++i)
    if (int64_t px = pixel_of(i); px >= 0) ev.offsets[px + 1]++;
  for (size_t k = 1; k < ev.offsets.size(); ++k) ev.offsets[k] += ev.offsets[k - 1];
  ev.tau.resize(ev.offsets.back());
  ev.polarity.resize(ev.offsets.back());
  std::vector<uint32_t> fill(ev.offsets.begin(), ev.offsets.end() - 1);
  for (size_t i = i0; i < i1; ++i) {
    const int64_t px = pixel_of(i);
    if (px < 0) continue;
    const uint32_t k = fill[px]++;
    ev.tau[k] = static_cast<float>(static_cast<double>(events.t[i]) - t_star_us);
    ev.polarity[k] = events.p[i] > 0 ? 1 : -1;
  }
  return ev;
}

void check_physics_image(const std::vector<float>& rs, int channels, const PixelEventLists& ev) {
  const size_t plane = static_cast<size_t>(ev.width) * ev.height;
  if (rs.size() != plane * channels)
    throw Error("physics unroller: image 'rs' has " + std::to_string(rs.size()) + " values, expected " +
                std::to_string(plane * channels) + " (" + std::to_string(channels) + "x" + std::to_string(ev.height) +
                "x" + std::to_string(ev.width) + ")");
  // The formula maps NaN to 0 and +inf to max_value without a word; say where the bad value is.
  for (size_t i = 0; i < rs.size(); ++i)
    if (!std::isfinite(rs[i])) {
      const size_t c = i / plane, y = (i % plane) / ev.width, x = i % ev.width;
      throw Error("physics unroller: image 'rs' holds " + std::string(std::isnan(rs[i]) ? "NaN" : "an infinite value") +
                  " at (channel " + std::to_string(c) + ", y " + std::to_string(y) + ", x " + std::to_string(x) +
                  "); the image must be finite");
    }
}

std::vector<float> physics_unroll_ref(const std::vector<float>& rs, int channels, const PixelEventLists& ev,
                                      const PhysicsUnrollParams& params) {
  const size_t plane = static_cast<size_t>(ev.width) * ev.height;
  check_physics_image(rs, channels, ev);
  std::vector<float> out(rs.size());
  for (int y = 0; y < ev.height; ++y) {
    const double S = ev.row_start[y], E = ev.row_end[y], T = E - S;
    for (int x = 0; x < ev.width; ++x) {
      const size_t pix = static_cast<size_t>(y) * ev.width + x;
      const uint32_t b = ev.offsets[pix], e = ev.offsets[pix + 1];
      int f0 = 0, f = 0;
      for (uint32_t i = b; i < e; ++i) {
        if (ev.tau[i] <= 0.f) f0 += ev.polarity[i];
        if (ev.tau[i] <= S) f += ev.polarity[i];
      }
      double log_ratio = 0;
      if (T > 0) {
        // Segments between consecutive events inside (S, E): log-sum-exp of log(len) + c * E.
        std::vector<double> terms;
        double prev = S;
        for (uint32_t i = b; i <= e; ++i) {
          const bool last = i == e;
          const double t = last ? E : ev.tau[i];
          if (!last && t <= S) continue;
          const double seg_end = std::min(t, E);
          if (seg_end > prev) {
            terms.push_back(std::log(seg_end - prev) + params.contrast * (f - f0));
            prev = seg_end;
          }
          if (last || t >= E) break;
          f += ev.polarity[i];
        }
        const double m = *std::max_element(terms.begin(), terms.end());
        double acc = 0;
        for (double v : terms) acc += std::exp(v - m);
        log_ratio = std::log(T) - (m + std::log(acc));
      }
      for (int c = 0; c < channels; ++c) {
        const double v = rs[c * plane + pix];
        const double offset = params.log_offset;  // events measure log(lin + offset)
        const double lin = (v > 0 ? std::pow(v, static_cast<double>(params.gamma)) : 0.0) + offset;
        // Capped in the log domain: log_ratio reaches ~c * (event count) (1e5 and more for millions
        // of events), and exp() of that is inf; the GPU does the same so it never relies on inf.
        const double o = lin > 0 ? std::min(std::exp(std::min(std::log(lin) + log_ratio, std::log(double(params.max_value)))),
                                                   double(params.max_value)) - offset
                                : 0.0;
        out[c * plane + pix] = static_cast<float>(o > 0 ? std::pow(o, 1.0 / params.gamma) : 0.0);
      }
    }
  }
  return out;
}

namespace {
struct PhysicsPush {
  int32_t width, height, channels;
  float contrast, gamma, max_value, log_offset, keep_max;
  uint32_t rs_off, out_off;
  uint32_t count;
};
template <class T>
Tensor upload_vector(Context& ctx, const std::vector<T>& v, DType dt, CommandStream* cs) {
  Tensor t(ctx, {1, 1, 1, std::max<int64_t>(1, static_cast<int64_t>(v.size()))}, dt);
  const std::vector<T> one(1, T{});
  const std::vector<T>& data = v.empty() ? one : v;
  if (cs) cs->upload(t, 0, data.data(), data.size() * sizeof(T));
  else t.upload(data);
  return t;
}
}  // namespace

bool PhysicsUnroll::fits(const PixelEventLists& ev) {
  for (size_t k = 0; k + 1 < ev.offsets.size(); ++k)
    if (ev.offsets[k + 1] - ev.offsets[k] > kMaxPixelEvents) return false;
  return true;
}

PhysicsUnroll::PhysicsUnroll(Context& ctx, const PixelEventLists& ev, CommandStream* cs)
    : ctx_(ctx), width_(ev.width), height_(ev.height), events_(ev.tau.size()) {
  for (size_t k = 0; k + 1 < ev.offsets.size(); ++k)
    if (const uint32_t n = ev.offsets[k + 1] - ev.offsets[k]; n > kMaxPixelEvents)
      throw Error("PhysicsUnroll: pixel (x=" + std::to_string(k % ev.width) + ", y=" + std::to_string(k / ev.width) +
                  ") has " + std::to_string(n) + " events in its window, more than the GPU kernel's " +
                  std::to_string(kMaxPixelEvents) +
                  " (lavapipe ends shader loops after 65535 iterations); use physics_unroll_ref");
  offsets_ = upload_vector(ctx, ev.offsets, DType::u32, cs);
  tau_ = upload_vector(ctx, ev.tau, DType::f32, cs);
  polarity_ = upload_vector(ctx, ev.polarity, DType::i32, cs);
  std::vector<float> rows(ev.row_start);
  rows.insert(rows.end(), ev.row_end.begin(), ev.row_end.end());
  rows_ = upload_vector(ctx, rows, DType::f32, cs);
  std::vector<uint32_t> listed;  // the pixels with events: the rest keep their value (pass 0)
  for (size_t k = 0; k + 1 < ev.offsets.size(); ++k)
    if (ev.offsets[k + 1] > ev.offsets[k]) listed.push_back(static_cast<uint32_t>(k));
  listed_count_ = listed.size();
  listed_ = upload_vector(ctx, listed, DType::u32, cs);
}

void PhysicsUnroll::record(CommandStream& cs, Slice rs, Slice result, const PhysicsUnrollParams& params) const {
  const Shape s = rs.shape();
  // Whole items: the shader addresses channel c of the item at offset + c * H * W.
  if (s.n != 1 || s.h != height_ || s.w != width_ || !(result.shape() == s) || s.c != rs.tensor_shape().c ||
      s.c != result.tensor_shape().c)
    throw Error("PhysicsUnroll: image " + s.str() + " / output " + result.shape().str() + " (items of " +
                rs.tensor_shape().str() + " / " + result.tensor_shape().str() + ") do not match the event lists (" +
                std::to_string(height_) + "x" + std::to_string(width_) + ") as one whole item each");
  // fp32 only: the exponentials and the log-sum-exp run in fp32 and an fp16 image would cap them.
  if (rs.t->dtype() != DType::f32 || result.t->dtype() != DType::f32)
    throw Error(std::string("PhysicsUnroll: image and output must be f32 tensors (got ") + dtype_name(rs.t->dtype()) +
                " / " + dtype_name(result.t->dtype()) + "); convert fp16 images with copy()");
  if (!(params.contrast > 0) || !(params.gamma > 0))
    throw Error("PhysicsUnroll: contrast and gamma must be positive");
  if (!(params.max_value > 0) || !std::isfinite(params.max_value))
    throw Error("PhysicsUnroll: max_value must be positive and finite");
  if (!(params.log_offset >= 0) || !(params.log_offset < params.max_value))
    throw Error("PhysicsUnroll: log_offset must be in [0, max_value)");
  const BoundSlice bi = bind_slice(rs, Access::read), bo = bind_slice(result, Access::write);
  // Without events the formula is clamp(v, 0, keep_max): the cap (max_value - log_offset)^(1/gamma).
  const float keep_max =
      static_cast<float>(std::pow(double(params.max_value) - double(params.log_offset), 1.0 / double(params.gamma)));
  const size_t pixels = static_cast<size_t>(width_) * height_;
  PhysicsPush p{width_,   height_,   static_cast<int32_t>(s.c), params.contrast, params.gamma, params.max_value,
                params.log_offset, keep_max, bi.offset, bo.offset, 0};
  const std::vector<Arg> args{in(offsets_), in(tau_), in(polarity_), in(rows_), bi.arg, bo.arg, in(listed_)};
  // Pass 0 over every pixel, then pass 1 over the listed ones (after it: the runtime orders the writes).
  for (uint32_t pass : {0u, 1u}) {
    const size_t count = pass == 0 ? (pixels + 3) / 4 : listed_count_;  // pass 0: four pixels an invocation
    if (count == 0) continue;
    p.count = static_cast<uint32_t>(count);
    const double n = static_cast<double>(count);
    cs.dispatch(kernel_pipeline(ctx_, "physics_unroll", {pass}, sizeof p), args, p, flat_groups(static_cast<int64_t>(count), 1),
                pass == 0 ? DispatchInfo{"physics_unroll_keep", 0, 8.0 * static_cast<double>(pixels * s.c)}
                          : DispatchInfo{"physics_unroll", 10.0 * (n + 2.0 * events_), 4.0 * (2 * events_ + n * (2 + 2 * s.c))});
  }
}

}  // namespace vkunroll
