// The op-test harness itself: it passes a correct op and fails each kind of wrong one (an output
// off the reference, a write beside the output slice, a write into an input, an op that applies to
// no case), so that the kernel tests built on it can fail.
#include <gtest/gtest-spi.h>
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
enum class Fault { none, wrong_value, beside_the_slice, into_an_input, applies_nowhere };

// add(a, b) of two channel slices of one input, on the whole-binding context (a stray write stays
// inside the binding, where a canary sees it), with `fault` put into the device side.
void run_add(Fault fault) {
  std::mt19937 rng(3);
  const Shape s{2, 3, 5, 7};
  optest::OpTest test{"add", {}, {1e-6, 2e-3, true}};
  optest::OpCase k;
  k.what = s.str();
  k.inputs = {random_tensor({s.n, 2 * s.c + 1, s.h, s.w}, rng)};
  k.outputs = {{s}};
  k.reference = [s](optest::HostRun& r) {
    add_ref(HostSlice(r.inputs[0], 0, s.c), HostSlice(r.inputs[0], s.c, s.c), r.out(0));
  };
  k.record = [s, fault](optest::DeviceRun& d) {
    const Slice a(d.inputs[0], 0, s.c), b(d.inputs[0], s.c, s.c);
    if (fault == Fault::applies_nowhere) return false;
    if (fault == Fault::wrong_value) {
      add(d.stream, a, a, d.out(0));
    } else if (fault == Fault::beside_the_slice) {
      const Slice out = d.out(0);
      add(d.stream, Slice(d.inputs[0], 0, s.c + 1), Slice(d.inputs[0], s.c, s.c + 1),
          Slice(d.outputs[0], out.c0, out.c + 1, out.n0, out.n));
    } else if (fault == Fault::into_an_input) {
      add(d.stream, a, b, d.out(0));
      copy(d.stream, b, a);
    } else {
      add(d.stream, a, b, d.out(0));
    }
    return true;
  };
  test.cases.push_back(std::move(k));
  optest::run_op_test(vktest::whole_binding_context(), test);
}

// The failures run_add(fault) reports, caught instead of failing this test.
std::vector<std::string> failures_of(Fault fault) {
  ::testing::TestPartResultArray results;
  {
    ::testing::ScopedFakeTestPartResultReporter catcher(
        ::testing::ScopedFakeTestPartResultReporter::INTERCEPT_ONLY_CURRENT_THREAD, &results);
    run_add(fault);
  }
  std::vector<std::string> messages;
  for (int i = 0; i < results.size(); ++i) messages.push_back(results.GetTestPartResult(i).message());
  return messages;
}

// How many of the messages contain `needle`.
int count(const std::vector<std::string>& messages, const std::string& needle) {
  int n = 0;
  for (const std::string& m : messages) n += m.find(needle) != std::string::npos;
  return n;
}
}  // namespace

TEST(OpTestHarness, PassesACorrectOp) { EXPECT_EQ(failures_of(Fault::none), std::vector<std::string>{}); }

TEST(OpTestHarness, FailsAWrongOutputAStrayWriteAWrittenInputAndAnOpThatNeverRan) {
  const std::vector<std::string> wrong = failures_of(Fault::wrong_value);
  EXPECT_EQ(count(wrong, "add fp32: 2x3x5x7, output 0"), 1) << ::testing::PrintToString(wrong);
  EXPECT_EQ(count(wrong, "add fp16: 2x3x5x7, output 0"), 1) << ::testing::PrintToString(wrong);
  const std::vector<std::string> stray = failures_of(Fault::beside_the_slice);
  EXPECT_EQ(count(stray, "canaries overwritten"), 2) << ::testing::PrintToString(stray);
  const std::vector<std::string> written = failures_of(Fault::into_an_input);
  EXPECT_EQ(count(written, "input 0 changed"), 2) << ::testing::PrintToString(written);
  const std::vector<std::string> never = failures_of(Fault::applies_nowhere);
  EXPECT_EQ(count(never, "no case applies to add in fp"), 2) << ::testing::PrintToString(never);
}
