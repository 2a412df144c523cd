// Which Vulkan implementation a run tested, and the second one's frames (docs/testing.md, "Devices and
// limits"): the `swiftshader` label runs this binary with SwiftShader forced (VKUNROLL_DEVICE) and
// lavapipe visible beside it, so its frames are compared with lavapipe's in one run.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cli_test_util.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {
// The device this run was forced to (VKUNROLL_EXPECT_DEVICE, else the suite's VKUNROLL_DEVICE).
std::string expected_device() {
  if (const char* e = std::getenv("VKUNROLL_EXPECT_DEVICE")) return e;
  if (const char* e = std::getenv("VKUNROLL_DEVICE")) return e;
  return "";
}
bool on_swiftshader() { return expected_device() == "SwiftShader"; }

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// The largest difference between two runs' PNG frames (same names), and how many were compared.
std::pair<double, size_t> frames_apart(const fs::path& a_dir, const fs::path& b_dir) {
  double worst = 0;
  size_t frames = 0;
  for (const auto& f : fs::directory_iterator(a_dir)) {
    const cv::Mat a = cv::imread(f.path().string(), cv::IMREAD_UNCHANGED);
    const cv::Mat b = cv::imread((b_dir / f.path().filename()).string(), cv::IMREAD_UNCHANGED);
    if (a.empty() || b.empty() || a.size() != b.size() || a.type() != b.type()) return {INFINITY, frames};
    cv::Mat d;
    cv::absdiff(a, b, d);
    double mx = 0;
    cv::minMaxLoc(d.reshape(1), nullptr, &mx);
    worst = std::max(worst, mx);
    ++frames;
  }
  return {worst, frames};
}
}  // namespace

// The run is on the device it asked for: a forced SwiftShader run that silently fell back to lavapipe
// (its ICD missing) would pass every other test while testing nothing new.
TEST(Devices, TheRunIsOnTheDeviceItAsksFor) {
  const std::string want = expected_device();
  ASSERT_FALSE(want.empty()) << "the suite sets VKUNROLL_DEVICE";
  const DeviceInfo& d = vktest::context().info();
  EXPECT_NE(lower(d.name).find(lower(want)), std::string::npos) << d.name << " is not " << want;
  std::printf("[ device   ] %s (%s, Vulkan %s), subgroup %u, %u bytes shared, fp16 %s, 16-bit storage %s\n", d.name.c_str(),
              d.driver_info.c_str(), d.api_version_string().c_str(), d.subgroup_size, d.max_shared_memory,
              d.shader_float16 ? "yes" : "no", d.storage_buffer_16bit ? "yes" : "no");
}

// fp16 through the CLI: it runs where the device has 16-bit storage; elsewhere (SwiftShader) it is
// refused, exit non-zero, naming the missing feature and the device.
TEST(Devices, Fp16RunsOrIsRefusedNamingTheFeature) {
  const fs::path dir = clitest::temp_dir("devices", "fp16");
  ASSERT_EQ(clitest::cli("simulate --out " + (dir / "seq").string() + " --size 32x24 --frames 2 --seed 3").rc, 0);
  const auto r = clitest::cli("unroll " + (dir / "seq").string() + " --out " + (dir / "out").string() +
                              " --precision fp16 --conv-choice heuristic --quiet --no-video");
  const DeviceInfo& d = vktest::context().info();
  if (d.storage_buffer_16bit) {
    EXPECT_EQ(r.rc, 0) << r.out;
  } else {
    EXPECT_NE(r.rc, 0) << r.out;
    EXPECT_TRUE(clitest::has(r, "storageBuffer16BitAccess")) << r.out;
    EXPECT_TRUE(clitest::has(r, d.name)) << r.out;
    EXPECT_FALSE(fs::exists(dir / "out" / "summary.json")) << "a refused run wrote a summary";
  }
  fs::remove_all(dir);
}

// SwiftShader's frames equal lavapipe's within one PNG step: the default model with each device's own
// heuristic conv choice (no tuning run), the GPU family, and a tiled run (`swiftshader` label only: there both are visible).
TEST(Devices, SwiftShaderFramesEqualLavapipesWithinOnePngStep) {
  if (!on_swiftshader()) GTEST_SKIP() << "the swiftshader label's test (VKUNROLL_EXPECT_DEVICE=SwiftShader)";
  const fs::path dir = clitest::temp_dir("devices", "frames");
  ASSERT_EQ(clitest::cli("simulate --out " + (dir / "seq").string() + " --size 64x48 --frames 2 --seed 5").rc, 0);
  for (const std::string& run : {std::string("--conv-choice heuristic"), std::string("--conv-choice gpu"),
                                 std::string("--conv-choice heuristic --tile 32")}) {
    fs::path outs[2];
    int i = 0;
    for (const std::string device : {"llvmpipe", "SwiftShader"}) {
      outs[i] = dir / (std::to_string(i) + device);
      const auto r = clitest::cli("unroll " + (dir / "seq").string() + " --out " + outs[i].string() + " " + run +
                                      " --quiet --no-video",
                                  "VKUNROLL_DEVICE=" + device + " ");
      ASSERT_EQ(r.rc, 0) << device << " " << run << ": " << r.out;
      ++i;
    }
    const auto [worst, frames] = frames_apart(outs[0] / "frames", outs[1] / "frames");
    EXPECT_GE(frames, 2u) << run;
    EXPECT_LE(worst, 1.0) << run << ": SwiftShader's frames are more than one PNG step from lavapipe's";
    std::printf("[ measured ] %s: %zu frames, SwiftShader vs lavapipe at most %.0f PNG steps apart\n", run.c_str(), frames, worst);
    fs::remove_all(outs[0]);
    fs::remove_all(outs[1]);
  }
  fs::remove_all(dir);
}
