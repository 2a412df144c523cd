// The stream's frame recorded once (a repeated submission replays its command buffer), its barriers
// (only on hazards, over the written ranges; a missing one is a hazard the validation layer sees),
// and its trace (Chrome trace events whose GPU spans add up to the profiler's per-op times).
#include <gtest/gtest.h>

#include <cstring>
#include <set>

#include <nlohmann/json.hpp>

#include "model_test_util.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/trace.hpp"

namespace vkunroll {
namespace {

ContextOptions test_options() {
  ContextOptions o;
  o.validation = true;
  o.validation_fatal = true;
  o.announce = false;
  return o;
}

template <class Key>
bool same_bits(const std::map<Key, HostTensor>& a, const std::map<Key, HostTensor>& b) {
  if (a.size() != b.size()) return false;
  for (const auto& [name, t] : a) {
    const auto it = b.find(name);
    if (it == b.end() || it->second.data.size() != t.data.size() ||
        std::memcmp(it->second.data.data(), t.data.data(), t.data.size() * sizeof(float)) != 0)
      return false;
  }
  return true;
}

// A uniform tensor {1, c, 1, n} on the device.
Tensor filled(Context& ctx, int64_t c, int64_t n, float v) {
  Tensor t(ctx, {1, c, 1, n});
  t.upload(std::vector<float>(size_t(c * n), v));
  return t;
}

std::vector<float> read(const Tensor& t) {
  std::vector<float> v(size_t(t.shape().count()));
  t.download(v.data(), v.size() * 4);
  return v;
}

}  // namespace

// Frames of the same shape with new data each time: from the fifth on, the recording replays the
// command buffers of an earlier frame (the first frame allocates its buffers and stages through
// memory of its own; the second takes the buffers kept from it, and its submissions make the staging
// arenas grow; the third and fourth, one submission each, fill the two slots' caches) (uploads through the stream's staging, so the new data goes
// up), and every output equals, bit for bit, that of a stream that records every frame afresh.
TEST(CommandStream, RepeatedModelFrameReplaysAndEqualsAFreshRecording) {
  const Weights w = load_weights(modeltest::fixture("selfunroll_tiny.safetensors"));
  for (const Precision p : {Precision::fp32, Precision::fp16}) {
    ContextOptions fresh_options = test_options();
    fresh_options.command_replay = false;
    Context replaying(test_options()), fresh(fresh_options);
    VulkanBackend vr(replaying, nullptr, kPoolFlushBytes, p), vf(fresh, nullptr, kPoolFlushBytes, p);
    Model mr(vr, w), mf(vf, w);
    RunOptions ro;
    ro.mode = Mode::s;
    for (uint32_t frame = 0; frame < 6; ++frame) {
      const ModelInputs in = modeltest::random_inputs(1, 32, 32, w.config.N, 100 + frame);
      const DeviceTraffic before = replaying.traffic();
      const auto a = mr.run(in, ro), b = mf.run(in, ro);
      const DeviceTraffic d = replaying.traffic() - before;
      EXPECT_TRUE(same_bits(a, b)) << "frame " << frame << " " << precision_name(p);
      if (frame < 4) continue;
      // Every command of the frame came from a command buffer recorded for an earlier one.
      EXPECT_EQ(d.replayed_submits, d.submits) << "frame " << frame << " " << precision_name(p);
      EXPECT_EQ(d.replayed_commands, d.dispatches + d.transfers) << "frame " << frame << " " << precision_name(p);
      EXPECT_GT(d.dispatches, 50u);
    }
    EXPECT_EQ(fresh.traffic().replayed_submits, 0u);
    EXPECT_TRUE(replaying.validation_messages().empty());
  }
}

// A repeated submission with new upload data computes the new data (not the recorded copy's old bytes).
TEST(CommandStream, ReplayedUploadsCarryTheNewData) {
  Context& ctx = vktest::context();
  Tensor a(ctx, {1, 1, 1, 1000}), b = filled(ctx, 1, 1000, 1.f), c(ctx, {1, 1, 1, 1000});
  CommandStream cs(ctx);
  const uint64_t replayed = ctx.traffic().replayed_submits;
  for (int rep = 0; rep < 6; ++rep) {
    std::vector<float> data(1000, float(rep)), got(1000);
    cs.upload(a, 0, data.data(), data.size() * 4);
    add(cs, Slice(a), Slice(b), Slice(c));
    cs.download(c, 0, got.data(), got.size() * 4);
    cs.submit_and_wait();
    EXPECT_EQ(got[0], rep + 1.f) << rep;
    EXPECT_EQ(got[999], rep + 1.f) << rep;
  }
  // The first two (one per slot) stage through memory of their own; the next two, through each
  // slot's arena, are recorded and kept; the last two replay those.
  EXPECT_EQ(ctx.traffic().replayed_submits - replayed, 2u);
}

// A crafted sequence: barriers only before a command that reads what was written (RAW) or writes
// what was read or written (WAR, WAW) since the last barrier, each over the ranges written since then.
TEST(CommandStream, BarriersOnlyOnHazardsOverTheWrittenRanges) {
  Context& ctx = vktest::context();
  Tensor a = filled(ctx, 1, 256, 1.f), b = filled(ctx, 1, 256, 2.f), c(ctx, {1, 1, 1, 256}), d(ctx, {1, 1, 1, 256});
  Tensor halves = filled(ctx, 2, 256, 0.f);  // two channels: disjoint byte ranges of one buffer
  CommandStream cs(ctx);
  add(cs, Slice(a), Slice(b), Slice(c));                          // 0: c = 3          nothing before: none
  add(cs, Slice(a), Slice(b), Slice(halves, 0, 1));               // 1: h0 = 3         reads shared, disjoint writes: none
  add(cs, Slice(a), Slice(b), Slice(halves, 1, 1));               // 2: h1 = 3         the other half: none
  add(cs, Slice(c), Slice(b), Slice(d));                          // 3: d = c + 2 = 5  RAW on c: over c, h0, h1
  add(cs, Slice(halves, 0, 1), Slice(b), Slice(c));               // 4: c = h0 + 2 = 5  WAR on c (read by 3): over d
  add(cs, Slice(a), Slice(b), Slice(halves, 1, 1));               // 5: h1 = 3         no hazard since 4: none
  cs.submit_and_wait();
  const auto& barriers = cs.last_barriers();
  ASSERT_EQ(barriers.size(), 2u);
  EXPECT_EQ(barriers[0].before, 3u);
  EXPECT_EQ(barriers[1].before, 4u);
  auto covered = [](const BarrierNote& n) {
    uint64_t bytes = 0;
    for (const BufferRange& r : n.ranges) bytes += r.size;
    return bytes;
  };
  auto covers = [](const BarrierNote& n, const BufferRange& r) {
    for (const BufferRange& x : n.ranges)
      if (x.buffer == r.buffer && x.offset <= r.offset && r.offset + r.size <= x.offset + x.size) return true;
    return false;
  };
  EXPECT_TRUE(covers(barriers[0], c.range()));
  EXPECT_TRUE(covers(barriers[0], halves.range()));
  EXPECT_EQ(covered(barriers[0]), c.range().size + halves.range().size) << "exactly the writes since the start";
  EXPECT_TRUE(covers(barriers[1], d.range()));
  EXPECT_EQ(covered(barriers[1]), d.range().size) << "exactly the write since the last barrier";
  EXPECT_EQ(read(d)[7], 5.f);
  EXPECT_EQ(read(c)[7], 5.f);
  EXPECT_EQ(read(halves)[300], 3.f);
}

// The same dependent pairs under the validation layer's synchronization validation: with the
// stream's barriers it reports nothing; without them it reports the read-after-write and the
// write-after-read hazards, so each barrier the stream records is one a GPU needs.
TEST(CommandStream, AMissingBarrierIsAHazardTheValidationLayerReports) {
  ContextOptions o = test_options();
  o.validation_fatal = false;
  o.synchronization_validation = true;
  Context ctx(o);
  Tensor a = filled(ctx, 1, 256, 1.f), b = filled(ctx, 1, 256, 2.f), c(ctx, {1, 1, 1, 256}), d(ctx, {1, 1, 1, 256});
  for (const bool drop : {false, true}) {
    ctx.clear_validation_messages();
    CommandStream cs(ctx);
    cs.drop_barriers_for_test(drop);
    add(cs, Slice(a), Slice(b), Slice(c));  // c = a + b
    add(cs, Slice(c), Slice(b), Slice(d));  // reads c: RAW
    add(cs, Slice(b), Slice(b), Slice(c));  // writes c, read just before: WAR
    cs.submit_and_wait();
    std::string all;
    for (const auto& m : ctx.validation_messages()) all += m + "\n";
    if (!drop) {
      EXPECT_EQ(all.find("SYNC-HAZARD"), std::string::npos) << all;
      continue;
    }
    EXPECT_NE(all.find("SYNC-HAZARD-READ-AFTER-WRITE"), std::string::npos) << all;
    EXPECT_NE(all.find("SYNC-HAZARD-WRITE-AFTER-READ"), std::string::npos) << all;
  }
}

// --trace's format: Chrome trace events (name, ph, ts, dur, pid, tid, args), sorted, no two spans of
// one track overlapping, one track per kind named by a thread_name record; its GPU spans add up to
// the profiler's per-op times.
TEST(CommandStream, TraceIsChromeTraceEventsAndAddsUpToTheProfile) {
  Context& ctx = vktest::context();
  if (!ctx.info().timestamps) GTEST_SKIP() << "the device writes no timestamps";
  Trace trace;
  ctx.set_trace(&trace);
  Profiler prof;
  {
    Tensor a = filled(ctx, 1, 4096, 1.f), b = filled(ctx, 1, 4096, 2.f), c(ctx, {1, 1, 1, 4096});
    CommandStream cs(ctx, &prof);
    cs.set_stage("chain");
    for (int i = 0; i < 600; ++i) add(cs, Slice(i % 2 ? c : a), Slice(b), Slice(i % 2 ? a : c));  // three submissions
    std::vector<float> back(4096);
    cs.download(c, 0, back.data(), back.size() * 4);
    cs.submit_and_wait();
  }
  ctx.set_trace(nullptr);
  const nlohmann::json j = nlohmann::json::parse(trace.json());
  ASSERT_TRUE(j.at("traceEvents").is_array());
  std::map<int, std::string> track;
  std::map<int, double> track_end;
  std::map<std::string, double> gpu_ms;
  double last_ts = -1e300;
  size_t spans = 0;
  for (const auto& e : j.at("traceEvents")) {
    ASSERT_TRUE(e.at("name").is_string() && e.at("ph").is_string() && e.at("pid").is_number_integer() &&
                e.at("tid").is_number_integer() && e.at("args").is_object()) << e.dump();
    const int tid = e.at("tid").get<int>();
    if (e.at("ph") == "M") {
      if (e.at("name") == "thread_name") track[tid] = e.at("args").at("name").get<std::string>();
      continue;
    }
    ASSERT_EQ(e.at("ph"), "X") << e.dump();
    const double ts = e.at("ts").get<double>(), dur = e.at("dur").get<double>();
    EXPECT_GE(dur, 0.0);
    EXPECT_GE(ts, last_ts) << "sorted by start";
    last_ts = ts;
    EXPECT_GE(ts + 1e-3, track_end[tid]) << "overlaps the track's previous span: " << e.dump();
    track_end[tid] = ts + dur;
    ASSERT_TRUE(track.count(tid)) << "every track is named before its spans: " << e.dump();
    if (track[tid].rfind("GPU", 0) == 0) gpu_ms[e.at("args").at("op").get<std::string>()] += dur * 1e-3;
    ++spans;
  }
  EXPECT_GE(spans, 601u);
  ASSERT_EQ(gpu_ms.size(), prof.ops().size());
  for (const auto& [op, st] : prof.ops()) {
    ASSERT_TRUE(gpu_ms.count(op)) << op;
    // dur is written to 1 ns: the sums agree within that per span.
    EXPECT_NEAR(gpu_ms[op], st.total_ms, 1e-6 * double(st.calls) + 1e-9) << op;
  }
  EXPECT_EQ(prof.ops().at("add").calls, 600u);
}

}  // namespace vkunroll
