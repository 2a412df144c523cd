#include "vkunroll/host/unroll/output_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string_view>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

// A safetensors file's __metadata__ names vkunroll as its writer.
bool safetensors_marked(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char len[8] = {};
  if (!in.read(reinterpret_cast<char*>(len), 8)) return false;
  uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = n << 8 | len[i];
  if (n < 2 || n > (100u << 20)) return false;
  std::string header(n, '\0');
  if (!in.read(header.data(), std::streamsize(n)) || header[0] != '{') return false;
  const nlohmann::json j = nlohmann::json::parse(header, nullptr, false);
  if (j.is_discarded() || !j.contains("__metadata__") || !j["__metadata__"].is_object()) return false;
  const auto& md = j["__metadata__"];
  return md.contains(kSafetensorsWrittenBy) && md[kSafetensorsWrittenBy].is_string() &&
         md[kSafetensorsWrittenBy].get<std::string>().rfind(kWrittenByVkunroll, 0) == 0;
}

// A Chrome trace vkunroll wrote starts with these bytes (runtime/trace.cpp, Trace::json; the
// registry's test checks a real trace against them).
constexpr std::string_view kTraceHead =
    "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[\n{\"name\":\"process_name\",\"ph\":\"M\",\"pid\":1,\"tid\":0,\"args\":{\"name\":\"vkunroll\"}}";

bool starts_with_bytes(const std::string& path, std::string_view head) {
  std::ifstream in(path, std::ios::binary);
  std::string got(head.size(), '\0');
  return in.read(got.data(), std::streamsize(got.size())) && got == head;
}

}  // namespace

bool written_by_vkunroll(const std::string& path, OutputMark mark) {
  switch (mark) {
    case OutputMark::written_by: return safetensors_marked(path) || event_file_written_by_vkunroll(path);
    case OutputMark::trace: return starts_with_bytes(path, kTraceHead);
    case OutputMark::conv_table: return is_conv_choice_table(path);
    case OutputMark::manifest: return false;  // a folder's: OutputFolder checks it
  }
  return false;
}

void check_output_file_rule(const std::string& path, const OutputPath& spec, ExistingOutput existing,
                            const std::vector<std::pair<std::string, std::string>>& inputs) {
  const std::string field = spec.field;
  if (path.empty()) throw OptionError(field, "", "an empty path (name the file to write)");
  check_output_apart(path, field, inputs);
  std::error_code ec;
  const auto st = fs::symlink_status(path, ec);
  if (fs::is_symlink(st))
    throw OptionError(field, path,
                      "is a symbolic link; the output is renamed over the name, which would replace the link, not what it "
                      "points to: name the file itself");
  if (const std::string folder = enclosing_output_folder(path); !folder.empty())
    throw OptionError(field, path,
                      "lies inside the vkunroll output folder " + folder + " (its manifest lists what it holds; a file added "
                      "there would stop it being replaced): choose another " + opt(field));
  if (!fs::exists(st)) return;
  if (!fs::is_regular_file(st))
    throw OptionError(field, path,
                      std::string("exists and is not a regular file (") + (fs::is_directory(st) ? "a folder" : "a device, FIFO or socket") +
                          "); the output is written under a temporary name and renamed over it: name a file");
  if (existing == ExistingOutput::refuse)
    throw OptionError(field, path, "the file exists; " + opt("overwrite") + " replaces it (only a file vkunroll wrote is replaced)");
  if (!written_by_vkunroll(path, spec.mark))
    throw OptionError(field, path,
                      std::string("the file exists and vkunroll did not write it (") +
                          (spec.mark == OutputMark::trace        ? "not a vkunroll trace"
                           : spec.mark == OutputMark::conv_table ? "not a vkunroll conv choice table"
                                                                 : "no vkunroll mark in it") +
                          "); refusing to replace it (move it away or choose another " + opt(field) + ")");
}

void check_output_folder_writable(const std::string& path, const std::string& field) {
  std::error_code ec;
  const fs::path folder = fs::absolute(path, ec).parent_path();
  auto fail = [&](const std::string& what, const std::string& why) {
    throw IoError(opt(field) + " " + path + ": " + what + " " + folder.string() + " (" + why + ")");
  };
  if (!fs::is_directory(folder, ec)) {
    fs::create_directories(folder, ec);
    if (ec) fail("cannot create the folder", ec.message());
  }
  const std::string probe = staged_file_name((folder / ".vkunroll-probe").string());
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) fail("cannot write in the folder", std::strerror(errno));
  ::close(fd);
  ::unlink(probe.c_str());
}

std::string staged_file_name(const std::string& path) {
  const fs::path p(path);
  return (p.parent_path() / ("." + p.filename().string() + ".partial-" + std::to_string(::getpid()))).string();
}

void commit_staged_file(const std::string& tmp, const std::string& path) {
  const int fd = ::open(tmp.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int e = errno;
    discard_staged_file(tmp);
    throw IoError(path + ": cannot rename the written file into place (" + std::string(std::strerror(e)) + ")");
  }
}

void discard_staged_file(const std::string& tmp) {
  std::error_code ec;
  fs::remove(tmp, ec);
}

}  // namespace vkunroll
