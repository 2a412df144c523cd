#include "host/event_reader_detail.hpp"
namespace vkunroll::detail {
void read_evt2(ByteSource& s, EventSink&) { throw Error(s.name() + ": EVT2 reader not built yet"); }
void read_evt3(ByteSource& s, EventSink&) { throw Error(s.name() + ": EVT3 reader not built yet"); }
void read_dat(ByteSource& s, EventSink&) { throw Error(s.name() + ": DAT reader not built yet"); }
void read_aedat4(ByteSource& s, EventSink&) { throw Error(s.name() + ": AEDAT4 reader not built yet"); }
void read_npy(ByteSource& s, EventSink&) { throw Error(s.name() + ": npy reader not built yet"); }
void read_npz(const std::string& p, const uint8_t*, size_t, EventSink&) { throw Error(p + ": npz reader not built yet"); }
PropheseeHeader parse_prophesee_header(ByteSource& s) { throw Error(s.name() + ": Prophesee reader not built yet"); }
}
