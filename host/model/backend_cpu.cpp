#include "vkunroll/host/model/backend_cpu.hpp"

#include <algorithm>
#include <thread>

#include <opencv2/core/utility.hpp>

#include "vkunroll/kernels/backward_warp.hpp"
#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/kernels/copy_rect.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

// The kernels' CPU references on HostTensor buffers. Convolutions are split by output channels
// over the machine's threads (each part is the reference on its own channel range).
struct CpuBackend::Impl {
  struct Buf {
    HostTensor t;
    bool live = false;
  };
  struct Part {
    int64_t c0 = 0, c = 0;
    HostTensor w, b;
  };
  struct Conv {
    ConvDesc d;
    std::vector<Part> parts;
  };
  std::vector<Buf> bufs;
  std::vector<Conv> convs;
  unsigned threads = 1;
  // The last event tensors built, handed out as a buffer (event_tensors()).
  EventTensors events;

  HostTensor& buf(int id) {
    if (id < 0 || id >= static_cast<int>(bufs.size()) || !bufs[id].live)
      throw InternalError("cpu backend: buffer " + std::to_string(id) + " is not allocated");
    return bufs[id].t;
  }
  HostSlice in(const BufferSlice& v) { return HostSlice(buf(v.buf), v.c0, v.c, v.n0, v.n); }
  HostSliceOut out(const BufferSlice& v) { return HostSliceOut(buf(v.buf), v.c0, v.c, v.n0, v.n); }
};

CpuBackend::CpuBackend(unsigned threads) : impl_(std::make_unique<Impl>()) {
  impl_->threads = threads ? threads : std::max(1u, std::min(8u, std::thread::hardware_concurrency()));
}
CpuBackend::~CpuBackend() = default;

int CpuBackend::alloc_id(const Shape& shape, const std::string&) {
  account_alloc(static_cast<uint64_t>(shape.count()) * 4);
  for (size_t i = 0; i < impl_->bufs.size(); ++i)
    if (!impl_->bufs[i].live) {
      impl_->bufs[i] = {HostTensor(shape), true};
      return static_cast<int>(i);
    }
  impl_->bufs.push_back({HostTensor(shape), true});
  return static_cast<int>(impl_->bufs.size() - 1);
}

void CpuBackend::release_id(int id) noexcept {
  // A live buffer: only its handle releases it, once.
  account_release(static_cast<uint64_t>(impl_->bufs[size_t(id)].t.shape.count()) * 4);
  impl_->bufs[size_t(id)] = {};
}

Shape CpuBackend::shape(int id) const { return impl_->buf(id).shape; }

void CpuBackend::upload(const BufferSlice& v, std::span<const float> data) {
  const Shape s = impl_->in(v).shape();
  if (static_cast<int64_t>(data.size()) != s.count()) throw InternalError("cpu backend: upload of " + std::to_string(data.size()) + " values into " + s.str());
  HostTensor src(s, std::vector<float>(data.begin(), data.end()));
  copy_ref(HostSlice(src), impl_->out(v));
}

void CpuBackend::download(const BufferSlice& v, std::span<float> dst) {
  const HostSlice s = impl_->in(v);
  if (static_cast<int64_t>(dst.size()) != s.shape().count())
    throw InternalError("cpu backend: download of " + s.shape().str() + " into " + std::to_string(dst.size()) + " values");
  HostTensor out(s.shape());
  copy_ref(s, HostSliceOut(out));
  std::copy(out.data.begin(), out.data.end(), dst.begin());
}

int CpuBackend::prepare_conv(const ConvDesc& d, const WeightTensor& w, const WeightTensor& b) {
  Impl::Conv cv{d, {}};
  const int64_t cout = d.cout, k = d.k;
  const int64_t parts = std::min<int64_t>(impl_->threads, cout);
  for (int64_t p = 0; p < parts; ++p) {
    Impl::Part part;
    part.c0 = cout * p / parts;
    part.c = cout * (p + 1) / parts - part.c0;
    part.b = HostTensor(Shape{1, 1, 1, part.c},
                        std::vector<float>(b.data.begin() + part.c0, b.data.begin() + part.c0 + part.c));
    if (!d.transposed) {  // [cout, cin, k, k]: a contiguous block of output channels
      const int64_t per = int64_t(d.cin) * k * k;
      part.w = HostTensor(Shape{part.c, d.cin, k, k}, std::vector<float>(w.data.begin() + part.c0 * per,
                                                                          w.data.begin() + (part.c0 + part.c) * per));
    } else {  // [cin, cout, k, k]: gather the output-channel range of every input channel
      part.w = HostTensor(Shape{d.cin, part.c, k, k});
      for (int64_t ci = 0; ci < d.cin; ++ci)
        std::copy_n(w.data.begin() + (ci * cout + part.c0) * k * k, part.c * k * k,
                    part.w.data.begin() + ci * part.c * k * k);
    }
    cv.parts.push_back(std::move(part));
  }
  impl_->convs.push_back(std::move(cv));
  return static_cast<int>(impl_->convs.size() - 1);
}

void CpuBackend::conv(int id, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) {
  const Impl::Conv& cv = impl_->convs.at(static_cast<size_t>(id));
  const ConvDesc& d = cv.d;
  if (residual && d.transposed) throw InternalError("cpu backend: " + d.name + ": a transposed conv takes no residual");
  const Act act = d.leaky ? leaky_relu(d.slope) : Act{};
  auto run_part = [&](const Impl::Part& p) {
    const BufferSlice o{out.buf, out.n0, out.n, out.c0 + p.c0, p.c};
    if (d.transposed) {
      conv_transpose2d_ref(impl_->in(in), impl_->out(o), p.w, p.b, ConvTranspose2dParams{d.k, d.stride, d.pad, act});
    } else {
      std::optional<HostSlice> r;
      if (residual) r = impl_->in(BufferSlice{residual->buf, residual->n0, residual->n, residual->c0 + p.c0, p.c});
      conv2d_ref(impl_->in(in), impl_->out(o), p.w, p.b, Conv2dParams{d.k, d.stride, d.pad, act}, r);
    }
  };
  if (cv.parts.size() == 1) {
    run_part(cv.parts[0]);
    return;
  }
  // One stripe per part on OpenCV's persistent pool (no thread is started per call).
  std::vector<std::exception_ptr> errors(cv.parts.size());
  cv::parallel_for_(
      cv::Range(0, static_cast<int>(cv.parts.size())),
      [&](const cv::Range& r) {
        for (int i = r.start; i < r.end; ++i) try {
            run_part(cv.parts[static_cast<size_t>(i)]);
          } catch (...) {
            errors[static_cast<size_t>(i)] = std::current_exception();
          }
      },
      static_cast<double>(cv.parts.size()));
  for (auto& e : errors)
    if (e) std::rethrow_exception(e);
}

void CpuBackend::space_to_depth(const BufferSlice& in, const BufferSlice& out) { space_to_depth_ref(impl_->in(in), impl_->out(out)); }
void CpuBackend::depth_to_space(const BufferSlice& in, const BufferSlice& out) { depth_to_space_ref(impl_->in(in), impl_->out(out)); }

void CpuBackend::reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) {
  const Shape si = impl_->in(in).shape(), so = impl_->in(out).shape();
  reflection_pad_ref(impl_->in(in), impl_->out(out), Pads{top, so.h - si.h - top, left, so.w - si.w - left});
}

void CpuBackend::crop(const BufferSlice& in, const BufferSlice& out, int top, int left) {
  crop_ref(impl_->in(in), impl_->out(out), top, left);
}

void CpuBackend::copy(const BufferSlice& in, const BufferSlice& out) { copy_ref(impl_->in(in), impl_->out(out)); }
void CpuBackend::add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) {
  add_ref(impl_->in(a), impl_->in(b), impl_->out(out));
}
void CpuBackend::clamp01(const BufferSlice& in, const BufferSlice& out) { clamp01_ref(impl_->in(in), impl_->out(out)); }
void CpuBackend::tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) {
  scale_act_ref(impl_->in(in), impl_->out(out), Act{Activation::tanh, 0.f}, scale);
}
void CpuBackend::backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) {
  backward_warp_ref(impl_->in(img), impl_->in(flow), impl_->out(out));
}

void CpuBackend::copy_rect(const BufferSlice& in, const BufferSlice& out, const Rect& src, int64_t dst_y, int64_t dst_x) {
  copy_rect_ref(impl_->in(in), impl_->out(out), src, dst_y, dst_x);
}
void CpuBackend::fill_rect(const BufferSlice& out, const Rect& rect, float value) { fill_rect_ref(impl_->out(out), rect, value); }

int CpuBackend::event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                 const EventTensorSpec& spec) {
  EventTensors& t = impl_->events;
  t = build_event_tensors_ref(events, pairs, spec);
  const int64_t P = t.pairs;
  const int buf = alloc_id({3 * P, 2 * t.bins, t.height, t.width}, "event tensors");
  HostTensor& dst = impl_->buf(buf);
  const size_t part = static_cast<size_t>(P) * t.slice();
  std::copy(t.ev1.begin(), t.ev1.end(), dst.data.begin());
  std::copy(t.ev2.begin(), t.ev2.end(), dst.data.begin() + part);
  std::copy(t.ev3.begin(), t.ev3.end(), dst.data.begin() + 2 * part);
  return buf;
}

void CpuBackend::physics_unroll(const BufferSlice& rs, const PixelEventLists& lists, const PhysicsUnrollParams& params,
                                const BufferSlice& out) {
  const HostTensor& src = impl_->buf(rs.buf);
  HostTensor& dst = impl_->buf(out.buf);
  const Shape item{1, src.shape.c, src.shape.h, src.shape.w};
  if (rs.n != 1 || out.n != 1 || rs.c != src.shape.c || out.c != dst.shape.c ||
      !(Shape{1, dst.shape.c, dst.shape.h, dst.shape.w} == item))
    throw InternalError("cpu backend: physics_unroll takes one whole item [1, C, H, W] each, got " + src.shape.str() + " item " +
                std::to_string(rs.n0) + " -> " + dst.shape.str() + " item " + std::to_string(out.n0));
  const size_t n = static_cast<size_t>(item.count());
  const std::vector<float> image(src.data.begin() + static_cast<std::ptrdiff_t>(rs.n0 * n),
                                 src.data.begin() + static_cast<std::ptrdiff_t>((rs.n0 + 1) * n));
  const std::vector<float> r = physics_unroll_ref(image, static_cast<int>(item.c), lists, params);
  std::copy(r.begin(), r.end(), dst.data.begin() + static_cast<std::ptrdiff_t>(out.n0 * n));
}

void CpuBackend::hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m, const BufferSlice& out,
                                   float forced) {
  if (forced >= 0) {
    HostSliceOut mm = impl_->out(m);
    const Shape s = mm.shape();
    for (int64_t n = 0; n < s.n; ++n)
      for (int64_t y = 0; y < s.h; ++y)
        for (int64_t x = 0; x < s.w; ++x) mm.at(n, 0, y, x) = forced;
  } else {
    scale_act_ref(impl_->in(score), impl_->out(m), Act{Activation::hardsigmoid, 0.f}, 1.f);
  }
  blend_ref(impl_->in(m), impl_->in(a), impl_->in(b), impl_->out(out));
}

}  // namespace vkunroll
