// Library errors -> Python exceptions, keeping the library's message.
//
// vkunroll::Error carries no category yet, so the type is chosen here, in one place, from the
// error's class, what the call was given (CallInfo) and the message:
//   RuntimeError       VulkanError (a failing Vulkan call), and any error while creating a device
//                      except a device selector that matches nothing (that is bad input)
//   FileNotFoundError  a file the call was given, or one a sequence names, does not exist
//   ValueError         everything else: bad input, named by the library (file, record, option)
// When base/error.hpp gains categories, python_error_type() is the one function to switch.
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
  if (call.device && message.rfind("--device", 0) != 0) return PyExc_RuntimeError;
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
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });
}

}  // namespace vkunroll::python
