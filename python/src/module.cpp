// The compiled part of `import vkunroll` (vkunroll._vkunroll). The public API, its docstrings and
// the numpy-side conversions are in python/vkunroll/*.py; these are the library entry points.
#include "common.hpp"
#include "vkunroll/host/unroll/output_paths.hpp"

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
  // The output table (host/unroll/output_paths.hpp), for the tests that try every entry.
  m.def("_output_paths", [] {
    pybind11::list out;
    for (const vkunroll::OutputPath& p : vkunroll::output_paths())
      out.append(pybind11::dict(pybind11::arg("id") = p.id, pybind11::arg("front_end") = p.front_end, pybind11::arg("command") = p.command,
                          pybind11::arg("field") = p.field, pybind11::arg("spelled") = p.spelled,
                          pybind11::arg("shape") = p.shape == vkunroll::OutputShape::file ? "file" : "folder"));
    return out;
  });
}
