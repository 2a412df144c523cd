// The sequence loader's fuzz case: one input blob is a sequence folder. The blob up to the first
// "\n@@FILE " line is meta.json; each "\n@@FILE <name>\n" starts another file (frames, ground
// truth, the event file). Names keep to [A-Za-z0-9._-] (a '/' makes one subfolder level, ".."
// is dropped), so an input never writes outside its folder. The folder is loaded through the
// public entry point only (load_sequence), then its events are read; returning or throwing
// vkunroll::Error is correct, anything else is a finding.
#pragma once
#include <cstddef>
#include <cctype>
#include <cstdint>
#include <climits>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll::fuzz {

inline constexpr std::string_view kSequenceFileMark = "\n@@FILE ";

// The name a blob part may have on disk: empty when nothing of it is usable.
inline std::string safe_member_name(std::string_view raw) {
  std::string out, part;
  int depth = 0;
  auto flush = [&] {
    if (!part.empty() && part != "." && part != ".." && depth < 2) {
      out += (out.empty() ? "" : "/") + part;
      ++depth;
    }
    part.clear();
  };
  for (char c : raw.substr(0, 64)) {
    if (c == '/') flush();
    else if (std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-') part += c;
  }
  flush();
  return out;
}

// (name, contents) of every file of the blob; meta.json first.
inline std::vector<std::pair<std::string, std::string>> split_sequence_blob(const uint8_t* data, size_t size) {
  const std::string_view all(reinterpret_cast<const char*>(data), size);
  std::vector<std::pair<std::string, std::string>> files;
  size_t mark = all.find(kSequenceFileMark);
  files.emplace_back("meta.json", std::string(all.substr(0, mark)));
  while (mark != std::string_view::npos && files.size() < 16) {
    const size_t name_begin = mark + kSequenceFileMark.size();
    const size_t name_end = all.find('\n', name_begin);
    if (name_end == std::string_view::npos) break;
    const size_t next = all.find(kSequenceFileMark, name_end);
    const std::string name = safe_member_name(all.substr(name_begin, name_end - name_begin));
    const size_t body_end = next == std::string_view::npos ? all.size() : next;
    if (!name.empty()) files.emplace_back(name, std::string(all.substr(name_end + 1, body_end - name_end - 1)));
    mark = next;
  }
  return files;
}

// Writes the blob's files into `dir` (emptied first).
inline void write_sequence_folder(const std::filesystem::path& dir, const uint8_t* data, size_t size) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::remove_all(dir, ec);
  fs::create_directories(dir);
  for (const auto& [name, body] : split_sequence_blob(data, size)) {
    const fs::path p = dir / name;
    fs::create_directories(p.parent_path(), ec);
    if (fs::is_directory(p, ec)) continue;  // "a" after "a/b": the folder stays
    std::ofstream(p, std::ios::binary).write(body.data(), static_cast<std::streamsize>(body.size()));
  }
}

// Loads the folder (options chosen by the blob's last byte) and reads its events. False only for
// an exception that is not vkunroll::Error (a crash or sanitizer report ends the process anyway).
inline bool sequence_load_survives(const std::filesystem::path& dir, const uint8_t* data, size_t size) {
  const uint8_t k = size ? data[size - 1] : 0;
  SequenceOptions o;
  o.layout = (k & 1) ? SequenceLayout::generic : SequenceLayout::automatic;
  o.check_frame_sizes = !(k & 2);
  o.events.on_bad = (k & 4) ? BadEventPolicy::sort : BadEventPolicy::drop;
  try {
    const Sequence s = load_sequence(dir.string(), o);
    const RowTiming& t = s.frame(0).timing;
    (void)s.read_events(t.first_start().floor(), t.last_end().ceil());  // the frame's window, as unroll reads it
    (void)s.read_events(INT64_MIN, INT64_MAX);
    (void)s.event_totals();
  } catch (const vkunroll::Error&) {
  } catch (...) {
    return false;
  }
  return true;
}

}  // namespace vkunroll::fuzz
