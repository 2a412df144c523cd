// libFuzzer harness, differential: the index against the full scan (fuzz_index.hpp). A mismatch traps.
#include "fuzz_index.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (!vkunroll::fuzz::index_matches_full_scan(data, size)) __builtin_trap();
  return 0;
}
