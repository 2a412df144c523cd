// libFuzzer harness: the .npz reader (libzip from memory + our .npy parser) on arbitrary bytes.
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return vkunroll::fuzz::run_reader(data, size, "fuzz.npz", [&](vkunroll::detail::ByteSource&, vkunroll::detail::EventSink& sink) {
    vkunroll::detail::read_npz("fuzz.npz", data, size, sink);
  });
}
