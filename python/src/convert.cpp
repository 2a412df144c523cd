// numpy and Python values <-> the library's types.
#include <cmath>
#include <cstring>

#include <opencv2/imgproc.hpp>

#include "common.hpp"

namespace vkunroll::python {

Rational to_rational(py::handle v, const std::string& what) {
  if (v.is_none()) throw UsageError(what + ": expected a time in microseconds, got None");
  if (py::isinstance<py::bool_>(v)) throw UsageError(what + ": expected a number, got a bool");
  if (py::isinstance<py::str>(v)) return Rational::parse(v.cast<std::string>(), what);
  if (py::isinstance<py::int_>(v) || (py::hasattr(v, "numerator") && py::hasattr(v, "denominator") && !py::isinstance<py::float_>(v))) {
    // int, numpy integers and fractions.Fraction: exact (through text, so big values are not truncated).
    const std::string num = py::str(v.attr("numerator")), den = py::str(v.attr("denominator"));
    return Rational::parse(den == "1" ? num : num + "/" + den, what);
  }
  double d = 0;
  try {
    d = py::float_(py::reinterpret_borrow<py::object>(v));
  } catch (py::error_already_set&) {
    throw UsageError(what + ": expected a number, a string like \"73000/259\" or a fractions.Fraction, got " +
                std::string(py::str(py::type::of(v).attr("__name__"))));
  }
  if (!std::isfinite(d)) throw UsageError(what + ": " + std::to_string(d) + " is not a finite time");
  return Rational::from_double(d);
}

std::vector<Rational> to_rationals(const py::sequence& values, const std::string& what) {
  std::vector<Rational> out;
  for (size_t i = 0; i < values.size(); ++i) out.push_back(to_rational(values[i], what + "[" + std::to_string(i) + "]"));
  return out;
}

py::object to_fraction(const Rational& r) { return py::module_::import("fractions").attr("Fraction")(r.str()); }

EventStream to_event_stream(const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, int width,
                            int height) {
  const size_t n = static_cast<size_t>(t.size());
  if (static_cast<size_t>(x.size()) != n || static_cast<size_t>(y.size()) != n || static_cast<size_t>(p.size()) != n)
    throw UsageError("events: fields t, x, y, p have different lengths (" + std::to_string(t.size()) + ", " +
                std::to_string(x.size()) + ", " + std::to_string(y.size()) + ", " + std::to_string(p.size()) + ")");
  EventStream ev;
  ev.width = width;
  ev.height = height;
  ev.t.assign(t.data(), t.data() + n);
  ev.x.assign(x.data(), x.data() + n);
  ev.y.assign(y.data(), y.data() + n);
  ev.p.assign(p.data(), p.data() + n);
  return ev;
}

py::tuple from_event_stream(EventStream&& ev) {
  const auto n = static_cast<py::ssize_t>(ev.size());
  return py::make_tuple(to_numpy(std::move(ev.t), {n}), to_numpy(std::move(ev.x), {n}), to_numpy(std::move(ev.y), {n}),
                        to_numpy(std::move(ev.p), {n}), ev.width, ev.height);
}

cv::Mat rgb_to_bgr_mat(const F32Array& rgb, const std::string& what) {
  if (rgb.ndim() != 3 || rgb.shape(2) != 3)
    throw UsageError(what + ": expected an H x W x 3 float image, got shape " + std::string(py::str(py::tuple(py::cast(
                    std::vector<py::ssize_t>(rgb.shape(), rgb.shape() + rgb.ndim()))))));
  const int h = static_cast<int>(rgb.shape(0)), w = static_cast<int>(rgb.shape(1));
  const cv::Mat view(h, w, CV_32FC3, const_cast<float*>(rgb.data()));
  cv::Mat bgr;
  cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

py::array_t<float> bgr_mat_to_rgb(const cv::Mat& bgr) {
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  if (!rgb.isContinuous()) rgb = rgb.clone();
  py::array_t<float> out({static_cast<py::ssize_t>(rgb.rows), static_cast<py::ssize_t>(rgb.cols), py::ssize_t(3)});
  std::memcpy(out.mutable_data(), rgb.ptr<float>(), sizeof(float) * rgb.total() * 3);
  return out;
}

}  // namespace vkunroll::python
