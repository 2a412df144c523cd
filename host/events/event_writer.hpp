// Writers of the project's event layouts (sequence-format.md); read back by read_events.
#pragma once
#include <string>

#include "vkunroll/base/events.hpp"

namespace vkunroll {

// HDF5: events/{t,x,y,p} with t int64 us, x/y uint16, p int8 1/0 (chunked), and int64 attributes
// width/height on the `events` group. Throws vkunroll::Error naming the file on failure, and
// refuses streams with mismatched arrays, out-of-sensor events, polarity other than +1/-1 or
// decreasing t.
void write_events_hdf5(const std::string& path, const EventStream& events);
// Text: "# width W height H" comment, then one "t x y p" line per event (t in us, p 1/0).
void write_events_text(const std::string& path, const EventStream& events);

// What marks an event file as vkunroll's (the output rule, host/unroll/output_file.hpp, replaces
// only marked files): an HDF5 root attribute, the text file's first line.
constexpr const char* kEventFileMark = "written_by_vkunroll";
constexpr const char* kTextEventMark = "# vkunroll events";
bool event_file_written_by_vkunroll(const std::string& path);

}  // namespace vkunroll
