// libFuzzer harness: the ROS bag reader on arbitrary bytes (see fuzz_common.hpp): the container
// (records, chunks in none/bz2/lz4, connections, the index section) and the message decoders.
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return vkunroll::fuzz::run_reader(data, size, "fuzz.bag", vkunroll::detail::read_rosbag);
}
