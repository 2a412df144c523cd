// The generic op test, after ncnn's test_layer: every case of an op runs on both backends (the
// Vulkan kernel and its CPU reference), in each precision, with canaries around every binding, and
// is judged by one tolerance rule. The kernel tests (test_conv2d.cpp, test_elementwise.cpp, ...)
// describe their cases; run_op_test runs them.
#pragma once
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "kernel_test_util.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::optest {

// An output the op writes: a slice of `shape` inside a larger tensor of canaries
// (ktest::canary_slice: `c_before` channels before it, `c_after` after it, a batch item either side).
struct OutputSpec {
  Shape shape;
  int64_t c_before = 1, c_after = 2;
  // fp32: this output's tolerance is the rule's times this (an op that multiplies by 100 multiplies
  // its rounding error too); fp16's relative rule needs no scale.
  double fp32_tolerance_scale = 1;
};

// The CPU side of one run: the inputs (in fp16 runs as the rule says) and the outputs among canaries.
struct HostRun {
  Precision precision = Precision::fp32;
  std::vector<HostTensor> inputs;
  std::vector<HostTensor> outputs;          // the whole canary tensors
  std::vector<ktest::CanarySlice> slices;   // where each output's slice lies in them
  HostSliceOut out(size_t i) { return slices[i].of(outputs[i]); }
  // Output i's slice as an input of a later op of the case.
  HostSlice written(size_t i) const {
    return HostSlice(outputs[i], slices[i].c0, slices[i].c, slices[i].n0, slices[i].n);
  }
};

// The device side of one run: the same tensors on the device, and the stream to record into.
struct DeviceRun {
  Context& ctx;
  Precision precision;
  CommandStream& stream;
  std::vector<Tensor> inputs;
  std::vector<Tensor> outputs;
  const std::vector<ktest::CanarySlice>& slices;
  Slice out(size_t i) const { return slices[i].of(outputs[i]); }
  std::shared_ptr<void> keep_alive;  // what the recorded dispatches use (an op object) until they ran
};

struct OpCase {
  std::string what;                 // names the case in failures: shapes and parameters
  std::vector<HostTensor> inputs;   // the tensors the op reads (the slices of them the case chooses)
  std::vector<OutputSpec> outputs;  // the slices it writes
  std::function<void(HostRun&)> reference;
  // Records the op (the case's ops, in order); false when it does not apply to the case.
  std::function<bool(DeviceRun&)> record;
  // Further checks of the reference's and the device's outputs (optional).
  std::function<void(const HostRun& reference, const std::vector<HostTensor>& device)> check;
};

// The tolerance rule (docs/kernels.md, "Precision"): the largest |device - reference| inside each
// output slice is at most `fp32` / `fp16`. fp16_relative: measured against max(1, max |reference|)
// over the slice (ops whose fp16 error grows with the values' range). fp16_reference_on_half_inputs:
// the reference reads the inputs as fp16 stores them (data movement, exact there); else the fp32
// inputs, so that the rule bounds the whole fp16 error.
struct Tolerance {
  double fp32 = 0, fp16 = 0;
  bool fp16_relative = false;
  bool fp16_reference_on_half_inputs = false;
};

struct OpTest {
  std::string op;  // names the op (and variant) in failures and the [ measured ] lines
  std::vector<OpCase> cases;
  Tolerance tolerance;
  std::vector<Precision> precisions{Precision::fp32, Precision::fp16};
  uint32_t seed = 1;  // the canary slices' random contents (which the op must overwrite)
  // An Error of the op for which this is true is a refusal by rule, counted, not a failure (the limits
  // matrix: an error naming a lowered limit). Without it, only fp16's refusal on a device without
  // 16-bit storage is.
  std::function<bool(const std::string& message)> refusal;
};

struct OpTestReport {
  int ran[2] = {0, 0}, skipped[2] = {0, 0};  // by precision (fp32, fp16)
  int refused[2] = {0, 0};  // fp16 cases refused by name on a device without 16-bit storage (counted in skipped)
  double worst[2] = {0, 0};
  std::vector<double> error[2];  // per case; -1 where it was skipped
};

// Runs every case of `test` in each of its precisions on `ctx`, each case as its own submit, and
// fails the current gtest test where an output is over the tolerance, a canary around an output was
// overwritten, an input changed, the op threw, or no case applied in a precision. Prints one
// "[ measured ]" line per precision.
OpTestReport run_op_test(Context& ctx, const OpTest& test);

}  // namespace vkunroll::optest
