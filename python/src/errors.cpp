// Library errors -> Python exceptions, keeping the library's message.
//
// The type is chosen here, in one place, from the error's kind (base/error.hpp ErrorKind, the
// table in docs/errors.md) and its class, never from its message:
//   RuntimeError       VulkanError (a failing Vulkan call), device_unavailable, internal, temporary, io
//   FileNotFoundError  input_missing
//   ValueError         usage, data: bad input, named by the library (file, record, option); and a
//                      device selector (opt("device")) that matches nothing
// An error the library has not classified yet (the reviewed list, tools/checks/bare_errors_allowed.txt)
// is a RuntimeError while creating a device, FileNotFoundError when a path the call was given does
// not exist, else ValueError.
#include <filesystem>

#include "common.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll::python {

PyObject* python_error_type(const Error& e, const CallInfo& call) {
  if (dynamic_cast<const VulkanError*>(&e)) return PyExc_RuntimeError;
  switch (e.kind()) {
    case ErrorKind::input_missing: return PyExc_FileNotFoundError;
    case ErrorKind::device_unavailable:  // a selector that matches nothing is the caller's bad input
      return e.text().rfind(opt("device"), 0) == 0 ? PyExc_ValueError : PyExc_RuntimeError;
    case ErrorKind::internal:
    case ErrorKind::temporary:
    case ErrorKind::io: return PyExc_RuntimeError;
    case ErrorKind::usage:
    case ErrorKind::data: return PyExc_ValueError;
    case ErrorKind::unspecified: break;
  }
  if (call.device && e.text().rfind(opt("device"), 0) != 0) return PyExc_RuntimeError;
  std::error_code ec;
  for (const std::string& p : call.paths)
    if (!p.empty() && !std::filesystem::exists(p, ec)) return PyExc_FileNotFoundError;
  return PyExc_ValueError;
}

void register_errors(py::module_& m) {
  (void)m;
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ClassifiedError& e) {
      // str(e) is the library's message (an OSError given a filename would reformat it).
      PyErr_SetString(e.type, e.what());
    } catch (const VulkanError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    } catch (const Error& e) {  // a library error outside guarded(): by its kind as well
      PyErr_SetString(python_error_type(e, CallInfo{}), e.spelled(python_keyword).c_str());
    }
  });
}

}  // namespace vkunroll::python
