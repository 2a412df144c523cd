// libFuzzer harness: the live-stream decoder against the offline .raw reader (fuzz_follow.hpp); a
// difference, a crash or a sanitizer report is a finding.
#include "fuzz_follow.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (!vkunroll::fuzz::follow_matches_offline(data, size)) __builtin_trap();
  return 0;
}
