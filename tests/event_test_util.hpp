// Helpers shared by the event reader tests: a temp folder of this process, file writers, stream
// comparison, error expectations, Debian's Python.
#pragma once
#include <gtest/gtest.h>
#include <unistd.h>
#include <zip.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll::evtest {

// A folder of this test process; removed at exit by the OS's tmp cleaning, not relied on.
inline std::string tmp(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("vkunroll_readers_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

inline void write_file(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
}

inline void write_bytes(const std::string& path, const std::vector<uint8_t>& b) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}

inline std::vector<uint8_t> read_bytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::vector<uint8_t>((std::istreambuf_iterator<char>(f)), {});
}

// A zip archive (.npz) of named members, stored or deflated (as numpy.savez / savez_compressed).
inline void write_npz(const std::string& path, const std::vector<std::pair<std::string, std::vector<uint8_t>>>& members,
                      bool deflate) {
  int err = 0;
  zip_t* z = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
  ASSERT_NE(z, nullptr) << path;
  for (const auto& [name, bytes] : members) {
    zip_source_t* s = zip_source_buffer(z, bytes.data(), bytes.size(), 0);
    const zip_int64_t i = zip_file_add(z, name.c_str(), s, ZIP_FL_OVERWRITE);
    zip_set_file_compression(z, zip_uint64_t(i), deflate ? ZIP_CM_DEFLATE : ZIP_CM_STORE, 6);
  }
  ASSERT_EQ(zip_close(z), 0) << path;
}

// The message of the vkunroll::Error `f` throws ("" when it does not throw).
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Expects read_events to throw vkunroll::Error whose message contains every fragment.
inline void expect_error(const std::string& path, const EventReadOptions& o, std::initializer_list<const char*> fragments) {
  try {
    read_events(path, o);
    ADD_FAILURE() << path << ": expected an error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const char* f : fragments) EXPECT_NE(msg.find(f), std::string::npos) << "missing '" << f << "' in: " << msg;
  }
}

inline void expect_same(const EventStream& a, const EventStream& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a.t[i], b.t[i]) << "event " << i;
    ASSERT_EQ(a.x[i], b.x[i]) << "event " << i;
    ASSERT_EQ(a.y[i], b.y[i]) << "event " << i;
    ASSERT_EQ(a.p[i], b.p[i]) << "event " << i;
  }
}

inline bool python_has(const std::string& modules) {
  const std::string cmd = "/usr/bin/python3 -c 'import " + modules + "' >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

inline void run_python(const std::string& code) {
  const std::string script = tmp("script.py");
  write_file(script, code);
  ASSERT_EQ(std::system(("/usr/bin/python3 " + script).c_str()), 0) << code;
}

}  // namespace vkunroll::evtest
