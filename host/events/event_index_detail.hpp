// The per-file index of the streamed event formats (text, EVT 2.0/2.1/3.0, .dat, AEDAT 2/3/4): decoder
// checkpoints every ~32 KiB, each with the time range of the valid records up to the next one, so a
// windowed read resumes near its window instead of re-parsing from the start. Built incrementally
// by the reads themselves (a read that decodes past the indexed part extends it). See
// docs/events.md, "Windowed reads".
#pragma once
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

namespace vkunroll::detail {

// Everything a streamed reader needs to resume at a record boundary: the byte offset of the next
// word/line/packet, the index of the next record, the lines consumed (text), the format's decoder
// state (EVT time high bits and vector base, .dat wrap count, ...) and the sink's time-order state.
struct Checkpoint {
  uint64_t offset = 0;
  uint64_t record = 0;
  uint64_t line = 0;
  std::array<int64_t, 8> state{};
  bool have_last = false;
  int64_t last_t = 0;
};

// Records from `start` up to the next segment's start; t_min/t_max over the records that broke no
// rule (INT64_MAX/INT64_MIN when there are none). Skipping a segment whose range misses a window
// drops nothing of that window.
struct Segment {
  Checkpoint start;
  int64_t t_min = std::numeric_limits<int64_t>::max();
  int64_t t_max = std::numeric_limits<int64_t>::min();
};

struct StreamIndex {
  static constexpr uint64_t kStride = uint64_t(1) << 15;  // bytes between checkpoints
  std::vector<Segment> segments;  // complete, contiguous from the data start
  std::optional<Checkpoint> tail; // where the indexed part ends (the next segment's start)
  bool complete = false;          // the segments cover the whole file
  std::shared_ptr<const void> header;  // a reader's parsed header, kept between reads (text: its layout)
};

// Disjoint, sorted [lo, hi) ranges of record indices (what a reader's totals already counted).
class RecordRanges {
 public:
  void add(uint64_t lo, uint64_t hi);
  const std::vector<std::pair<uint64_t, uint64_t>>& ranges() const { return r_; }

 private:
  std::vector<std::pair<uint64_t, uint64_t>> r_;
};

// The first byte offset at or after which the next checkpoint goes, for a reader at `offset` whose
// data starts at `base`: checkpoints fall on the first record boundary at or after each multiple of
// the stride, so a reader resumed at a checkpoint meets the same later checkpoints.
inline uint64_t next_checkpoint_offset(uint64_t offset, uint64_t base) {
  const uint64_t k = offset >= base ? (offset - base) / StreamIndex::kStride : 0;
  return base + (k + 1) * StreamIndex::kStride;
}

}  // namespace vkunroll::detail
