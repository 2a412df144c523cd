// The foundation: tensors, pipelines, command streams and barriers, device choice, errors.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cctype>
#include <filesystem>
#include <numeric>
#include <sstream>

#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/pipeline_compiler.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/shader_registry.hpp"
#include "vkunroll/runtime/tensor.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;

namespace {
struct AxpyPush {
  float a;
  uint32_t n;
};

void axpy(CommandStream& cs, Context& ctx, const Tensor& x, Tensor& y, float a) {
  const auto n = static_cast<uint32_t>(x.shape().count());
  AxpyPush p{a, n};
  cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof(AxpyPush)), {in(x), inout(y)}, p, {(n + 63) / 64},
              {"axpy", 2.0 * n, 12.0 * n});
}
}  // namespace

TEST(Runtime, RoundTripEveryDtype) {
  Context& ctx = vktest::context();
  for (DType dt : {DType::f32, DType::f16, DType::u32, DType::i32}) {
    Tensor t(ctx, {1, 3, 5, 7}, dt);
    std::vector<uint8_t> data(t.bytes());
    std::iota(data.begin(), data.end(), static_cast<uint8_t>(dtype_size(dt)));
    t.upload(data.data(), data.size());
    std::vector<uint8_t> back(t.bytes());
    t.download(back.data(), back.size());
    EXPECT_EQ(data, back) << dtype_name(dt);
  }
}

TEST(Runtime, UploadWrongSizeIsAnError) {
  Tensor t(vktest::context(), {1, 1, 2, 2});
  std::vector<float> v(3);
  EXPECT_THROW(t.upload(v), Error);
}

// A stream destroyed while its submission is still running (its fence wait timed out: the timeout of
// VKUNROLL_FENCE_TIMEOUT_S, here 0) frees nothing the device still uses: before the fix its destructor
// destroyed the in-flight fence, command pool and staging (VUID-vkDestroyFence-fence-01120).
TEST(Runtime, AStreamWhoseWaitTimedOutFreesNothingInFlight) {
  ContextOptions o;
  o.validation = true;
  o.validation_fatal = false;  // the messages are this test's verdict
  o.announce = false;
  Context ctx(o);
  const int n = 1 << 22;
  Tensor x(ctx, {1, 1, 1, n}), y(ctx, {1, 1, 1, n});
  {
    CommandStream cs(ctx);
    cs.set_timeout_seconds(0);
    for (int i = 0; i < 32; ++i) axpy(cs, ctx, x, y, 1.f);  // ~0.1 s of lavapipe work, still running below
    cs.submit();
  }
  const auto messages = ctx.validation_messages();
  EXPECT_TRUE(messages.empty()) << messages.size() << " messages, the first: " << messages.front();
}

TEST(Runtime, ChainOfDependentDispatches) {
  Context& ctx = vktest::context();
  const int n = 100003;  // not a multiple of the workgroup
  Tensor x(ctx, {1, 1, 1, n}), y(ctx, {1, 1, 1, n}), z(ctx, {1, 1, 1, n});
  std::vector<float> xv(n), yv(n, 1.f), zv(n, 0.f);
  for (int i = 0; i < n; ++i) xv[i] = static_cast<float>(i % 97) * 0.5f;
  x.upload(xv);
  y.upload(yv);
  z.upload(zv);
  CommandStream cs(ctx);
  // y = 2x + y; z = 3y + z; y = -1*z + y   (each step reads what the previous one wrote)
  axpy(cs, ctx, x, y, 2.f);
  axpy(cs, ctx, y, z, 3.f);
  axpy(cs, ctx, z, y, -1.f);
  cs.submit_and_wait();
  auto yo = y.download<float>(), zo = z.download<float>();
  for (int i = 0; i < n; ++i) {
    const float y1 = 2 * xv[i] + 1, z1 = 3 * y1, y2 = y1 - z1;
    ASSERT_EQ(zo[i], z1) << i;
    ASSERT_EQ(yo[i], y2) << i;
  }
}

TEST(Runtime, DispatchWritingTheSameBufferTwice) {
  Context& ctx = vktest::context();
  const int n = 4096;
  Tensor x(ctx, {1, 1, 1, n}), y(ctx, {1, 1, 1, n});
  x.upload(std::vector<float>(n, 1.f));
  CommandStream cs(ctx);
  cs.fill(y, 0);  // transfer write, then compute writes: write-after-write on y
  for (int k = 0; k < 10; ++k) axpy(cs, ctx, x, y, 1.f);
  cs.submit_and_wait();
  for (float v : y.download<float>()) ASSERT_EQ(v, 10.f);
  // The stream is reusable after a submit.
  axpy(cs, ctx, x, y, 5.f);
  cs.submit_and_wait();
  EXPECT_EQ(y.download<float>()[17], 15.f);
}

TEST(Runtime, ManyDispatchesSplitAcrossSubmits) {
  Context& ctx = vktest::context();
  Tensor x(ctx, {1, 1, 1, 64}), y(ctx, {1, 1, 1, 64});
  x.upload(std::vector<float>(64, 1.f));
  y.upload(std::vector<float>(64, 0.f));
  CommandStream cs(ctx);
  for (int k = 0; k < 2500; ++k) axpy(cs, ctx, x, y, 1.f);  // more than one query pool holds
  cs.submit_and_wait();
  EXPECT_EQ(y.download<float>()[63], 2500.f);
}

TEST(Runtime, SubRangesOfOneTensorAreIndependentBindings) {
  Context& ctx = vktest::context();
  Tensor t(ctx, {1, 2, 1, 64});
  std::vector<float> v(128, 1.f);
  t.upload(v);
  CommandStream cs(ctx);
  // Second half += 4 * first half: reads one range, writes a disjoint one of the same buffer.
  AxpyPush p{4.f, 64};
  cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof p),
              {{t.range(0, 256), Access::read}, {t.range(256, 256), Access::read_write}}, p, {1}, {"axpy"});
  cs.submit_and_wait();
  auto o = t.download<float>();
  EXPECT_EQ(o[0], 1.f);
  EXPECT_EQ(o[64], 5.f);
  EXPECT_THROW(t.range(256, 512), Error);
}

TEST(Runtime, AllocationsShareBlocks) {
  Context& ctx = vktest::context();
  const auto before = ctx.allocator().stats();
  std::vector<Tensor> ts;
  for (int i = 0; i < 50; ++i) ts.emplace_back(ctx, Shape{1, 4, 16, 16});
  const auto after = ctx.allocator().stats();
  EXPECT_EQ(after.allocations - before.allocations, 50u);
  EXPECT_LE(after.blocks - before.blocks, 1u);  // 50 tensors, at most one new vkAllocateMemory
  ts.clear();
  EXPECT_EQ(ctx.allocator().stats().used_bytes, before.used_bytes);
}

TEST(Runtime, OverLimitTensorIsRefusedNamingTheLimit) {
  Context& ctx = vktest::context();
  const uint64_t limit = ctx.info().max_storage_buffer_range;
  const int64_t w = static_cast<int64_t>(limit / 4 / 1024) + 1;  // just over the limit in f32
  try {
    Tensor t(ctx, {1, 1, 1024, w});
    FAIL() << "no error for a tensor over maxStorageBufferRange";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("maxStorageBufferRange"), std::string::npos) << e.what();
  }
  // A ranged tensor may exist, but binding it whole is refused.
  Tensor big(ctx, {1, 1, 1024, w}, DType::f32, Binding::ranged);
  Tensor x(ctx, {1, 1, 1, 64});
  CommandStream cs(ctx);
  AxpyPush p{1.f, 64};
  EXPECT_THROW(cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof p), {in(x), inout(big)}, p, {1}, {"axpy"}), Error);
}

TEST(Runtime, WrongArgumentCountIsAnError) {
  Context& ctx = vktest::context();
  Tensor x(ctx, {1, 1, 1, 64});
  CommandStream cs(ctx);
  AxpyPush p{1.f, 64};
  EXPECT_THROW(cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof p), {in(x)}, p, {1}, {"axpy"}), Error);
  EXPECT_THROW(ctx.pipeline(vktest::test_shader("no_such_shader")), Error);
}

TEST(Runtime, DeviceChoiceByIndexNameAndPolicy) {
  std::vector<DeviceInfo> devs(3);
  devs[0].index = 0, devs[0].name = "llvmpipe (LLVM 15)", devs[0].type = VK_PHYSICAL_DEVICE_TYPE_CPU;
  devs[1].index = 1, devs[1].name = "Intel Iris Xe", devs[1].type = VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU;
  devs[2].index = 2, devs[2].name = "AMD Radeon RX 7900", devs[2].type = VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU;
  EXPECT_EQ(choose_device(devs, ""), 2u);
  EXPECT_EQ(choose_device(devs, "1"), 1u);
  EXPECT_EQ(choose_device(devs, "LLVMPIPE"), 0u);
  EXPECT_EQ(choose_device(devs, "iris"), 1u);
  devs.pop_back();
  EXPECT_EQ(choose_device(devs, ""), 1u);  // integrated beats cpu
  try {
    choose_device(devs, "nvidia");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("nvidia"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("llvmpipe"), std::string::npos);  // lists what exists
  }
  EXPECT_THROW(choose_device(devs, "7"), Error);
}

TEST(Runtime, RealDeviceChosenByNameAndIndex) {
  // The last device the loader lists (lavapipe in CI; whichever GPU elsewhere), by index and by a
  // case-changed name; the first device of that name is the one a name picks.
  const DeviceList list = Context::enumerate();
  ASSERT_FALSE(list.devices.empty());
  const auto& want = list.devices.back();
  uint32_t first_of_name = want.index;
  for (const auto& d : list.devices)
    if (d.name == want.name) {
      first_of_name = d.index;
      break;
    }
  ContextOptions o;
  o.announce = false;
  o.validation = true;
  o.device = std::to_string(want.index);
  Context by_index(o);
  EXPECT_EQ(by_index.info().name, want.name);
  std::string upper = want.name;
  for (char& ch : upper) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  o.device = upper;
  Context by_name(o);
  EXPECT_EQ(by_name.info().index, first_of_name);
  EXPECT_GT(by_name.info().subgroup_size, 0u);
  EXPECT_GE(by_name.info().max_storage_buffer_range, 1u << 20);
  o.device = "no-such-gpu";
  EXPECT_THROW(Context bad(o), Error);
}

TEST(Runtime, ProfilerTablePerOp) {
  Context& ctx = vktest::context();
  if (!ctx.info().timestamps) GTEST_SKIP() << "device has no timestamps";
  Tensor x(ctx, {1, 1, 1, 1 << 16}), y(ctx, {1, 1, 1, 1 << 16});
  x.upload(std::vector<float>(1 << 16, 1.f));
  y.upload(std::vector<float>(1 << 16, 0.f));
  Profiler prof;
  CommandStream cs(ctx, &prof);
  for (int k = 0; k < 3; ++k) axpy(cs, ctx, x, y, 1.f);
  cs.fill(y, 0);
  cs.submit_and_wait();
  ASSERT_EQ(prof.ops().count("axpy"), 1u);
  EXPECT_EQ(prof.ops().at("axpy").calls, 3u);
  EXPECT_EQ(prof.ops().at("fill").calls, 1u);
  EXPECT_GT(prof.ops().at("axpy").total_ms, 0.0);
  std::ostringstream os;
  prof.print(os);
  EXPECT_NE(os.str().find("axpy"), std::string::npos);
  EXPECT_NE(os.str().find("GFLOP/s"), std::string::npos);
}

TEST(Runtime, SpirvBindingsAreDerivedFromTheModule) {
  auto b = spirv_storage_bindings(vktest::test_shader_words("runtime_axpy"));
  EXPECT_EQ(b, (std::vector<uint32_t>{0, 1}));
  EXPECT_THROW(spirv_storage_bindings(std::vector<uint32_t>{1, 2, 3, 4, 5}), Error);
}

TEST(Runtime, UniformBufferBindingsAreDerivedAndBound) {
  Context& ctx = vktest::context();
  using K = DescriptorKind;
  EXPECT_EQ(spirv_bindings(vktest::test_shader_words("runtime_uniform_scale")),
            (std::vector<SpirvBinding>{{0, K::storage_buffer}, {1, K::uniform_buffer}, {2, K::storage_buffer}}));
  EXPECT_EQ(spirv_bindings(vktest::test_shader_words("runtime_axpy")),
            (std::vector<SpirvBinding>{{0, K::storage_buffer}, {1, K::storage_buffer}}));
  const Pipeline& pl = ctx.pipeline(vktest::test_shader("runtime_uniform_scale"), {}, 4);
  EXPECT_TRUE(pl.binding_is_uniform(1));
  EXPECT_FALSE(pl.binding_is_uniform(0));
  // The scales are the second 16 floats of a 64-float tensor: a uniform sub-range at offset 64 bytes.
  Tensor x(ctx, {1, 1, 1, 40}), s(ctx, {1, 1, 1, 64}), y(ctx, {1, 1, 1, 40});
  std::vector<float> xv(40), sv(64);
  for (size_t i = 0; i < xv.size(); ++i) xv[i] = static_cast<float>(i) + 1.f;
  for (size_t i = 0; i < sv.size(); ++i) sv[i] = 0.5f * static_cast<float>(i);
  x.upload(xv);
  s.upload(sv);
  CommandStream cs(ctx);
  const uint32_t n = 40;
  cs.dispatch(pl, {in(x), {s.range(64, 64), Access::read}, out(y)}, n, {1}, {"uniform_scale"});
  cs.submit_and_wait();
  const auto yv = y.download<float>();
  for (size_t i = 0; i < yv.size(); ++i) EXPECT_EQ(yv[i], xv[i] * sv[16 + i % 16]) << i;
  // A uniform binding beyond maxUniformBufferRange or at an unaligned offset is refused by name.
  const uint64_t limit = ctx.info().max_uniform_buffer_range;
  Tensor big(ctx, {1, 1, 1, static_cast<int64_t>(limit / 4 + 4)});
  EXPECT_THROW(cs.dispatch(pl, {in(x), {big.range(), Access::read}, out(y)}, n, {1}, {"uniform_scale"}), Error);
  if (ctx.info().min_uniform_buffer_offset_alignment > 4) {
    EXPECT_THROW(cs.dispatch(pl, {in(x), {s.range(4, 64), Access::read}, out(y)}, n, {1}, {"uniform_scale"}), Error);
  }
}

TEST(Runtime, TexelBufferBindingsAreDerivedAndBound) {
  Context& ctx = vktest::context();
  using K = DescriptorKind;
  EXPECT_EQ(spirv_bindings(vktest::test_shader_words("runtime_texel_scale")),
            (std::vector<SpirvBinding>{{0, K::uniform_texel_buffer}, {1, K::uniform_texel_buffer},
                                       {2, K::storage_texel_buffer}}));
  const Pipeline& pl = ctx.pipeline(vktest::test_shader("runtime_texel_scale"), {}, 4);
  EXPECT_EQ(pl.binding_kind(1), K::uniform_texel_buffer);
  EXPECT_EQ(pl.binding_kind(2), K::storage_texel_buffer);
  // x: floats 16.. of a tensor (an R32 view at byte offset 64); q: an RGBA32 view at byte offset 32;
  // y: floats 4.. of its tensor (byte offset 16), the floats before it must survive.
  const uint32_t n = 40;
  Tensor x(ctx, {1, 1, 1, 64}), q(ctx, {1, 1, 1, 64}), y(ctx, {1, 1, 1, 48});
  std::vector<float> xv(64), qv(64), y0(48, -7.f);
  for (size_t i = 0; i < xv.size(); ++i) xv[i] = static_cast<float>(i) + 1.f;
  for (size_t i = 0; i < qv.size(); ++i) qv[i] = 0.25f * static_cast<float>(i);
  x.upload(xv);
  q.upload(qv);
  y.upload(y0);
  const Arg xa{x.range(64, n * 4), Access::read}, qa{q.range(32, n * 4), Access::read, VK_FORMAT_R32G32B32A32_SFLOAT};
  const Arg ya{y.range(16, n * 4), Access::write};
  CommandStream cs(ctx);
  cs.dispatch(pl, {xa, qa, ya}, n, {1}, {"texel_scale"});
  cs.dispatch(pl, {xa, qa, ya}, n, {1}, {"texel_scale"});  // the same views again (cached)
  cs.submit_and_wait();
  const auto yv = y.download<float>();
  for (size_t i = 0; i < 4; ++i) EXPECT_EQ(yv[i], -7.f) << i;
  for (size_t i = 0; i < n; ++i) EXPECT_EQ(yv[4 + i], xv[16 + i] + 2.f * qv[8 + i]) << i;
  for (size_t i = 4 + n; i < yv.size(); ++i) EXPECT_EQ(yv[i], -7.f) << i;
  // Refused by name before Vulkan sees them: more texels than maxTexelBufferElements (the range is
  // never created), an offset that is not a multiple of minTexelBufferOffsetAlignment, a partial texel.
  const uint64_t max_texels = ctx.info().max_texel_buffer_elements;
  ASSERT_GT(max_texels, 0u);
  const Arg too_long{{x.range().buffer, x.range().offset, (max_texels + 1) * 4}, Access::read};
  try {
    cs.dispatch(pl, {too_long, qa, ya}, n, {1}, {"texel_scale"});
    ADD_FAILURE() << "a view beyond maxTexelBufferElements was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("maxTexelBufferElements"), std::string::npos) << e.what();
  }
  if (ctx.info().min_texel_buffer_offset_alignment > 4) {
    try {
      cs.dispatch(pl, {{x.range(4, n * 4), Access::read}, qa, ya}, n, {1}, {"texel_scale"});
      ADD_FAILURE() << "an unaligned view was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("minTexelBufferOffsetAlignment"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(cs.dispatch(pl, {xa, {q.range(32, 20), Access::read, VK_FORMAT_R32G32B32A32_SFLOAT}, ya}, n, {1},
                           {"texel_scale"}),
               Error);
  cs.submit_and_wait();
}

TEST(Runtime, VkResultNames) {
  EXPECT_STREQ(vk_result_name(VK_ERROR_DEVICE_LOST), "VK_ERROR_DEVICE_LOST");
  EXPECT_STREQ(vk_result_name(static_cast<VkResult>(-12345)), "VkResult(-12345)");
  try {
    VK_CHECK(VK_ERROR_OUT_OF_DEVICE_MEMORY);
    FAIL();
  } catch (const VulkanError& e) {
    EXPECT_EQ(e.result(), VK_ERROR_OUT_OF_DEVICE_MEMORY);
    EXPECT_NE(std::string(e.what()).find("test_runtime.cpp"), std::string::npos);
  }
}

TEST(Runtime, ValidationLayerIsOnAndReportsMisuse) {
  Context& ctx = vktest::context();
  ASSERT_TRUE(ctx.validation_enabled());
  // A deliberate misuse: a zero-sized buffer violates VUID-VkBufferCreateInfo-size-00912.
  VkBufferCreateInfo bci{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  bci.size = 0;
  bci.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  VkBuffer b = VK_NULL_HANDLE;
  (void)vkCreateBuffer(ctx.device(), &bci, nullptr, &b);
  if (b) vkDestroyBuffer(ctx.device(), b, nullptr);
  const auto msgs = ctx.validation_messages();
  ASSERT_FALSE(msgs.empty()) << "the validation layer reported nothing";
  EXPECT_NE(msgs.front().find("00912"), std::string::npos) << msgs.front();
  ctx.clear_validation_messages();  // expected here; any other test with a message fails
}

TEST(Runtime, PipelineCachePersistsAcrossContexts) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("vkunroll-cache-test-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  ::setenv("VKUNROLL_CACHE_DIR", dir.c_str(), 1);
  ContextOptions o;
  o.announce = false;
  o.validation = true;
  {
    Context first(o);
    first.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof(AxpyPush));
  }
  ASSERT_TRUE(fs::exists(dir));
  size_t files = 0, bytes = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    files++;
    bytes += fs::file_size(e.path());
  }
  EXPECT_EQ(files, 1u);
  // A VkPipelineCache blob starts with its 32-byte header; lavapipe (Mesa 22.3) stores nothing
  // past it, drivers with a real cache store the compiled pipelines after it.
  EXPECT_GE(bytes, 32u);
  {
    Context second(o);  // loads the blob; creating the same pipeline hits the cache
    second.pipeline(vktest::test_shader("runtime_axpy"), {}, sizeof(AxpyPush));
    EXPECT_TRUE(second.validation_messages().empty());
  }
  fs::remove_all(dir);
}

// CommandStream transfers are ordered with the recorded dispatches: a buffer is uploaded, read,
// overwritten by a second upload and read again, all in one submission, and the downloads see each
// state. The context counts the traffic and the one submit.
TEST(Runtime, StreamTransfersAreOrderedWithDispatchesInOneSubmit) {
  Context& ctx = vktest::context();
  const size_t n = 1000;
  Tensor x(ctx, {1, 1, 1, static_cast<int64_t>(n)}), y(ctx, {1, 1, 1, static_cast<int64_t>(n)});
  std::vector<float> ones(n, 1.f), twos(n, 2.f), zeros(n, 0.f), after1(n, -1.f), after2(n, -1.f);
  const DeviceTraffic before = ctx.traffic();
  CommandStream cs(ctx);
  cs.upload(y, 0, zeros.data(), n * 4);
  cs.upload(x, 0, ones.data(), n * 4);
  axpy(cs, ctx, x, y, 3.f);                     // y = 3
  cs.download(y, 0, after1.data(), n * 4);
  cs.upload(x, 0, twos.data(), n * 4);          // must not overtake the axpy above
  axpy(cs, ctx, x, y, 0.5f);                    // y = 4
  cs.download(y, 0, after2.data(), n * 4);
  EXPECT_EQ(after1[0], -1.f);  // nothing before the submit
  cs.submit_and_wait();
  const DeviceTraffic d = ctx.traffic() - before;
  for (size_t i = 0; i < n; ++i) {
    ASSERT_EQ(after1[i], 3.f) << i;
    ASSERT_EQ(after2[i], 4.f) << i;
  }
  EXPECT_EQ(d.submits, 1u);
  EXPECT_EQ(d.upload_bytes, 3 * n * 4);
  EXPECT_EQ(d.download_bytes, 2 * n * 4);
  EXPECT_THROW(cs.upload(x, 4, ones.data(), n * 4), Error);  // past the end of x
}

// Two contexts in one process, one with the validation layer and one without, each created after
// the other has been used: every call must go to its own device (no process-wide device table).
TEST(Runtime, ContextsWithAndWithoutValidationCoexist) {
  Context& validated = vktest::context();
  ContextOptions plain_options;
  plain_options.validation = false;
  plain_options.announce = false;
  plain_options.persistent_pipeline_cache = false;
  Context plain(plain_options);
  const size_t n = 256;
  for (Context* ctx : {&validated, &plain, &validated}) {
    Tensor x(*ctx, {1, 1, 1, static_cast<int64_t>(n)}), y(*ctx, {1, 1, 1, static_cast<int64_t>(n)});
    x.upload(std::vector<float>(n, 1.f));
    y.upload(std::vector<float>(n, 2.f));
    CommandStream cs(*ctx);
    axpy(cs, *ctx, x, y, 4.f);
    cs.submit_and_wait();
    EXPECT_EQ(y.download<float>(), std::vector<float>(n, 6.f)) << (ctx == &plain ? "plain" : "validated");
  }
}

// Push descriptors (VK_KHR_push_descriptor, lavapipe and NVIDIA have it) and descriptor sets from
// pools bind the same buffers: the same chain of dispatches gives the same values, validated.
TEST(Runtime, PushDescriptorsAndDescriptorSetsBindTheSame) {
  Context& pushed = vktest::context();
  if (pushed.info().push_descriptor) {
    EXPECT_TRUE(pushed.uses_push_descriptors());
  }
  ContextOptions o;
  o.validation = true;
  o.validation_fatal = true;
  o.announce = false;
  o.push_descriptors = false;
  Context sets(o);
  EXPECT_FALSE(sets.uses_push_descriptors());
  std::vector<std::vector<float>> results;
  for (Context* ctx : {&pushed, &sets}) {
    Tensor x(*ctx, {1, 1, 1, 1000}), y(*ctx, {1, 1, 1, 1000});
    std::vector<float> xv(1000), yv(1000);
    for (int i = 0; i < 1000; ++i) xv[i] = 0.5f * i, yv[i] = 1.f - i;
    x.upload(xv);
    y.upload(yv);
    CommandStream cs(*ctx);
    for (int k = 0; k < 20; ++k) axpy(cs, *ctx, x, y, 0.25f + k);  // 20 dependent dispatches in one submit
    cs.submit_and_wait();
    results.push_back(y.download<float>());
  }
  EXPECT_EQ(results[0], results[1]);
  EXPECT_FLOAT_EQ(results[0][10], 1.f - 10 + 5.f * (20 * 0.25f + 190.f));
  EXPECT_TRUE(sets.validation_messages().empty());
}

namespace {
// A validated context of its own (a message aborts), without the persistent cache, whose pipelines
// compile on `threads` workers.
ContextOptions compiler_test_options(uint32_t threads) {
  ContextOptions o;
  o.validation = true;
  o.validation_fatal = true;
  o.announce = false;
  o.persistent_pipeline_cache = false;
  o.pipeline_compile_threads = threads;
  return o;
}

// 12 pipelines (one per B) asked for and dispatched in one submission, each with its own push
// constant, alternating with the plain axpy; returns y. Pipelines compile on the context's workers
// (or, with none, when asked for) while later dispatches are recorded.
std::vector<float> chain_of_specialized_axpys(Context& ctx) {
  const size_t n = 300;
  Tensor x(ctx, {1, 1, 1, static_cast<int64_t>(n)}), y(ctx, {1, 1, 1, static_cast<int64_t>(n)});
  std::vector<float> xv(n);
  for (size_t i = 0; i < n; ++i) xv[i] = 0.01f * static_cast<float>(i);
  x.upload(xv);
  y.upload(std::vector<float>(n, 1.f));
  CommandStream cs(ctx);
  for (int k = 0; k < 12; ++k) {
    const AxpyPush p{0.5f * static_cast<float>(k), static_cast<uint32_t>(n)};
    cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_spec_axpy"), {spec_float(static_cast<float>(k))}, sizeof p),
                {in(x), inout(y)}, p, {(static_cast<uint32_t>(n) + 63) / 64}, {"spec_axpy"});
    axpy(cs, ctx, x, y, 1.f);
  }
  cs.submit_and_wait();
  return y.download<float>();
}
}  // namespace

// The same chain with pipelines compiled on 0, 1 and 3 worker threads, with and without push
// descriptors, validated: the same values, and each pipeline's build counted once as host time.
TEST(Runtime, PipelinesCompiledOnWorkersBindTheSame) {
  const size_t n = 300;
  float sum_b = 0;  // y = 1 + x * sum over k of ((0.5 k + k) + 1)
  for (int k = 0; k < 12; ++k) sum_b += 1.5f * static_cast<float>(k) + 1.f;
  for (uint32_t threads : {0u, 1u, 3u}) {
    for (bool push : {true, false}) {
      ContextOptions o = compiler_test_options(threads);
      o.push_descriptors = push;
      Context ctx(o);
      EXPECT_EQ(ctx.pipeline_compiler().threads(), threads);
      const std::vector<float> y = chain_of_specialized_axpys(ctx);
      ASSERT_EQ(y.size(), n);
      for (size_t i = 0; i < n; i += 37)
        EXPECT_NEAR(y[i], 1.f + 0.01f * static_cast<float>(i) * sum_b, 1e-4f) << "threads " << threads << ", item " << i;
      EXPECT_GT(ctx.traffic().pipeline_build_ms, 0.0);
      EXPECT_TRUE(ctx.validation_messages().empty());
    }
  }
}

// Pipelines asked for and never bound, with builds still queued or running when the context goes:
// each build is cancelled or waited for before its module is destroyed (no hang, no crash, and the
// validation layer sees no object destroyed in use).
TEST(Runtime, ContextWithQueuedPipelineBuildsClosesCleanly) {
  for (int round = 0; round < 3; ++round) {
    Context ctx(compiler_test_options(1));
    for (int k = 0; k < 24; ++k)
      ctx.pipeline(vktest::test_shader("runtime_spec_axpy"), {spec_float(100.f + static_cast<float>(k))}, sizeof(AxpyPush));
    EXPECT_TRUE(ctx.validation_messages().empty());
  }
}

TEST(Runtime, PipelineCompileThreadsAreChecked) {
  ContextOptions o;
  o.announce = false;
  o.pipeline_compile_threads = 65;
  try {
    Context ctx(o);
    FAIL() << "65 compile threads accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("pipeline_compile_threads 65: expected 0 to 64"), std::string::npos) << e.what();
  }
}

// A pipeline whose compile fails (the injected fault at the 2nd pipeline request) is reported when
// the submission that binds it is written, naming the shader and the VkResult; the stream is then
// empty and usable, and the other pipelines still run.
TEST(Runtime, FailedPipelineCompileIsReportedAtSubmitNamingTheShader) {
  ContextOptions o = compiler_test_options(1);
  o.fault = {FaultInjection::Site::pipeline, 2, VK_ERROR_OUT_OF_DEVICE_MEMORY};
  Context ctx(o);
  const size_t n = 64;
  Tensor x(ctx, {1, 1, 1, static_cast<int64_t>(n)}), y(ctx, {1, 1, 1, static_cast<int64_t>(n)});
  x.upload(std::vector<float>(n, 1.f));
  y.upload(std::vector<float>(n, 0.f));
  CommandStream cs(ctx);
  axpy(cs, ctx, x, y, 1.f);  // pipeline request 1: compiles
  const AxpyPush p{0.f, static_cast<uint32_t>(n)};
  cs.dispatch(ctx.pipeline(vktest::test_shader("runtime_spec_axpy"), {spec_float(5.f)}, sizeof p), {in(x), inout(y)}, p,
              {1}, {"spec_axpy"});  // request 2: fails
  try {
    cs.submit_and_wait();
    FAIL() << "the failed compile was not reported";
  } catch (const VulkanError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("vkCreateComputePipelines"), std::string::npos) << what;
    EXPECT_NE(what.find("runtime_spec_axpy"), std::string::npos) << what;
    EXPECT_NE(what.find("VK_ERROR_OUT_OF_DEVICE_MEMORY"), std::string::npos) << what;
  }
  EXPECT_EQ(cs.recorded(), 0u);
  axpy(cs, ctx, x, y, 2.f);
  cs.submit_and_wait();
  EXPECT_EQ(y.download<float>(), std::vector<float>(n, 2.f));  // the failed submission never ran
  EXPECT_EQ(ctx.faults().calls(FaultInjection::Site::pipeline), 2u);
  EXPECT_TRUE(ctx.validation_messages().empty());
}
