// Backend buffers own themselves (host/model/backend.hpp): a Buffer handle releases its buffer when
// it goes, moving it moves the ownership (one release), copying does not compile; the Vulkan
// backend's release keeps its ordering (a pooled buffer is reused only after the recorded reads).
#include <gtest/gtest.h>

#include <type_traits>
#include <utility>
#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;

// A buffer has one owner: no copies, and no handle made from a bare id.
static_assert(!std::is_copy_constructible_v<Buffer>);
static_assert(!std::is_copy_assignable_v<Buffer>);
static_assert(!std::is_constructible_v<Buffer, int>);
static_assert(std::is_nothrow_move_constructible_v<Buffer>);
static_assert(std::is_nothrow_move_assignable_v<Buffer>);
static_assert(std::is_nothrow_destructible_v<Buffer>);
// Nobody releases by id: only the handle does.
template <class B>
concept ReleasesById = requires(B& b) { b.release(0); };
static_assert(!ReleasesById<Backend> && !ReleasesById<CpuBackend> && !ReleasesById<VulkanBackend> &&
              !ReleasesById<PlanningBackend>);

namespace {

// The handle's life on any backend, by its live-byte accounting (fp32: 4 bytes a value; a second
// release of one buffer would take live_bytes() below zero, i.e. wrap it).
void expect_handles_release_once(Backend& b) {
  ASSERT_EQ(b.live_bytes(), 0u);
  {
    const Buffer a = b.alloc({2, 3, 4, 5}, "a");
    EXPECT_EQ(b.live_bytes(), 480u);
    EXPECT_TRUE(a);
    EXPECT_EQ(a.shape(), (Shape{2, 3, 4, 5}));
    const BufferSlice v = a.items(1, 1);
    EXPECT_EQ(v.buf, a.id());
    EXPECT_EQ(v.n0, 1);
    EXPECT_EQ(v.c, 3);
  }
  EXPECT_EQ(b.live_bytes(), 0u) << "a handle going out of scope releases its buffer";

  Buffer outer;
  EXPECT_FALSE(outer);
  EXPECT_EQ(outer.id(), -1);
  {
    Buffer a = b.alloc({1, 1, 8, 8}, "moved");
    const int id = a.id();
    outer = std::move(a);
    EXPECT_FALSE(a);  // NOLINT(bugprone-use-after-move): moved from is empty by contract
    EXPECT_EQ(outer.id(), id);
    EXPECT_EQ(b.live_bytes(), 256u);
  }
  EXPECT_EQ(b.live_bytes(), 256u) << "the moved-from handle released nothing";
  Buffer moved(std::move(outer));
  EXPECT_EQ(b.live_bytes(), 256u);
  moved.reset();
  EXPECT_EQ(b.live_bytes(), 0u);
  moved.reset();  // empty now: nothing more
  EXPECT_EQ(b.live_bytes(), 0u);

  // Assigning over a held buffer releases it; containers move handles without releasing.
  Buffer x = b.alloc({1, 1, 4, 4}, "x"), y = b.alloc({1, 1, 2, 2}, "y");
  EXPECT_EQ(b.live_bytes(), 80u);
  x = std::move(y);
  EXPECT_EQ(b.live_bytes(), 16u);
  {
    std::vector<Buffer> held;
    for (int i = 0; i < 5; ++i) held.push_back(b.alloc({1, 1, 1, 4}, "held"));  // reallocations move them
    EXPECT_EQ(b.live_bytes(), 16u + 5 * 16u);
    held.erase(held.begin() + 1);
    EXPECT_EQ(b.live_bytes(), 16u + 4 * 16u);
  }
  EXPECT_EQ(b.live_bytes(), 16u);
  x.reset();
  EXPECT_EQ(b.live_bytes(), 0u);
  EXPECT_EQ(b.peak_bytes(), 480u);
}

}  // namespace

TEST(BackendBuffer, CpuHandlesReleaseOnceOnScopeExit) {
  CpuBackend cpu(1);
  expect_handles_release_once(cpu);
}

TEST(BackendBuffer, PlanningHandlesReleaseOnceOnScopeExit) {
  PlanningBackend plan;
  expect_handles_release_once(plan);
}

TEST(BackendBuffer, VulkanHandlesReleaseOnceOnScopeExit) {
  VulkanBackend vk(vktest::context());
  expect_handles_release_once(vk);
  const uint64_t held = vk.device_bytes();
  vk.flush();
  EXPECT_EQ(vk.device_bytes(), held) << "released buffers are kept over one flush, for a repeated frame";
  vk.flush();
  EXPECT_EQ(vk.device_bytes(), 0u) << "and freed at the next one when no allocation took them";
}

// A released buffer is pooled, reused by the next allocation of its size, and overwritten only
// after the reads recorded before its release (the stream's barriers order the reuse).
TEST(BackendBuffer, VulkanReuseWaitsForRecordedReads) {
  VulkanBackend vk(vktest::context());
  const std::vector<float> first{1, 2, 3, 4, 5, 6, 7, 8}, second{-1, -2, -3, -4, -5, -6, -7, -8};
  const Buffer copy = vk.alloc({1, 2, 2, 2}, "copy");
  uint64_t device = 0;
  {
    const Buffer a = vk.alloc({1, 2, 2, 2}, "a");
    vk.upload(a.whole(), first);
    vk.copy(a.whole(), copy.whole());  // recorded, not run
    device = vk.device_bytes();
  }
  const Buffer b = vk.alloc({2, 1, 2, 2}, "b");  // the same bytes: a's memory again
  EXPECT_EQ(vk.device_bytes(), device) << "the pooled buffer is reused";
  vk.upload(b.whole(), second);
  EXPECT_EQ(vk.download(copy.whole()), first) << "the copy read a before b overwrote its memory";
  EXPECT_EQ(vk.download(b.whole()), second);
}

// Past the pool's limit, the allocation after the release submits and frees the pooled buffers
// (a release itself never submits).
TEST(BackendBuffer, VulkanPoolLimitFreesAtTheNextAllocation) {
  VulkanBackend vk(vktest::context(), nullptr, /*pool_flush_bytes=*/1024);
  { const Buffer big = vk.alloc({1, 1, 32, 16}, "big"); }  // 2048 bytes pooled
  EXPECT_EQ(vk.pool_flushes(), 0u);
  EXPECT_EQ(vk.device_bytes(), 2048u);
  const Buffer small = vk.alloc({1, 1, 4, 4}, "small");
  EXPECT_EQ(vk.pool_flushes(), 1u);
  EXPECT_EQ(vk.device_bytes(), 64u);
}

// The event tensors' handle: valid until the next build; one still held then names a buffer that is
// gone (an Error, never another buffer), and releasing it later harms nothing.
TEST(BackendBuffer, VulkanEventTensorsHeldPastTheNextBuild) {
  VulkanBackend vk(vktest::context());
  RowTiming tm{Rational::parse("100"), Rational::parse("10"), Rational::parse("50"), 3, Readout::top_down};
  const std::vector<EventTensorPair> pairs{{tm, tm.target_time(Rational::parse("0.5")), std::nullopt}};
  EventStream ev;
  ev.width = 2;
  ev.height = 3;
  ev.push(100, 0, 0, 1);
  ev.push(140, 1, 0, -1);
  ev.push(165, 0, 2, 1);
  const EventTensorSpec spec{2, {}};
  const EventTensors want = build_event_tensors_ref(ev, pairs, spec);
  Buffer first = vk.event_tensors(ev, pairs, spec);
  EXPECT_EQ(first.shape(), (Shape{3, 4, 3, 2}));
  const Buffer second = vk.event_tensors(ev, pairs, spec);
  EXPECT_NE(second.id(), first.id());
  EXPECT_THROW(vk.shape(first.id()), Error);
  first.reset();
  const Buffer other = vk.alloc({1, 1, 2, 2}, "other");
  std::vector<float> all = vk.download(second.whole()), cat = want.ev1;
  cat.insert(cat.end(), want.ev2.begin(), want.ev2.end());
  cat.insert(cat.end(), want.ev3.begin(), want.ev3.end());
  EXPECT_EQ(all, cat);
  EXPECT_EQ(vk.live_bytes(), 16u) << "the event tensors are the builder's memory, not the pool's";
}

// Model::run_on_backend releases the buffers handed over with its inputs (and only those).
TEST(BackendBuffer, ModelReleasesHandedOverInputs) {
  const Weights w = random_weights(ModelConfig::published(), 1);
  PlanningBackend plan;
  Model model(plan, w);
  const int64_t ev = model.config().ev_channels(), H = 32, W = 48;
  auto inputs = [&](std::vector<Buffer>& held, ModelBuffers& in) {
    for (auto [slice, c] : {std::pair{&in.rs, int64_t(3)}, {&in.ev1, ev}, {&in.ev2, ev}, {&in.ev3, ev}}) {
      held.push_back(plan.alloc({1, c, H, W}, "input"));
      *slice = held.back().whole();
    }
  };
  const uint64_t input_bytes = 4 * H * W * (3 + 3 * ev), output_bytes = 4 * H * W * 3;
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  {
    std::vector<Buffer> held;
    ModelBuffers in;
    inputs(held, in);
    const std::map<ModelOutput, Buffer> out = model.run_on_backend(in, opt);
    EXPECT_EQ(plan.live_bytes(), input_bytes + output_bytes) << "kept: the caller's inputs and the output";
  }
  EXPECT_EQ(plan.live_bytes(), 0u);
  {
    std::vector<Buffer> held;
    ModelBuffers in;
    inputs(held, in);
    const std::map<ModelOutput, Buffer> out = model.run_on_backend(in, opt, std::move(held));
    EXPECT_EQ(plan.live_bytes(), output_bytes) << "handed over: the inputs went with the run";
    EXPECT_EQ(out.at(ModelOutput::fused).shape(), (Shape{1, 3, H, W}));
  }
  EXPECT_EQ(plan.live_bytes(), 0u);
  // A handed-over buffer that two inputs read cannot be released after either: refused.
  std::vector<Buffer> held;
  ModelBuffers in;
  inputs(held, in);
  in.ev2 = in.ev1;
  std::vector<Buffer> given;
  given.push_back(std::move(held[1]));
  EXPECT_THROW(model.run_on_backend(in, opt, std::move(given)), Error);
}
