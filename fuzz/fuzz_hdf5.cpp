// libFuzzer harness for the HDF5 reader. Feeding raw bytes to libhdf5 would fuzz the HDF5 library
// itself (a known source of crashes we cannot fix here); instead the fuzzer's bytes choose a
// layout (project / DSEC / N x K / DRE), each column's dtype (ints, floats, bool enum, strings),
// lengths (mismatches included), values, size attributes, t_offset, ms_to_idx and the read
// options (hdf5_image_builder.hpp). The file is built in memory (core driver) and read back
// through read_hdf5's file-image path, so the fuzzer explores our layout detection, dtype
// handling, window search and record rules.
#include "fuzz_common.hpp"
#include "hdf5_image_builder.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  vkunroll::fuzz::FuzzBytes fb(data, size);
  const vkunroll::EventReadOptions o = vkunroll::fuzz::options_from(fb);
  const std::vector<uint8_t> image = vkunroll::fuzz::build_file(fb);
  if (image.empty()) return 0;
  vkunroll::EventReadReport report;
  try {
    vkunroll::detail::EventSink sink("fuzz.h5", o, report);
    vkunroll::detail::read_hdf5("fuzz.h5", image.data(), image.size(), sink);
    const vkunroll::EventStream s = sink.finish();
    if (s.size() != report.kept) __builtin_trap();
  } catch (const vkunroll::Error&) {
  }
  return 0;
}
