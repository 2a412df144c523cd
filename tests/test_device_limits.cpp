// The limits of real devices (docs/testing.md, "Devices and limits"): what each kernel shader needs,
// a pipeline over a limit refused by the limit's name, and the matrix's cells. A cell is this binary
// run with VKUNROLL_TEST_LIMITS lowering what lavapipe reports (tests/CMakeLists.txt, label `limits`):
// there every conv algorithm and the model run with parity, or refuse naming the lowered limit.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <random>
#include <string>

#include "conv_test_cases.hpp"
#include "model_test_util.hpp"
#include "op_test_harness.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/spirv_needs.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

// VKUNROLL_TEST_LIMITS set for the scope (the Context reads it when it is created), then restored.
class ScopedLimits {
 public:
  explicit ScopedLimits(const char* text) {
    if (const char* old = std::getenv("VKUNROLL_TEST_LIMITS")) old_ = old;
    ::setenv("VKUNROLL_TEST_LIMITS", text, 1);
  }
  ~ScopedLimits() {
    if (old_) ::setenv("VKUNROLL_TEST_LIMITS", old_->c_str(), 1);
    else ::unsetenv("VKUNROLL_TEST_LIMITS");
  }

 private:
  std::optional<std::string> old_;
};

std::unique_ptr<Context> lowered_context(const char* limits) {
  ScopedLimits scoped(limits);
  ContextOptions o;
  o.validation = true;
  o.validation_fatal = true;
  o.announce = false;
  return std::make_unique<Context>(o);
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// The Vulkan names of the limits this run's VKUNROLL_TEST_LIMITS lowered: an error naming one of them
// is the refusal the matrix accepts.
std::vector<std::string> lowered_limit_names() {
  const char* text = std::getenv("VKUNROLL_TEST_LIMITS");
  std::vector<std::string> names;
  if (!text) return names;
  const std::string t = text;
  if (t.find("shared=") != std::string::npos) names.push_back("maxComputeSharedMemorySize");
  if (t.find("invocations=") != std::string::npos) names.push_back("maxComputeWorkGroupInvocations");
  if (t.find("storage_range=") != std::string::npos) names.push_back("maxStorageBufferRange");
  if (t.find("fp16=0") != std::string::npos) names.push_back("storageBuffer16BitAccess");
  return names;
}

bool names_a_lowered_limit(const std::string& message) {
  for (const std::string& n : lowered_limit_names())
    if (message.find(n) != std::string::npos) return true;
  return false;
}

}  // namespace

// Every kernel shader's workgroup and shared memory resolve from its SPIR-V (so the pipelines' check
// never skips one), and the table of what they need is printed for docs/testing.md.
TEST(DeviceLimits, EveryKernelShaderDeclaresWhatItNeeds) {
  size_t shaders = 0;
  uint64_t most_shared = 0, most_invocations = 0;
  for (const auto& f : fs::directory_iterator(fs::path(VKUNROLL_SOURCE_DIR) / "shaders")) {
    if (f.path().extension() != ".comp") continue;
    const std::string name = f.path().stem().string();
    const ShaderModuleBlob& b = kernel_shader(name);
    const SpirvComputeNeeds n = spirv_compute_needs({b.words, b.word_count}, {});
    EXPECT_TRUE(n.resolved) << name << ": its workgroup or shared memory size is not read from the module";
    EXPECT_GT(n.invocations(), 0u) << name;
    std::printf("[ needs    ] %-32s %4llu invocations %6llu bytes shared (default constants)\n", name.c_str(),
                static_cast<unsigned long long>(n.invocations()), static_cast<unsigned long long>(n.shared_bytes));
    most_shared = std::max(most_shared, n.shared_bytes);
    most_invocations = std::max(most_invocations, n.invocations());
    ++shaders;
  }
  EXPECT_GT(shaders, 20u);
  std::printf("[ measured ] %zu kernel shaders: at most %llu invocations, %llu bytes of shared memory\n", shaders,
              static_cast<unsigned long long>(most_invocations), static_cast<unsigned long long>(most_shared));
}

// The reader applies specialization constants: the test shader's workgroup (constant 0) and its
// shared array of 2 * N floats (constant 1, through an OpSpecConstantOp).
TEST(DeviceLimits, NeedsFollowTheSpecializationConstants) {
  const ShaderModuleBlob& b = vktest::test_shader("runtime_shared_need");
  const SpirvComputeNeeds d = spirv_compute_needs({b.words, b.word_count}, {});
  EXPECT_TRUE(d.resolved);
  EXPECT_EQ(d.invocations(), 1u);  // local_size_x_id's default: 1
  EXPECT_EQ(d.shared_bytes, 2u * 1024 * 4);
  const SpirvComputeNeeds s = spirv_compute_needs({b.words, b.word_count}, {256, 4096});
  EXPECT_EQ(s.invocations(), 256u);
  EXPECT_EQ(s.shared_bytes, 2u * 4096 * 4);
}

// A pipeline over a lowered limit is refused when it is made, by the limit's Vulkan name and the
// override that lowered it; under the limit it builds.
TEST(DeviceLimits, APipelineOverALimitIsRefusedNamingIt) {
  auto ctx = lowered_context("shared=16384,invocations=128");
  EXPECT_EQ(ctx->info().max_shared_memory, 16384u);
  EXPECT_EQ(ctx->info().max_workgroup_invocations, 128u);
  const ShaderModuleBlob& b = vktest::test_shader("runtime_shared_need");
  const std::string shared = error_of([&] { ctx->pipeline(b, {64, 4096}); });  // 32 KiB
  EXPECT_NE(shared.find("maxComputeSharedMemorySize 16384"), std::string::npos) << shared;
  EXPECT_NE(shared.find("runtime_shared_need"), std::string::npos) << shared;
  EXPECT_NE(shared.find("VKUNROLL_TEST_LIMITS"), std::string::npos) << shared;
  const std::string wide = error_of([&] { ctx->pipeline(b, {256, 64}); });
  EXPECT_NE(wide.find("maxComputeWorkGroupInvocations 128"), std::string::npos) << wide;
  EXPECT_EQ(error_of([&] { ctx->pipeline(b, {128, 2048}).handle(); }), "");  // 16 KiB, 128: fits
}

// The override only lowers: a value above the device's, an unknown key or a bad value is a named error.
TEST(DeviceLimits, BadOverridesAreNamedErrors) {
  const uint64_t range = vktest::context().info().max_storage_buffer_range;
  const std::string above = "storage_range=" + std::to_string(range * 2);
  for (const auto& [text, want] : std::vector<std::pair<std::string, std::string>>{
           {above, "maxStorageBufferRange"}, {"shared=0", "positive whole number"}, {"subgroup=3", "power of two"},
           {"warp=32", "unknown key 'warp'"}, {"fp16=1", "expected 0"}, {"shared", "key=value"}}) {
    const std::string m = error_of([&] { lowered_context(text.c_str()); });
    EXPECT_NE(m.find("VKUNROLL_TEST_LIMITS"), std::string::npos) << text << ": " << m;
    EXPECT_NE(m.find(want), std::string::npos) << text << ": " << m;
  }
}

// A cell of the matrix reports what it lowered, and nothing else changed.
TEST(DeviceLimits, TheDeviceReportsTheLoweredLimits) {
  const DeviceInfo& d = vktest::context().info();
  const DeviceList raw = Context::enumerate();
  const DeviceInfo& r = raw.devices.at(d.index);
  const std::string t = std::getenv("VKUNROLL_TEST_LIMITS") ? std::getenv("VKUNROLL_TEST_LIMITS") : "";
  auto value = [&](const std::string& key, uint64_t dflt) {
    const size_t at = t.find(key + "=");
    return at == std::string::npos ? dflt : std::stoull(t.substr(at + key.size() + 1));
  };
  EXPECT_EQ(d.max_shared_memory, value("shared", r.max_shared_memory));
  EXPECT_EQ(d.max_workgroup_invocations, value("invocations", r.max_workgroup_invocations));
  EXPECT_EQ(d.max_storage_buffer_range, value("storage_range", r.max_storage_buffer_range));
  EXPECT_EQ(d.subgroup_size, value("subgroup", r.subgroup_size));
  EXPECT_EQ(d.storage_buffer_16bit, r.storage_buffer_16bit && value("fp16", 1) != 0);
  EXPECT_EQ(d.timestamps, r.timestamps && value("timestamps", 1) != 0);
  std::printf("[ cell     ] VKUNROLL_TEST_LIMITS='%s' on '%s'\n", t.c_str(), d.name.c_str());
}

// The matrix: every conv algorithm, in each precision the cell leaves, on the canary cases: parity,
// or a refusal naming a limit the cell lowered. The automatic choice must run.
TEST(DeviceLimits, EveryConvAlgorithmRunsWithParityOrRefusesNamingTheLimit) {
  Context& ctx = vktest::context();
  using convtest::Limits;
  for (ConvAlgo algo : {ConvAlgo::automatic, ConvAlgo::naive, ConvAlgo::blocked, ConvAlgo::winograd, ConvAlgo::gemm,
                        ConvAlgo::direct, ConvAlgo::pointwise, ConvAlgo::igemm_l, ConvAlgo::igemm_m, ConvAlgo::igemm_s,
                        ConvAlgo::igemm_n}) {
    std::mt19937 rng(7);
    std::vector<optest::OpCase> cases;
    for (const convtest::Case& c : convtest::canary_cases()) cases.push_back(convtest::conv_case(c, algo, Limits{}, rng));
    optest::OpTest test{std::string("conv2d ") + conv_algo_name(algo) + " (limits cell)", cases,
                        {convtest::kTol, convtest::kTolFp16}};
    if (algo != ConvAlgo::automatic) test.refusal = names_a_lowered_limit;  // the automatic choice must run
    const optest::OpTestReport r = optest::run_op_test(ctx, test);
    EXPECT_GT(r.ran[0] + r.refused[0], 0) << conv_algo_name(algo);
  }
}

// The default model (the device's own conv choice, then the GPU family) in the cell: golden parity
// with the PyTorch mirror, or a refusal naming a lowered limit (fp16 only: fp32 must always run).
TEST(DeviceLimits, TheModelRunsWithParityInEveryCell) {
  const Weights w = load_weights(modeltest::fixture("selfunroll_tiny.safetensors"));
  const SafetensorsFile g = read_safetensors(modeltest::fixture("selfunroll_golden_s_64x48.safetensors"));
  for (const bool gpu_family : {false, true}) {
    VulkanBackend vk(vktest::context());
    if (gpu_family) vk.set_conv_choice(nullptr, ConvChoice::gpu);
    Model model(vk, w);
    RunOptions opt;
    opt.mode = Mode::s;
    const auto out = model.run(modeltest::inputs_from(g), opt);
    for (const auto& [name, arr] : out)
      EXPECT_LE(modeltest::max_abs_diff(arr, modeltest::array_from(g.get(output_name(name)))), 1e-4)
          << name << (gpu_family ? " (gpu family)" : " (device's choice)");
  }
}
