#include "op_test_harness.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <random>

#include "vkunroll/base/error.hpp"

namespace vkunroll::optest {

namespace {
using namespace vkunroll::ktest;

// The inputs as the device stores them in `p` (fp16: rounded to nearest even).
std::vector<HostTensor> stored(const std::vector<HostTensor>& inputs, Precision p) {
  std::vector<HostTensor> out;
  for (const HostTensor& t : inputs) out.push_back(p == Precision::fp16 ? rounded_to_half(t) : t);
  return out;
}

// The rule's error of one output slice (see Tolerance) and the limit it must stay within.
struct Judged {
  double error = 0, limit = 0;
};
Judged judge(const HostTensor& got, const HostTensor& ref, const CanarySlice& cs, const OutputSpec& spec,
             const Tolerance& tol, Precision p) {
  if (p == Precision::fp32) return {max_abs_diff(got, ref, cs), tol.fp32 * spec.fp32_tolerance_scale};
  return {tol.fp16_relative ? max_range_rel_diff(got, ref, cs) : max_abs_diff(got, ref, cs), tol.fp16};
}

struct CaseRun {
  bool applied = false;
  bool refused = false;  // fp16 on a device without 16-bit storage, refused by name as the rule says
  double error = 0;  // the largest error over the outputs
};

// One case in one precision: reference, device, comparison, canaries and inputs.
CaseRun run_case(Context& ctx, const OpTest& test, const OpCase& c, Precision p, std::mt19937& rng) {
  const DType dt = precision_dtype(p);
  const std::string what = test.op + " " + precision_name(p) + ": " + c.what;
  HostRun host;
  host.precision = p;
  host.inputs = p == Precision::fp16 && test.tolerance.fp16_reference_on_half_inputs ? stored(c.inputs, p) : c.inputs;
  for (const OutputSpec& o : c.outputs) {
    host.slices.push_back(canary_slice(o.shape, rng, o.c_before, o.c_after));
    // The slice's contents before the op as the device stores them: what an op leaves unwritten
    // (copy_rect outside its rectangle) compares equal in fp16 too.
    if (p == Precision::fp16) host.slices.back().host = rounded_to_half(host.slices.back().host);
    host.outputs.push_back(host.slices.back().host);
  }
  CommandStream cs(ctx);
  DeviceRun dev{ctx, p, cs, {}, {}, host.slices, nullptr};
  for (const HostTensor& t : host.inputs) dev.inputs.push_back(to_device(ctx, t, dt));
  for (const CanarySlice& s : host.slices) dev.outputs.push_back(to_device(ctx, s.host, dt));
  CaseRun result;
  // The rule (docs/testing.md): a device without 16-bit storage (SwiftShader) refuses fp16 by the
  // feature's name when the op is recorded; running it there anyway is a failure too.
  const bool must_refuse = p == Precision::fp16 && !ctx.info().storage_buffer_16bit;
  try {
    if (!c.record(dev)) return result;
    if (must_refuse) {
      ADD_FAILURE() << what << ": recorded fp16 on device '" << ctx.info().name << "', which lacks 16-bit storage";
      return result;
    }
    cs.submit_and_wait();
  } catch (const Error& e) {
    const std::string m = e.what();
    result.refused = (must_refuse && m.find("storageBuffer16BitAccess") != std::string::npos) || (test.refusal && test.refusal(m));
    if (!result.refused) ADD_FAILURE() << what << ": " << e.what();
    return result;
  }
  result.applied = true;
  c.reference(host);
  std::vector<HostTensor> got;
  for (size_t i = 0; i < c.outputs.size(); ++i) {
    got.push_back(to_host(dev.outputs[i]));
    const Judged j = judge(got[i], host.outputs[i], host.slices[i], c.outputs[i], test.tolerance, p);
    result.error = std::max(result.error, j.error);
    EXPECT_LE(j.error, j.limit) << what << ", output " << i;
    EXPECT_EQ(canary_damage(got[i], host.slices[i]), "") << what << ", output " << i;
  }
  // A read-only binding comes back as it went: nothing wrote into an input.
  const std::vector<HostTensor> sent = stored(host.inputs, p);
  for (size_t i = 0; i < sent.size(); ++i)
    EXPECT_EQ(max_abs_diff(to_host(dev.inputs[i]), sent[i]), 0.0) << what << ": input " << i << " changed";
  if (c.check) c.check(host, got);
  return result;
}
}  // namespace

OpTestReport run_op_test(Context& ctx, const OpTest& test) {
  OpTestReport report;
  std::mt19937 rng(test.seed);
  for (Precision p : test.precisions) {
    const int k = p == Precision::fp16;
    for (const OpCase& c : test.cases) {
      const CaseRun r = run_case(ctx, test, c, p, rng);
      report.error[k].push_back(r.applied ? r.error : -1);
      report.refused[k] += r.refused;
      if (!r.applied) {
        ++report.skipped[k];
        continue;
      }
      ++report.ran[k];
      report.worst[k] = std::max(report.worst[k], r.error);
    }
    if (report.refused[k])
      std::printf("[ refused  ] %s %s: %d cases refused by name on '%s'\n", test.op.c_str(), precision_name(p),
                  report.refused[k], ctx.info().name.c_str());
    if (p == Precision::fp16 && !ctx.info().storage_buffer_16bit) {
      EXPECT_EQ(report.ran[k], 0) << test.op << ": fp16 ran on a device without 16-bit storage";
    } else if (!report.refused[k]) {
      EXPECT_GT(report.ran[k], 0) << "no case applies to " << test.op << " in " << precision_name(p);
    }
    if (!report.ran[k]) continue;
    std::printf("[ measured ] %s %s: max %s error %.3g over %d cases\n", test.op.c_str(), precision_name(p),
                p == Precision::fp16 && test.tolerance.fp16_relative ? "relative" : "abs", report.worst[k],
                report.ran[k]);
  }
  return report;
}

}  // namespace vkunroll::optest
