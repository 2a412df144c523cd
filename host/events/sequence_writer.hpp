// Writer of the generic sequence layout (sequence-format.md) from frames, timing and events held in
// memory: what users write their own recordings with (the Python bindings' Sequence.create). The
// simulator writes its own (host/sim/recording.hpp: synthetic provenance in `source`).
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/base/events.hpp"
#include "vkunroll/base/row_timing.hpp"

namespace vkunroll {

// An image as stored in a PNG: rows of interleaved channels, 8-bit (values in `u8`) or 16-bit (`u16`).
struct SequenceImage {
  int width = 0, height = 0;
  int channels = 3;       // 1 (gray) or 3 (RGB order)
  int bit_depth = 8;      // 8 or 16
  std::vector<uint8_t> u8;
  std::vector<uint16_t> u16;
};

struct SequenceWriteFrame {
  SequenceImage image;
  RowTiming timing;  // rows must equal the sensor height; line delay and readout equal for all frames
};

struct SequenceWriteGroundTruth {
  SequenceImage image;
  Rational t_us;
};

struct SequenceWriteSpec {
  int width = 0, height = 0;
  std::vector<SequenceWriteFrame> frames;
  std::vector<SequenceWriteGroundTruth> ground_truth;
  EventStream events;                 // inside the sensor, polarity +1/-1, t non-decreasing
  std::string events_format = "h5";   // h5 | txt
  std::string source_json;            // optional JSON object text stored as meta.json's `source`
};

// Writes rs/NNNNNN.png, gs/NNNNNN.png, events.h5 (or events.txt) and meta.json under `dir`
// (created if needed; meta.json last, through a temporary file, so a failed write leaves no folder
// that loads as a sequence). Times that a float64 does not hold exactly are written as exact
// strings ("73000/259"), which load_sequence reads back exactly. Throws Error naming the frame,
// field or file before anything is written when the spec is inconsistent.
void write_generic_sequence(const std::string& dir, const SequenceWriteSpec& spec);

}  // namespace vkunroll
