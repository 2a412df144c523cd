// The conv choice through the CLI, end to end on real frames: `unroll --conv-choice gpu` on
// lavapipe against the device's own choice, and a committed table found by the device's identity.
// (Not in the device bundle: it needs the CLI and OpenCV.)
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <unistd.h>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "model_test_util.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;

namespace {

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll_conv_choice_cli_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return {std::istreambuf_iterator<char>(in), {}};
}

}  // namespace

// --conv-choice gpu runs the GPU kernels' rule on lavapipe: other algorithms than lavapipe's own
// choice (the igemm family, transposed convs as its sub-pixel phases, the folded convs), at most 100
// dispatches per GS frame, and the shipped default model's GS frames equal those of lavapipe's
// choice within one PNG step.
TEST(ConvChoice, GpuChoiceKeepsTheFramesOfTheDevicesOwnChoice) {
  const std::string cli = VKUNROLL_CLI_PATH;
  if (!fs::exists(cli)) GTEST_SKIP() << cli << " is not here (the device bundle carries no CLI)";
  if (vktest::context().info().type != VK_PHYSICAL_DEVICE_TYPE_CPU) GTEST_SKIP() << "on a GPU both choices are the GPU rule";
  const fs::path dir = fresh_dir("gpu");
  const std::string env = "VKUNROLL_CACHE_DIR=" + (dir / "cache").string() + " ";
  const std::string model = std::string(VKUNROLL_SOURCE_DIR) + "/models/selfunroll_small_physics.safetensors";
  ASSERT_EQ(std::system((env + cli + " simulate --out " + (dir / "seq").string() +
                         " --size 64x48 --frames 2 --gt-per-frame 2 --seed 5 > /dev/null 2>&1").c_str()), 0);
  std::map<std::string, nlohmann::json> calls;
  for (const std::string choice : {"heuristic", "gpu"}) {
    const fs::path out = dir / choice;
    ASSERT_EQ(std::system((env + cli + " unroll " + (dir / "seq").string() + " --out " + out.string() + " --model " + model +
                           " --mode s --sparse off --conv-choice " + choice + " --quiet --no-video --profile > " +
                           (dir / (choice + ".txt")).string() + " 2>&1").c_str()), 0)
        << slurp(dir / (choice + ".txt"));
    const auto summary = nlohmann::json::parse(slurp(out / "summary.json"));
    EXPECT_EQ(summary.at("conv_algorithms").at("choice"), choice);
    calls[choice] = summary.at("conv_algorithms").at("calls_by_algorithm");
    if (choice != "gpu") continue;
    // Issue 49's goal: at most 100 dispatches per GS frame for the default model with the GPU family;
    // the UNets' pads and crops, SFENet1's space-to-depth and UPNet.2's depth-to-space are folded.
    EXPECT_LE(summary.at("device_traffic_per_gs_frame").at("dispatches").get<double>(), 100.0) << summary.dump();
    for (const auto& [op, v] : summary.at("gpu_ms_per_gs_frame_by_op").items())
      for (const char* folded : {"reflection_pad", "space_to_depth", "depth_to_space", "crop"})
        EXPECT_EQ(op.find(folded), std::string::npos) << op << " ran as its own dispatch";
  }
  EXPECT_NE(calls["gpu"], calls["heuristic"]) << calls["gpu"].dump();
  EXPECT_TRUE(calls["gpu"].contains("igemm_n")) << calls["gpu"].dump();  // the 8-channel UNet levels, the heads
  EXPECT_TRUE(calls["gpu"].contains("transposed igemm")) << calls["gpu"].dump();
  EXPECT_FALSE(calls["heuristic"].contains("transposed igemm")) << calls["heuristic"].dump();
  size_t frames = 0;
  for (const auto& f : fs::directory_iterator(dir / "heuristic" / "frames")) {
    const cv::Mat a = cv::imread(f.path().string(), cv::IMREAD_UNCHANGED);
    const cv::Mat b = cv::imread((dir / "gpu" / "frames" / f.path().filename()).string(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(a.empty()) << f.path();
    ASSERT_FALSE(b.empty()) << "gpu run lacks " << f.path().filename();
    ASSERT_EQ(a.size(), b.size());
    cv::Mat d;
    cv::absdiff(a, b, d);
    double mx = 0;
    cv::minMaxLoc(d.reshape(1), nullptr, &mx);
    EXPECT_LE(mx, 1.0) << f.path().filename() << ": more than one PNG step apart";
    ++frames;
  }
  EXPECT_EQ(frames, 2u);  // one GS frame per RS frame (--times 0.5)
  fs::remove_all(dir);
}

// A committed table measured on this device model (written here for lavapipe's identity: no GPU
// numbers are invented) is found in VKUNROLL_CONV_TABLES and used by `unroll --conv-choice auto`
// with no tuning run; a table of another device (a made-up identity) is not.
TEST(ConvChoice, CommittedTableOfThisDeviceIsUsedWithNoTuning) {
  const std::string cli = VKUNROLL_CLI_PATH;
  if (!fs::exists(cli)) GTEST_SKIP() << cli << " is not here (the device bundle carries no CLI)";
  const fs::path dir = fresh_dir("committed");
  Context& ctx = vktest::context();
  const Weights w = load_weights(modeltest::fixture("selfunroll_tiny.safetensors"));
  // Every key the unroll below meets (S, 40x30, one item, fp32), from a census of the same run.
  auto census = std::make_shared<ConvChoiceTable>();
  {
    VulkanBackend vk(ctx);
    vk.set_conv_choice(census, ConvChoice::retune, ConvTimingBudget{1, 0, 0, true});
    RunOptions opt;
    opt.mode = Mode::s;
    Model(vk, w).run(modeltest::random_inputs(1, 30, 40, w.config.N, 31), opt);
  }
  ASSERT_GT(census->entries().size(), 5u);
  ConvChoiceTable mine, other;
  for (const auto& [key, e] : census->entries()) {
    mine.set(key, {"blocked", 1.0, "blocked=1.0000", e.heuristic});  // blocked applies to every conv
    other.set(key, {"direct", 1.0, "direct=1.0000", e.heuristic});
  }
  fs::create_directories(dir / "tables");
  ConvDeviceIdentity fake{"NVIDIA H200 (made up for this test)", "580.159.4", "00000000-0000-0000-0000-000000000001", 0x10de, 0x2335};
  other.save((dir / "tables" / "a-other.tsv").string(), "a made-up device", fake);
  mine.save((dir / "tables" / "b-lavapipe.tsv").string(), conv_choice_header(ctx), conv_device_identity(ctx));
  const std::string env = "VKUNROLL_CACHE_DIR=" + (dir / "cache").string() + " VKUNROLL_CONV_TABLES=" + (dir / "tables").string() + " ";
  ASSERT_EQ(std::system((env + cli + " simulate --out " + (dir / "seq").string() +
                         " --size 40x30 --frames 2 --gt-per-frame 1 --seed 3 > /dev/null 2>&1").c_str()), 0);
  ASSERT_EQ(std::system((env + cli + " unroll " + (dir / "seq").string() + " --out " + (dir / "out").string() + " --model " +
                         modeltest::fixture("selfunroll_tiny.safetensors") + " --mode s --sparse off --quiet --no-video > " +
                         (dir / "unroll.txt").string() + " 2>&1").c_str()), 0)
      << slurp(dir / "unroll.txt");
  const auto c = nlohmann::json::parse(slurp(dir / "out" / "summary.json")).at("conv_algorithms");
  EXPECT_EQ(c.at("choice"), "auto");
  EXPECT_EQ(c.at("committed_table"), (dir / "tables" / "b-lavapipe.tsv").string());
  EXPECT_EQ(c.at("committed_table_match"), "device uuid and driver");
  EXPECT_EQ(c.at("shapes_timed").get<uint64_t>(), 0u);
  EXPECT_GT(c.at("convs_from_table").get<uint64_t>(), 0u);
  for (const auto& [algo, calls] : c.at("calls_by_algorithm").items())  // every call took the table's blocked
    EXPECT_TRUE(algo == "blocked" || algo == "transposed blocked") << algo << ": " << calls;
  fs::remove_all(dir);
}
