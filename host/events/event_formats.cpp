// The event-format table and what reads it here: detection from the signature and extension,
// the guess for a text file that is binary, and the reader dispatch.
#include "vkunroll/host/events/event_formats.hpp"

#include <cctype>
#include <cstring>
#include <filesystem>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll {

namespace {

void read_h5_image(const std::string& path, const uint8_t* data, size_t size, detail::EventSink& sink) {
  detail::read_hdf5(path, data, size, sink);
}

using namespace std::string_view_literals;

// The order of the names in messages and help. Magic bytes are disjoint, so their order is free.
const EventFormat kFormats[] = {
    {.name = "txt", .alias = "csv", .what = "a text/CSV file", .extensions = {".txt", ".csv", ".tsv"}, .streamed = true,
     .read_bytes = detail::read_text, .reader = "reader_text.cpp", .write = write_events_text, .fuzzer = "text"},
    {.name = "h5", .alias = "hdf5", .what = "an HDF5 file", .extensions = {".h5", ".hdf5", ".hdf"},
     .magic = {"\x89HDF\r\n\x1a\n"sv}, .signature = "HDF5 signature", .read_image = read_h5_image,
     .reader = "reader_hdf5.cpp", .write = write_events_hdf5, .fuzzer = "hdf5"},
    {.name = "npy", .what = "a NumPy .npy array", .extensions = {".npy"}, .magic = {"\x93NUMPY"sv},
     .signature = "\\x93NUMPY magic", .read_bytes = detail::read_npy, .reader = "reader_numpy.cpp", .fuzzer = "npy"},
    {.name = "npz", .what = "a zip archive (.npz)", .extensions = {".npz"}, .magic = {"PK\x03\x04"sv, "PK\x05\x06"sv},
     .signature = "'PK' magic", .read_image = detail::read_npz, .reader = "reader_numpy.cpp", .fuzzer = "npz"},
    {.name = "evt2", .what = "a Prophesee EVT 2.0 recording", .extensions = {".raw"}, .evt = "2.0", .percent_header = true,
     .signature = "its '%' header says EVT 2.0", .streamed = true, .read_bytes = detail::read_evt2,
     .reader = "reader_evt.cpp", .fuzzer = "evt2"},
    {.name = "evt21", .what = "a Prophesee EVT 2.1 recording", .extensions = {".raw"}, .evt = "2.1", .percent_header = true,
     .signature = "its '%' header says EVT 2.1", .streamed = true, .read_bytes = detail::read_evt21,
     .reader = "reader_evt.cpp", .fuzzer = "evt21"},
    {.name = "evt3", .what = "a Prophesee EVT 3.0 recording", .extensions = {".raw"}, .evt = "3.0", .percent_header = true,
     .signature = "its '%' header says EVT 3.0", .streamed = true, .read_bytes = detail::read_evt3,
     .reader = "reader_evt.cpp", .fuzzer = "evt3"},
    {.name = "dat", .what = "a Prophesee .dat recording", .extensions = {".dat"}, .percent_header = true,
     .signature = "'%' header lines naming no EVT encoding", .streamed = true, .read_bytes = detail::read_dat,
     .reader = "reader_evt.cpp", .fuzzer = "dat"},
    {.name = "aedat2", .what = "a jAER AEDAT 2.0 recording", .extensions = {".aedat", ".aedat2"}, .magic = {"#!AER-DAT2.0"sv},
     .signature = "'#!AER-DAT2.0' version line", .signature_required = true, .streamed = true,
     .read_bytes = detail::read_aedat2, .reader = "reader_aedat2.cpp", .fuzzer = "aedat2"},
    {.name = "aedat3", .what = "an AEDAT 3.1 recording", .extensions = {".aedat", ".aedat3"}, .magic = {"#!AER-DAT3"sv},
     .signature = "'#!AER-DAT3' version line", .signature_required = true, .streamed = true,
     .read_bytes = detail::read_aedat3, .reader = "reader_aedat3.cpp", .fuzzer = "aedat3"},
    {.name = "aedat4", .what = "an AEDAT 4 recording", .extensions = {".aedat4"}, .magic = {"#!AER-DAT4"sv},
     .signature = "'#!AER-DAT4' version line", .streamed = true, .read_bytes = detail::read_aedat4,
     .reader = "reader_aedat4.cpp", .fuzzer = "aedat4"},
    {.name = "bag", .what = "a ROS 1 bag", .extensions = {".bag"}, .magic = {"#ROSBAG V"sv}, .signature = "'#ROSBAG V' magic",
     .streamed = true, .read_bytes = detail::read_rosbag, .reader = "reader_rosbag.cpp", .fuzzer = "rosbag"},
};

std::string lower_ext(const std::string& path) {
  std::string e = std::filesystem::path(path).extension().string();
  for (auto& c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

bool has_extension(const EventFormat& f, std::string_view ext) {
  for (std::string_view e : f.extensions)
    if (!e.empty() && e == ext) return true;
  return false;
}

const EventFormat* by_magic(const std::vector<uint8_t>& head) {
  for (const EventFormat& f : kFormats)
    for (std::string_view m : f.magic)
      if (!m.empty() && head.size() >= m.size() && std::memcmp(head.data(), m.data(), m.size()) == 0) return &f;
  return nullptr;
}

// The row whose '%' header names encoding `evt` (empty: the '%' format that names none).
const EventFormat* by_evt(const std::string& evt) {
  for (const EventFormat& f : kFormats)
    if (f.percent_header && f.evt == evt) return &f;
  return nullptr;
}

// "EVT 2.0, EVT 2.1 and EVT 3.0" / "evt2, evt21 or evt3": the Prophesee encodings read.
std::string evt_list(bool names) {
  std::string out;
  std::vector<const EventFormat*> rows;
  for (const EventFormat& f : kFormats)
    if (!f.evt.empty()) rows.push_back(&f);
  for (size_t i = 0; i < rows.size(); ++i) {
    out += i == 0 ? "" : i + 1 == rows.size() ? (names ? " or " : " and ") : ", ";
    out += names ? std::string(rows[i]->name) : "EVT " + std::string(rows[i]->evt);
  }
  return out;
}

std::string from_percent_header(detail::ByteSource& src, const std::string& path) {
  const detail::PropheseeHeader h = detail::parse_prophesee_header(src);
  if (h.evt.empty())
    throw DataError(path + ": Prophesee header does not say the encoding (no '% evt' or '% format' line, unknown plugin);"
                           " pass " + opt("format") + " " + evt_list(true));
  if (const EventFormat* f = by_evt(h.evt)) return std::string(f->name);
  throw DataError(path + ": Prophesee encoding EVT " + h.evt + " is not supported (" + evt_list(false) + " are)");
}

// A file whose extension only formats with a required signature share, without any signature.
[[noreturn]] void refuse_unsigned(const std::string& path, const std::string& ext) {
  std::string sigs, names;
  for (const EventFormat& f : kFormats)
    if (has_extension(f, ext)) {
      sigs += std::string(sigs.empty() ? "" : " or ") + std::string(f.signature) + " (" + std::string(f.what.substr(f.what.find(' ') + 1)) + ")";
      names += std::string(names.empty() ? "" : "/") + std::string(f.name);
    }
  throw DataError(path + ": a " + ext + " file without a " + sigs + " (older and headerless versions are not read); pass " +
                  opt("format") + " " + names + " if it is one");
}

}  // namespace

std::span<const EventFormat> event_formats() { return kFormats; }

const EventFormat* find_event_format(std::string_view name) {
  for (const EventFormat& f : kFormats)
    if (f.name == name || (!f.alias.empty() && f.alias == name)) return &f;
  return nullptr;
}

std::string event_format_names(std::string_view sep, bool writable) {
  std::string out;
  for (const EventFormat& f : kFormats)
    if (!writable || f.write) out += std::string(out.empty() ? "" : sep) + std::string(f.name);
  return out;
}

namespace detail {

std::string detect_format(ByteSource& src, const std::string& path) {
  const auto head = read_range(src, 0, 64);
  if (const EventFormat* f = by_magic(head)) return std::string(f->name);
  const std::string ext = lower_ext(path);
  bool by_header = false, unsigned_only = false;
  for (const EventFormat& f : kFormats) {
    if (!has_extension(f, ext)) continue;
    if (f.evt.empty() && !f.signature_required) return std::string(f.name);
    by_header |= !f.evt.empty();
    unsigned_only |= f.signature_required;
  }
  if (unsigned_only && !by_header) refuse_unsigned(path, ext);
  if (by_header || (!head.empty() && head[0] == '%')) return from_percent_header(src, path);
  throw DataError(path + ": cannot tell the event format from the extension '" + ext + "' or the first bytes; pass " +
                  opt("format") + " (" + event_format_names() + ")");
}

BinaryGuess guess_binary_format(ByteSource& src) {
  const auto head = read_range(src, 0, 64);
  auto guess = [](const EventFormat& f) {
    return BinaryGuess{std::string(f.name), std::string(f.extensions[0]), std::string(f.what) + " (" + std::string(f.signature) + ")"};
  };
  if (const EventFormat* f = by_magic(head)) return guess(*f);
  if (!head.empty() && head[0] == '%') {
    const PropheseeHeader h = parse_prophesee_header(src);
    if (const EventFormat* f = by_evt(h.evt)) return guess(*f);
    return {"", "", "a Prophesee EVT " + h.evt + " recording, which is not supported (" + evt_list(false) + " are)"};
  }
  return {"", "", "its first bytes match no event format vkunroll reads"};
}

void read_source(const std::string& format, ByteSource& src, EventSink& sink) {
  const EventFormat& f = format_row(format, src.name());
  if (!f.read_bytes) throw InternalError("read_source: format " + format + " has no byte-source reader (it reads a path)");
  f.read_bytes(src, sink);
}

const EventFormat& format_row(const std::string& format, const std::string& path) {
  if (const EventFormat* f = find_event_format(format)) return *f;
  throw OptionError("format", format, "one of " + event_format_names(),
                    path + ": unknown event format '" + format + "' (expected " + event_format_names() + ")");
}

}  // namespace detail

}  // namespace vkunroll
