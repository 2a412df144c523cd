// vkunroll._Session's state, shared by the session's bindings (bind_unroll.cpp) and the job's
// (bind_unroll_job.cpp).
#pragma once
#include <memory>
#include <mutex>
#include <string>

#include "common.hpp"
#include "vkunroll/host/unroll/session.hpp"

namespace vkunroll::python {

struct PySession {
  std::unique_ptr<UnrollSession> session;
  std::string model_path;
  std::mutex mutex;  // one frame at a time (the session's buffers and device queue)
  // Frames go into the model as v^to_model, its results come back as v^(1/to_model): the last
  // job's (plan_physics), for unroll_frame.
  double to_model = 1.0;
};

void bind_unroll_job(py::module_& m);

}  // namespace vkunroll::python
