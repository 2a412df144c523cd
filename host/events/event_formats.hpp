// The event formats vkunroll reads, in one table (event_formats.cpp). Detection, the reader
// dispatch, the CLI's --format and help, Python's format= and vkunroll.EVENT_FORMATS, the fuzz
// corpus test and docs/events.md's format table are read from it or checked against it
// (tests/test_event_formats.cpp, tests/python/test_event_formats.py). A new format is one reader
// file and one row here (docs/events.md, "Adding a format").
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "vkunroll/base/events.hpp"

namespace vkunroll {

namespace detail {
class ByteSource;
class EventSink;
}  // namespace detail

struct EventFormat {
  std::string_view name;   // EventReadOptions::format, --format, Python's format=, EventReadReport::format
  std::string_view alias;  // a second name taken for it ("hdf5", "csv"), or empty
  std::string_view what;   // the kind of file, with its article: "an HDF5 file", for messages
  std::array<std::string_view, 3> extensions;  // lower case with the dot; empty slots unused
  // What identifies the file. magic: bytes at offset 0 (empty slots unused). evt: a Prophesee '%'
  // header naming this encoding ("3.0"). percent_header: the file starts with Prophesee '%' lines.
  std::array<std::string_view, 2> magic;
  std::string_view evt;
  bool percent_header = false;
  std::string_view signature;  // the signature in words ("HDF5 signature"), empty when there is none
  // The extension is shared with another format (.aedat): a file with it but without the signature
  // is refused by name instead of being read as this format.
  bool signature_required = false;
  bool streamed = false;  // read front to back (windows through the index); else random access
  // The reader: a byte source (streamed formats, npy) or a path/in-memory image (h5, npz); one is set.
  void (*read_bytes)(detail::ByteSource& src, detail::EventSink& sink) = nullptr;
  void (*read_image)(const std::string& path, const uint8_t* data, size_t size, detail::EventSink& sink) = nullptr;
  std::string_view reader;  // its source file under host/events/
  // The writer (vkunroll's own layouts), or null; Python's write_events(format=) takes these.
  void (*write)(const std::string& path, const EventStream& events) = nullptr;
  std::string_view fuzzer;  // the harness fuzz/fuzz_<fuzzer>.cpp and its corpus tests/fuzz_corpus/<fuzzer>/
};

// Every format, in the order messages and help list them.
std::span<const EventFormat> event_formats();
// The format named `name` (or its alias), or null.
const EventFormat* find_event_format(std::string_view name);
// "txt, h5, npy, ..." (the names, `sep` between them); writable: only formats with a writer.
std::string event_format_names(std::string_view sep = ", ", bool writable = false);

}  // namespace vkunroll
