// ROS 1 bag files (format 2.0), read without the ROS libraries: the record layer (op-coded records
// of "name=value" header fields), chunks (none, bz2, lz4 frames), connections and messages.
// rosbag_container.cpp reads the container; reader_rosbag.cpp decodes the event messages.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

// One connection record: a topic and the message type the bag says it carries.
struct BagConnection {
  uint32_t id = 0;
  std::string topic, type, md5sum, definition;
};

// The bag header and every connection, from the index section at the end, or (a bag that was not
// closed, or cut short) from a scan of all chunks.
struct BagInfo {
  uint64_t data_start = 0;   // first record after the bag header record
  uint64_t index_pos = 0;    // where the index section starts (0 or past the end: none)
  bool indexed = false;      // connections came from the index section
  uint32_t chunk_count = 0;  // as the header says
  std::map<uint32_t, BagConnection> connections;
  std::vector<std::string> notes;
};

// What the record scan hands over. Each callback returns false to stop the scan.
class BagVisitor {
 public:
  virtual ~BagVisitor() = default;
  // Before each top-level record (a chunk, an index record, ...) at file offset `offset`.
  virtual bool top_record(uint64_t offset) = 0;
  virtual void connection(const BagConnection& c) = 0;
  // A message record of connection `conn`, recorded at `time_ns`; `chunk_offset` is the file
  // offset of the chunk that holds it (for messages: compressed chunks have no message offsets).
  virtual bool message(uint32_t conn, uint64_t time_ns, const uint8_t* data, size_t size, uint64_t chunk_offset) = 0;
  // A record the scan cannot use at file offset `offset`: the file ends inside it (a bag cut
  // short), a chunk that does not decompress, a record cut short inside a chunk, an unknown op.
  // The scan goes on after it where it can.
  virtual void damaged(uint64_t offset, const std::string& what) = 0;
};

// Reads "#ROSBAG V2.0" and the bag header, then the connections (see BagInfo). Throws Error
// naming the file and byte for what is not a bag 2.0.
BagInfo read_bag_info(ByteSource& src);

// Scans the top-level records from `offset` (a record boundary: data_start or a checkpoint) to the
// end of the file, decompressing each chunk (at most 256 MiB) and visiting its records in order.
// Records at and after a valid index_pos (connections, chunk infos) are visited too.
void scan_bag_records(ByteSource& src, uint64_t offset, BagVisitor& visitor);

// The event topic a read with `asked` (EventReadOptions::events_topic) decodes; throws the read's
// Error when there is none, several, or its type or md5 is not known (reader_rosbag.cpp).
std::string bag_event_topic(ByteSource& src, const std::string& asked);

// Little-endian readers of a message's bytes with bounds checks: a read past the end throws
// Error(what + ": message ends early").
struct RosCursor {
  const uint8_t* p;
  size_t n, at = 0;
  const std::string* what;
  void need(size_t k) const;
  uint8_t u8() { need(1); return p[at++]; }
  uint16_t u16();
  uint32_t u32();
  uint64_t u64();
  std::string string();  // uint32 length + bytes
  size_t left() const { return n - at; }
};

}  // namespace vkunroll::detail
