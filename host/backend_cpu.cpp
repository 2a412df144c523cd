#include "host/backend_cpu.hpp"

#include <algorithm>
#include <cmath>
#include <thread>

#include "runtime/error.hpp"

namespace vkunroll {

struct CpuBackend::Impl {
  struct Buf {
    Shape shape;
    std::vector<float> data;
    bool live = false;
  };
  struct Conv {
    ConvDesc d;
    std::vector<float> w, b;  // w as in the checkpoint
  };
  std::vector<Buf> bufs;
  std::vector<Conv> convs;

  Buf& buf(int id) {
    if (id < 0 || id >= static_cast<int>(bufs.size()) || !bufs[id].live) throw Error("cpu backend: dead buffer " + std::to_string(id));
    return bufs[id];
  }
  float* plane(const View& v, int64_t i, int64_t c) {
    Buf& b = buf(v.buf);
    if (v.n0 + v.n > b.shape.n || v.c0 + v.c > b.shape.c || i >= v.n || c >= v.c)
      throw Error("cpu backend: view outside buffer " + b.shape.str());
    return b.data.data() + ((v.n0 + i) * b.shape.c + v.c0 + c) * b.shape.h * b.shape.w;
  }
  Shape hw(const View& v) { return buf(v.buf).shape; }
};

namespace {

// Runs f(i) for i in [0, n) on up to two threads (the CI machine has two cores).
template <class F>
void parallel_for(int64_t n, F&& f) {
  const int64_t threads = std::min<int64_t>(n, std::max(1u, std::min(4u, std::thread::hardware_concurrency())));
  if (threads <= 1) {
    for (int64_t i = 0; i < n; ++i) f(i);
    return;
  }
  std::vector<std::thread> pool;
  for (int64_t t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      for (int64_t i = t; i < n; i += threads) f(i);
    });
  for (auto& th : pool) th.join();
}

void same_extent(const char* op, const View& a, const Shape& sa, const View& b, const Shape& sb) {
  if (a.n != b.n || a.c != b.c || sa.h != sb.h || sa.w != sb.w)
    throw Error(std::string("cpu backend: ") + op + ": views differ in extent");
}

}  // namespace

CpuBackend::CpuBackend() : impl_(std::make_unique<Impl>()) {}
CpuBackend::~CpuBackend() = default;

int CpuBackend::alloc(const Shape& shape, const std::string&) {
  Impl::Buf b{shape, std::vector<float>(static_cast<size_t>(shape.count())), true};
  account_alloc(static_cast<uint64_t>(shape.count()) * 4);
  for (size_t i = 0; i < impl_->bufs.size(); ++i)
    if (!impl_->bufs[i].live) {
      impl_->bufs[i] = std::move(b);
      return static_cast<int>(i);
    }
  impl_->bufs.push_back(std::move(b));
  return static_cast<int>(impl_->bufs.size() - 1);
}

void CpuBackend::release(int id) {
  auto& b = impl_->buf(id);
  account_release(static_cast<uint64_t>(b.shape.count()) * 4);
  b.live = false;
  b.data = {};
}

Shape CpuBackend::shape(int id) const { return impl_->buf(id).shape; }

void CpuBackend::upload(const View& v, std::span<const float> data) {
  const Shape s = impl_->hw(v);
  const int64_t p = s.h * s.w;
  if (static_cast<int64_t>(data.size()) != v.n * v.c * p) throw Error("cpu backend: upload size mismatch");
  for (int64_t i = 0; i < v.n; ++i)
    for (int64_t c = 0; c < v.c; ++c) std::copy_n(data.data() + (i * v.c + c) * p, p, impl_->plane(v, i, c));
}

std::vector<float> CpuBackend::download(const View& v) {
  const Shape s = impl_->hw(v);
  const int64_t p = s.h * s.w;
  std::vector<float> out(static_cast<size_t>(v.n * v.c * p));
  for (int64_t i = 0; i < v.n; ++i)
    for (int64_t c = 0; c < v.c; ++c) std::copy_n(impl_->plane(v, i, c), p, out.data() + (i * v.c + c) * p);
  return out;
}

int CpuBackend::prepare_conv(const ConvDesc& d, const WeightTensor& w, const WeightTensor& b) {
  impl_->convs.push_back({d, w.data, b.data});
  return static_cast<int>(impl_->convs.size() - 1);
}

void CpuBackend::conv(int id, const View& in, const View& out, const View* residual) {
  const auto& cv = impl_->convs.at(static_cast<size_t>(id));
  const ConvDesc& d = cv.d;
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  if (in.c != d.cin || out.c != d.cout || in.n != out.n)
    throw Error("cpu backend: conv " + d.name + ": channel/batch mismatch");
  const int64_t H = si.h, W = si.w, OH = so.h, OW = so.w, k = d.k, s = d.stride, p = d.pad;
  if (!d.transposed && (OH != (H + 2 * p - k) / s + 1 || OW != (W + 2 * p - k) / s + 1))
    throw Error("cpu backend: conv " + d.name + ": output size mismatch");
  if (d.transposed && (OH != (H - 1) * s - 2 * p + k || OW != (W - 1) * s - 2 * p + k))
    throw Error("cpu backend: conv_transpose " + d.name + ": output size mismatch");
  parallel_for(out.n * d.cout, [&](int64_t job) {
    const int64_t i = job / d.cout, co = job % d.cout;
    float* o = impl_->plane(out, i, co);
    std::vector<float> acc(static_cast<size_t>(OH * OW), cv.b[co]);
    for (int64_t ci = 0; ci < d.cin; ++ci) {
      const float* x = impl_->plane(in, i, ci);
      for (int64_t ky = 0; ky < k; ++ky)
        for (int64_t kx = 0; kx < k; ++kx) {
          if (!d.transposed) {
            const float wv = cv.w[((co * d.cin + ci) * k + ky) * k + kx];
            // ox range with 0 <= ox*s - p + kx < W
            const int64_t ox0 = std::max<int64_t>(0, (p - kx + s - 1) / s);
            const int64_t ox1 = std::min<int64_t>(OW, (W - 1 + p - kx) / s + 1);
            for (int64_t oy = 0; oy < OH; ++oy) {
              const int64_t iy = oy * s - p + ky;
              if (iy < 0 || iy >= H) continue;
              const float* xr = x + iy * W - p + kx;
              float* ar = acc.data() + oy * OW;
              if (s == 1)
                for (int64_t ox = ox0; ox < ox1; ++ox) ar[ox] += wv * xr[ox];
              else
                for (int64_t ox = ox0; ox < ox1; ++ox) ar[ox] += wv * xr[ox * s];
            }
          } else {
            const float wv = cv.w[((ci * d.cout + co) * k + ky) * k + kx];
            // out (oy, ox) = (iy*s - p + ky, ix*s - p + kx)
            for (int64_t iy = 0; iy < H; ++iy) {
              const int64_t oy = iy * s - p + ky;
              if (oy < 0 || oy >= OH) continue;
              for (int64_t ix = 0; ix < W; ++ix) {
                const int64_t ox = ix * s - p + kx;
                if (ox < 0 || ox >= OW) continue;
                acc[oy * OW + ox] += wv * x[iy * W + ix];
              }
            }
          }
        }
    }
    const float* r = residual ? impl_->plane(*residual, i, co) : nullptr;
    for (int64_t j = 0; j < OH * OW; ++j) {
      float v = acc[j];
      if (d.leaky && v < 0) v *= d.slope;
      if (r) v += r[j];
      o[j] = v;
    }
  });
}

void CpuBackend::space_to_depth(const View& in, const View& out) {
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  for (int64_t i = 0; i < in.n; ++i)
    for (int64_t c = 0; c < in.c; ++c) {
      const float* x = impl_->plane(in, i, c);
      for (int a = 0; a < 2; ++a)
        for (int bb = 0; bb < 2; ++bb) {
          float* o = impl_->plane(out, i, c * 4 + a * 2 + bb);
          for (int64_t y = 0; y < so.h; ++y)
            for (int64_t xx = 0; xx < so.w; ++xx) o[y * so.w + xx] = x[(2 * y + a) * si.w + 2 * xx + bb];
        }
    }
}

void CpuBackend::depth_to_space(const View& in, const View& out) {
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  for (int64_t i = 0; i < out.n; ++i)
    for (int64_t c = 0; c < out.c; ++c) {
      float* o = impl_->plane(out, i, c);
      for (int a = 0; a < 2; ++a)
        for (int bb = 0; bb < 2; ++bb) {
          const float* x = impl_->plane(in, i, c * 4 + a * 2 + bb);
          for (int64_t y = 0; y < si.h; ++y)
            for (int64_t xx = 0; xx < si.w; ++xx) o[(2 * y + a) * so.w + 2 * xx + bb] = x[y * si.w + xx];
        }
    }
}

namespace {
// Reflection (without repeating the edge) of index j into [0, n), periodic beyond one reflection.
int64_t reflect(int64_t j, int64_t n) {
  if (n == 1) return 0;
  const int64_t period = 2 * (n - 1);
  j %= period;
  if (j < 0) j += period;
  return j < n ? j : period - j;
}
}  // namespace

void CpuBackend::reflect_pad(const View& in, const View& out, int top, int left) {
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  for (int64_t i = 0; i < in.n; ++i)
    for (int64_t c = 0; c < in.c; ++c) {
      const float* x = impl_->plane(in, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t y = 0; y < so.h; ++y) {
        const int64_t sy = reflect(y - top, si.h);
        for (int64_t xx = 0; xx < so.w; ++xx) o[y * so.w + xx] = x[sy * si.w + reflect(xx - left, si.w)];
      }
    }
}

void CpuBackend::crop(const View& in, const View& out, int top, int left) {
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  for (int64_t i = 0; i < in.n; ++i)
    for (int64_t c = 0; c < in.c; ++c) {
      const float* x = impl_->plane(in, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t y = 0; y < so.h; ++y) std::copy_n(x + (y + top) * si.w + left, so.w, o + y * so.w);
    }
}

void CpuBackend::copy(const View& in, const View& out) {
  const Shape si = impl_->hw(in), so = impl_->hw(out);
  same_extent("copy", in, si, out, so);
  for (int64_t i = 0; i < in.n; ++i)
    for (int64_t c = 0; c < in.c; ++c) std::copy_n(impl_->plane(in, i, c), si.h * si.w, impl_->plane(out, i, c));
}

void CpuBackend::add(const View& a, const View& b, const View& out) {
  const Shape s = impl_->hw(a);
  for (int64_t i = 0; i < a.n; ++i)
    for (int64_t c = 0; c < a.c; ++c) {
      const float *x = impl_->plane(a, i, c), *y = impl_->plane(b, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t j = 0; j < s.h * s.w; ++j) o[j] = x[j] + y[j];
    }
}

void CpuBackend::tanh_scale(const View& in, const View& out, float scale) {
  const Shape s = impl_->hw(in);
  for (int64_t i = 0; i < in.n; ++i)
    for (int64_t c = 0; c < in.c; ++c) {
      const float* x = impl_->plane(in, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t j = 0; j < s.h * s.w; ++j) o[j] = scale * std::tanh(x[j]);
    }
}

void CpuBackend::backward_warp(const View& img, const View& flow, const View& out) {
  const Shape s = impl_->hw(img);
  const int64_t H = s.h, W = s.w;
  for (int64_t i = 0; i < img.n; ++i) {
    const float* fx = impl_->plane(flow, i, 0);
    const float* fy = impl_->plane(flow, i, 1);
    for (int64_t c = 0; c < img.c; ++c) {
      const float* x = impl_->plane(img, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t y = 0; y < H; ++y)
        for (int64_t xx = 0; xx < W; ++xx) {
          const int64_t j = y * W + xx;
          const float px = std::clamp(float(xx) + fx[j], 0.f, float(W - 1));
          const float py = std::clamp(float(y) + fy[j], 0.f, float(H - 1));
          const int64_t x0 = static_cast<int64_t>(std::floor(px)), y0 = static_cast<int64_t>(std::floor(py));
          const int64_t x1 = std::min(x0 + 1, W - 1), y1 = std::min(y0 + 1, H - 1);
          const float ax = px - float(x0), ay = py - float(y0);
          const float t = x[y0 * W + x0] * (1 - ax) + x[y0 * W + x1] * ax;
          const float b = x[y1 * W + x0] * (1 - ax) + x[y1 * W + x1] * ax;
          o[j] = t * (1 - ay) + b * ay;
        }
    }
  }
}

void CpuBackend::hardsigmoid_blend(const View& score, const View& a, const View& b, const View& m, const View& out,
                                   float forced) {
  const Shape s = impl_->hw(score);
  const int64_t P = s.h * s.w;
  for (int64_t i = 0; i < score.n; ++i) {
    const float* sc = impl_->plane(score, i, 0);
    float* mm = impl_->plane(m, i, 0);
    for (int64_t j = 0; j < P; ++j) mm[j] = forced >= 0 ? forced : std::clamp(sc[j] / 6.f + 0.5f, 0.f, 1.f);
    for (int64_t c = 0; c < a.c; ++c) {
      const float *x = impl_->plane(a, i, c), *y = impl_->plane(b, i, c);
      float* o = impl_->plane(out, i, c);
      for (int64_t j = 0; j < P; ++j) o[j] = mm[j] * x[j] + (1 - mm[j]) * y[j];
    }
  }
}

}  // namespace vkunroll
