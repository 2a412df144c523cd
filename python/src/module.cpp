// The compiled part of `import vkunroll` (vkunroll._vkunroll). The public API, its docstrings and
// the numpy-side conversions are in python/vkunroll/*.py; these are the library entry points.
#include "common.hpp"

PYBIND11_MODULE(_vkunroll, m) {
  namespace vp = vkunroll::python;
  m.doc() = "vkunroll's C++ library (internal; use the `vkunroll` package).";
  m.attr("__version__") = VKUNROLL_VERSION;
  vp::register_errors(m);
  vp::install_log_sink();
  vp::bind_runtime(m);
  vp::bind_events(m);
  vp::bind_sequence(m);
  vp::bind_tensors(m);
  vp::bind_model(m);
  vp::bind_unroll(m);
  vp::bind_sim(m);
}
