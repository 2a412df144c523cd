// libFuzzer harness: the aedat3 reader on arbitrary bytes (see fuzz_common.hpp).
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return vkunroll::fuzz::run_reader(data, size, "fuzz.aedat3", vkunroll::detail::read_aedat3);
}
