// A generic sequence (meta.json, sequence-format.md) from a ROS bag alone: the RS frames from a
// sensor_msgs/Image topic written as PNGs, their t0 from each message's header stamp, the row
// timing from options (a bag does not hold it), and meta.json's `events` naming the bag itself (its
// events are read in place, no copy), and the frames' sensor_msgs/CameraInfo, when the bag has one,
// in meta.json's source. `vkunroll bag-sequence`; docs/rosbags.md.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "vkunroll/base/row_timing.hpp"

namespace vkunroll {

struct BagSequenceOptions {
  std::string frames_topic;  // empty: the bag's only sensor_msgs/Image topic
  std::string events_topic;  // empty: the bag's only event topic (checked here)
  Rational line_delay_us, exposure_us;
  Readout readout = Readout::top_down;
  Rational t0_offset_us = 0;  // added to each header stamp (a driver that stamps mid-exposure: -exposure/2)
  uint64_t max_frames = 0;    // 0: all
};

struct BagSequenceReport {
  std::string frames_topic, events_topic, encoding;
  std::string camera_info_topic;  // the sensor_msgs/CameraInfo recorded in meta.json's source (empty: none)
  uint64_t frames = 0;
  int width = 0, height = 0;
  std::vector<std::string> notes;
};

// Writes `out_dir`/rs/NNNNNN.png and meta.json (last). Throws Error naming the bag, topic, message
// or file: no image topic, an image encoding other than mono8/mono16/rgb8/bgr8/rgba8/bgra8 (and
// their 8UC1/16UC1 names), frames of changing size, stamps that do not increase.
BagSequenceReport write_bag_sequence(const std::string& bag, const std::string& out_dir, const BagSequenceOptions& o);

}  // namespace vkunroll
