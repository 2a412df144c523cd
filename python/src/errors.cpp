// Library errors -> Python exceptions, keeping the library's message.
//
// The type is chosen here, in one place, from the error's kind (base/error.hpp ErrorKind), its
// class, what the call was given (CallInfo) and, for errors not yet classified, the message:
//   RuntimeError       VulkanError (a failing Vulkan call), device_unavailable, temporary, io, and
//                      any error while creating a device except a selector that matches nothing
//   FileNotFoundError  input_missing; a file the call was given, or one a sequence names, does not exist
//   ValueError         everything else: bad input, named by the library (file, record, option)
#include <filesystem>

#include "common.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll::python {

namespace {

bool contains(const std::string& s, const char* what) { return s.find(what) != std::string::npos; }

// The library's wordings for a file that is not there (readers, sequence loader, safetensors).
bool says_missing_file(const std::string& m) {
  return contains(m, "event file does not exist") || contains(m, "' does not exist") || contains(m, ": no meta.json (generic layout") ||
         contains(m, "No such file or directory");
}

}  // namespace

PyObject* python_error_type(const Error& e, const CallInfo& call) {
  const std::string message = e.what();
  if (dynamic_cast<const VulkanError*>(&e)) return PyExc_RuntimeError;
  switch (e.kind()) {
    case ErrorKind::input_missing: return PyExc_FileNotFoundError;
    case ErrorKind::device_unavailable:  // a selector that matches nothing is the caller's bad input
      return e.text().rfind(opt("device"), 0) == 0 ? PyExc_ValueError : PyExc_RuntimeError;
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
  if (says_missing_file(message)) return PyExc_FileNotFoundError;
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
    } catch (const Error& e) {  // a library error outside guarded(): bad input by default
      PyErr_SetString(PyExc_ValueError, e.spelled(python_keyword).c_str());
    }
  });
}

}  // namespace vkunroll::python
