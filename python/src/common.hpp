// Shared by the binding sources: error translation, library output to Python's logging, the GIL,
// numpy <-> library conversions, and the device context Python objects share.
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/events.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace py = pybind11;

namespace vkunroll {
class Context;
class EventTensorBuilder;
class Backend;
}  // namespace vkunroll

namespace vkunroll::python {

// ---- errors (errors.cpp) -----------------------------------------------------------------------
// What a library call from Python was given: the files it opens (a missing one makes the error a
// FileNotFoundError) and whether it creates a device (its failures are RuntimeErrors).
struct CallInfo {
  std::vector<std::string> paths;
  bool device = false;
};

// Raised by guarded(): the Python type chosen for a library error, with the library's message.
struct ClassifiedError : std::runtime_error {
  ClassifiedError(PyObject* t, const std::string& what) : std::runtime_error(what), type(t) {}
  PyObject* type;
};

// The Python exception type of a library error (see errors.cpp for the rules).
PyObject* python_error_type(const Error& e, const CallInfo& call);
void register_errors(py::module_& m);

// The keyword that spells a library field (base/error.hpp opt()) in Python: the field itself, but
// for vkunroll.stream's events, idle_s and max_events (log_sink.cpp).
std::string python_keyword(std::string_view field);

// Runs f(), turning vkunroll::Error into the ClassifiedError of `call`, its options spelled as keywords.
template <class F>
auto guarded(const CallInfo& call, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const ClassifiedError&) {
    throw;
  } catch (const Error& e) {
    throw ClassifiedError(python_error_type(e, call), e.spelled(python_keyword));
  }
}

// ---- logging (log_sink.cpp) ----------------------------------------------------------------------
// The library's log to logging.getLogger("vkunroll") at its level (progress at DEBUG); installed
// once, when the module is imported.
void install_log_sink();
// logging.getLogger("vkunroll").log(level, message); takes the GIL.
void log_message(int level, const std::string& message);
constexpr int kDebug = 10, kInfo = 20, kWarning = 30, kError = 40;

// Long library work: the GIL released, errors classified.
template <class F>
auto without_gil(const CallInfo& call, F&& f) -> decltype(f()) {
  return guarded(call, [&]() -> decltype(f()) {
    py::gil_scoped_release release;
    return f();
  });
}

// ---- numpy conversions (convert.cpp) ------------------------------------------------------------
// A numpy array that owns `v` (no copy).
template <class T>
py::array_t<T> to_numpy(std::vector<T>&& v, const std::vector<py::ssize_t>& shape) {
  auto* heap = new std::vector<T>(std::move(v));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), owner);
}

using F32Array = py::array_t<float, py::array::c_style | py::array::forcecast>;
using I64Array = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;
using U16Array = py::array_t<uint16_t, py::array::c_style | py::array::forcecast>;
using I8Array = py::array_t<int8_t, py::array::c_style | py::array::forcecast>;

// An exact time from a Python int, float, str ("73000/259", "1e3") or fractions.Fraction.
Rational to_rational(py::handle value, const std::string& what);
std::vector<Rational> to_rationals(const py::sequence& values, const std::string& what);
py::object to_fraction(const Rational& r);

// Events from four equal-length arrays (t us, x, y, p +1/-1) and the sensor size.
EventStream to_event_stream(const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, int width,
                            int height);
// (t, x, y, p, width, height) arrays owning the stream's vectors.
py::tuple from_event_stream(EventStream&& ev);

// An H x W x 3 float32 RGB image -> an OpenCV BGR CV_32FC3 image (a copy), and back.
cv::Mat rgb_to_bgr_mat(const F32Array& rgb, const std::string& what);
py::array_t<float> bgr_mat_to_rgb(const cv::Mat& bgr);

// The reader's report as a dict, and on_bad="error"|"drop"|"sort" (bind_events.cpp).
py::dict report_dict(const EventReadReport& r);
BadEventPolicy parse_on_bad(const std::string& s);
// ---- the device context Python objects share (bind_runtime.cpp) ---------------------------------
struct SharedContext {
  explicit SharedContext(std::unique_ptr<Context> c);
  ~SharedContext();
  std::unique_ptr<Context> ctx;
  std::mutex mutex;  // one user of the device's queue at a time (Python threads run with the GIL released)
  // Made on first use, under `mutex`.
  EventTensorBuilder& builder();
  Backend& backend();

 private:
  std::unique_ptr<EventTensorBuilder> builder_;
  std::unique_ptr<Backend> backend_;
};
using ContextPtr = std::shared_ptr<SharedContext>;

// The drop and reorder counts that a read report (EventReadReport) and a sequence's totals
// (EventTotals) share, under the same keys.
template <class Counts>
void add_drop_counts(py::dict& d, const Counts& c) {
  d["dropped"] = c.dropped();
  d["dropped_out_of_sensor"] = c.dropped_out_of_sensor;
  d["dropped_time_order"] = c.dropped_time_order;
  d["dropped_nan"] = c.dropped_nan;
  d["dropped_unknown_word"] = c.dropped_unknown_word;
  d["dropped_bad_polarity"] = c.dropped_bad_polarity;
  d["reordered"] = c.reordered;
}

void bind_runtime(py::module_& m);
void bind_events(py::module_& m);
void bind_sequence(py::module_& m);
void bind_tensors(py::module_& m);
void bind_model(py::module_& m);
void bind_unroll(py::module_& m);
void bind_sim(py::module_& m);

}  // namespace vkunroll::python
