// libFuzzer harness: `vkunroll bag-sequence` (write_bag_sequence) on arbitrary bytes as a bag: the
// container, the sensor_msgs/Image and CameraInfo decoders and the PNG writes. The bytes go to a
// temporary file (the converter reads a path); a vkunroll::Error is fine, anything else a finding.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/rosbag_sequence.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  namespace fs = std::filesystem;
  static const fs::path dir = fs::temp_directory_path() / ("fuzz_bag_sequence_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "out");
  const fs::path bag = dir / "in.bag";
  if (std::FILE* f = std::fopen(bag.c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  vkunroll::BagSequenceOptions o;
  o.line_delay_us = vkunroll::Rational(10);
  o.exposure_us = vkunroll::Rational(100);
  o.max_frames = 4;
  try {
    (void)vkunroll::write_bag_sequence(bag.string(), (dir / "out").string(), o);
  } catch (const vkunroll::Error&) {
  }
  return 0;
}
