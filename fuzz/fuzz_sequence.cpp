// libFuzzer harness: a blob is a sequence folder (meta.json plus its files, fuzz_sequence.hpp),
// written to a RAM folder and loaded through load_sequence.
#include <unistd.h>

#include "fuzz_sequence.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::filesystem::path dir =
      std::filesystem::path(std::filesystem::exists("/dev/shm") ? "/dev/shm" : "/tmp") /
      ("vkunroll_fuzz_sequence_" + std::to_string(getpid()));
  vkunroll::fuzz::write_sequence_folder(dir, data, size);
  if (!vkunroll::fuzz::sequence_load_survives(dir, data, size)) __builtin_trap();
  return 0;
}
