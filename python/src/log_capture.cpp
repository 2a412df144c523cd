// The library's std::cerr lines (the chosen device, validation messages) -> Python's logging.
// std::cerr is redirected only while a call runs (LogCapture, reference-counted across threads),
// so other C++ code in the process keeps its stderr. A finished line is logged at once, taking the
// GIL: the threads that write hold no lock a GIL holder could wait for (contexts are locked only
// after the GIL is released), so this cannot deadlock.
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <streambuf>

#include "common.hpp"
#include "vkunroll/base/env.hpp"

namespace vkunroll::python {

namespace {

class LineForwarder final : public std::streambuf {
 public:
  void install() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (users_++ == 0) previous_ = std::cerr.rdbuf(this);
  }
  void uninstall() {
    std::string rest;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (--users_ == 0) {
        std::cerr.rdbuf(previous_);
        rest.swap(line_);
      }
    }
    if (!rest.empty()) emit(rest);
  }

 protected:
  int_type overflow(int_type c) override {
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    put(static_cast<char>(c));
    return c;
  }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    for (std::streamsize i = 0; i < n; ++i) put(s[i]);
    return n;
  }

 private:
  void put(char c) {
    std::string done;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (c != '\n') {
        line_ += c;
        return;
      }
      done.swap(line_);
    }
    emit(done);
  }
  static void emit(std::string line) {
    if (line.rfind("vkunroll: ", 0) == 0) line.erase(0, 10);
    const bool error = line.rfind("validation error", 0) == 0 || line.rfind("aborting", 0) == 0;
    const bool warning = line.rfind("validation warning", 0) == 0;
    // Under VKUNROLL_VALIDATION_FATAL the process aborts right after: say it where it is seen.
    // A value it does not take is refused, by name, where a Context reads it.
    static const bool fatal = [] {
      try {
        return env::flag("VKUNROLL_VALIDATION_FATAL");
      } catch (const Error&) {
        return false;
      }
    }();
    if (fatal && (error || warning)) std::fprintf(stderr, "vkunroll: %s\n", line.c_str());
    log_message(error ? kError : warning ? kWarning : kInfo, line);
  }

  std::mutex mutex_;
  int users_ = 0;
  std::streambuf* previous_ = nullptr;
  std::string line_;
};

LineForwarder& forwarder() {
  static LineForwarder* f = new LineForwarder;  // never destroyed: std::cerr may point at it at exit
  return *f;
}

}  // namespace

LogCapture::LogCapture() { forwarder().install(); }
LogCapture::~LogCapture() { forwarder().uninstall(); }

void log_message(int level, const std::string& message) {
  if (!Py_IsInitialized()) return;
  py::gil_scoped_acquire gil;
  try {
    py::module_::import("logging").attr("getLogger")("vkunroll").attr("log")(level, message);
  } catch (py::error_already_set& e) {
    e.discard_as_unraisable("vkunroll logging");
  }
}

}  // namespace vkunroll::python
