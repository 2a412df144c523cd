// Event tensors (GPU builder or the exact CPU reference), the physics unroller, image metrics.
#include "common.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"

namespace vkunroll::python {

namespace {

// [C, H, W] float planes of the physics unroller on the context's device, or on the CPU reference
// (ctx null, or a pixel beyond the GPU kernel's per-pixel event limit).
std::vector<float> physics_planes(SharedContext* ctx, const std::vector<float>& rs, int channels, const PixelEventLists& lists,
                                  const PhysicsUnrollParams& prm, bool& on_cpu) {
  check_physics_image(rs, channels, lists);
  on_cpu = ctx == nullptr || !PhysicsUnroll::fits(lists);
  if (on_cpu) return physics_unroll_ref(rs, channels, lists, prm);
  std::lock_guard<std::mutex> lock(ctx->mutex);
  Backend& b = ctx->backend();
  const Shape shape{1, channels, lists.height, lists.width};
  const Buffer in = b.alloc(shape, "physics rs"), out = b.alloc(shape, "physics out");
  b.upload(in.whole(), rs);
  b.physics_unroll(in.whole(), lists, prm, out.whole());
  std::vector<float> result(rs.size());
  b.download(out.whole(), result);
  b.flush();
  return result;
}

cv::Mat image_mat(const F32Array& a, const std::string& what) {
  if (a.ndim() != 2 && a.ndim() != 3) throw UsageError(what + ": expected an H x W or H x W x C image");
  const int c = a.ndim() == 3 ? static_cast<int>(a.shape(2)) : 1;
  return cv::Mat(static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), CV_MAKETYPE(CV_32F, c),
                 const_cast<float*>(a.data()));
}

}  // namespace

void bind_tensors(py::module_& m) {
  m.def(
      "_event_tensors",
      [](const ContextPtr& ctx, const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, int width,
         int height, const std::vector<RowTiming>& timings, const py::sequence& targets, const py::object& target_exposure,
         int bins, const std::vector<long long>& crop) {
        std::vector<EventTensorPair> pairs;
        EventTensorSpec spec;
        const EventStream ev = guarded({}, [&] {
          if (timings.size() != targets.size())
            throw UsageError("event_tensors: " + std::to_string(timings.size()) + " timings for " + std::to_string(targets.size()) +
                        " targets (one timing per target)");
          std::optional<Rational> texp;
          if (!target_exposure.is_none()) texp = to_rational(target_exposure, "target_exposure_us");
          for (size_t i = 0; i < timings.size(); ++i) {
            if (timings[i].rows != height)
              throw UsageError("event_tensors: timing " + std::to_string(i) + " has " + std::to_string(timings[i].rows) +
                          " rows, the sensor " + std::to_string(height));
            pairs.push_back({timings[i], to_rational(targets[i], "t_us[" + std::to_string(i) + "]"), texp});
          }
          if (bins < 1) throw UsageError("event_tensors: bins " + std::to_string(bins) + " (expected at least 1)");
          spec.bins = bins;
          if (!crop.empty()) spec.crop = user_crop(crop, "crop");  // the CLI's --crop rule
          return to_event_stream(t, x, y, p, width, height);
        });
        EventTensors out = without_gil({}, [&] {
          spec.crop = resolve_crop(spec.crop, width, height);
          if (!ctx) return build_event_tensors_ref(ev, pairs, spec);
          std::lock_guard<std::mutex> lock(ctx->mutex);
          return ctx->builder().build(ev, pairs, spec);
        });
        const std::vector<py::ssize_t> shape = {out.pairs, 2 * out.bins, out.height, out.width};
        return py::make_tuple(to_numpy(std::move(out.ev1), shape), to_numpy(std::move(out.ev2), shape),
                              to_numpy(std::move(out.ev3), shape), out.events_considered);
      },
      py::arg("context"), py::arg("t"), py::arg("x"), py::arg("y"), py::arg("p"), py::arg("width"), py::arg("height"),
      py::arg("timings"), py::arg("targets"), py::arg("target_exposure"), py::arg("bins"), py::arg("crop"));

  m.def(
      "_physics_unroll",
      [](const ContextPtr& ctx, const F32Array& rs, const I64Array& t, const U16Array& x, const U16Array& y,
         const I8Array& p, const RowTiming& timing, const py::object& t_star, float contrast, float gamma, float log_offset) {
        PhysicsUnrollParams prm;
        PixelEventLists lists;
        std::vector<float> planes;
        int channels = 0;
        guarded({}, [&] {
          if (rs.ndim() != 3) throw UsageError("physics_unroll: expected rs planes [C, H, W]");
          channels = static_cast<int>(rs.shape(0));
          const int h = static_cast<int>(rs.shape(1)), w = static_cast<int>(rs.shape(2));
          if (timing.rows != h)
            throw UsageError("physics_unroll: the timing has " + std::to_string(timing.rows) + " rows, the image " + std::to_string(h));
          if (!(contrast > 0)) throw UsageError("physics_unroll: contrast " + std::to_string(contrast) + " (expected > 0)");
          if (!(gamma > 0)) throw UsageError("physics_unroll: gamma " + std::to_string(gamma) + " (expected > 0)");
          if (!(log_offset >= 0)) throw UsageError("physics_unroll: log_offset " + std::to_string(log_offset) + " (expected >= 0)");
          prm.contrast = contrast;
          prm.gamma = gamma;
          prm.log_offset = log_offset;
          const Rational ts = to_rational(t_star, "t_us");
          const EventStream ev = to_event_stream(t, x, y, p, w, h);
          lists = gather_pixel_events(ev, ts.to_double(), timing.start_times_us(), timing.end_times_us(), 0, 0, w, h);
          planes.assign(rs.data(), rs.data() + rs.size());
        });
        bool on_cpu = false;
        std::vector<float> out = without_gil({}, [&] { return physics_planes(ctx.get(), planes, channels, lists, prm, on_cpu); });
        if (ctx && on_cpu) log_message(kInfo, "physics_unroll: a pixel has more events than the GPU kernel's limit; ran the CPU reference");
        return to_numpy(std::move(out), {channels, lists.height, lists.width});
      },
      py::arg("context"), py::arg("rs"), py::arg("t"), py::arg("x"), py::arg("y"), py::arg("p"), py::arg("timing"),
      py::arg("t_us"), py::arg("contrast"), py::arg("gamma"), py::arg("log_offset") = 0.0f);

  m.def(
      "psnr",
      [](const F32Array& a, const F32Array& b) {
        return guarded({}, [&] {
          if (a.ndim() != b.ndim() || !std::equal(a.shape(), a.shape() + a.ndim(), b.shape()))
            throw UsageError("psnr: the images have different shapes");
          return vkunroll::psnr(image_mat(a, "psnr"), image_mat(b, "psnr"));
        });
      },
      py::arg("a"), py::arg("b"),
      "PSNR in dB of two float images in [0, 1] (H x W or H x W x C; values clamped to [0, 1]); identical images give inf.");
  m.def(
      "ssim",
      [](const F32Array& a, const F32Array& b) {
        return guarded({}, [&] {
          if (a.ndim() != b.ndim() || !std::equal(a.shape(), a.shape() + a.ndim(), b.shape()))
            throw UsageError("ssim: the images have different shapes");
          return vkunroll::ssim(image_mat(a, "ssim"), image_mat(b, "ssim"));
        });
      },
      py::arg("a"), py::arg("b"),
      "SSIM (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5, valid positions, mean over channels) of two float "
      "images in [0, 1].");
}

}  // namespace vkunroll::python
