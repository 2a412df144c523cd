// The measured conv algorithm choice (host/model/conv_choice.hpp): the table file, the timing of
// candidates, the backend taking the table's algorithm (and falling back where it cannot), and
// `vkunroll tune` writing the table that `unroll` reads.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "kernel_test_util.hpp"
#include "model_test_util.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/trace.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::modeltest;

namespace {

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll_conv_choice_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

HostTensor random_host(Shape s, uint32_t seed, float scale) {
  std::mt19937 rng(seed);
  return ktest::random_tensor(s, rng, -scale, scale);
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return {std::istreambuf_iterator<char>(in), {}};
}

}  // namespace

TEST(ConvChoice, TableRoundTripsAndMergesWithTheFile) {
  const fs::path dir = fresh_dir("table");
  const std::string path = (dir / "t.tsv").string();
  ConvChoiceTable a;
  a.set("conv2d k3 s1 p1 8->8 fp32 n<=1 16x16", {"winograd", 1.5, "blocked=2.0000 winograd=1.5000", "direct"});
  EXPECT_TRUE(a.changed());
  a.save(path, "test device");
  ConvChoiceTable b;
  b.set("conv2d k1 s1 p0 8->8 fp16 n<=2 16x16", {"gemm", 0.25, "gemm=0.2500", "gemm"});
  b.save(path, "test device");  // merged over what the file holds: both entries stay
  std::vector<std::string> warnings;
  const ConvChoiceTable c = ConvChoiceTable::load(path, &warnings);
  EXPECT_TRUE(warnings.empty());
  EXPECT_FALSE(c.changed());
  ASSERT_EQ(c.entries().size(), 2u);
  const ConvChoiceEntry* e = c.find("conv2d k3 s1 p1 8->8 fp32 n<=1 16x16");
  ASSERT_NE(e, nullptr);
  EXPECT_EQ(e->algo, "winograd");
  EXPECT_DOUBLE_EQ(e->ms, 1.5);
  EXPECT_EQ(e->timings, "blocked=2.0000 winograd=1.5000");
  EXPECT_EQ(e->heuristic, "direct");
  EXPECT_EQ(c.find("conv2d k1 s1 p0 8->8 fp16 n<=2 16x16")->algo, "gemm");
  EXPECT_EQ(c.find("missing"), nullptr);
  EXPECT_EQ(ConvChoiceTable::load((dir / "absent.tsv").string(), &warnings).entries().size(), 0u);
  for (const auto& f : fs::directory_iterator(dir)) EXPECT_EQ(f.path().filename().string().find(".tmp"), std::string::npos);
  fs::remove_all(dir);
}

TEST(ConvChoice, DamagedLinesAreSkippedWithTheFileAndLine) {
  const fs::path dir = fresh_dir("damaged");
  const fs::path p = dir / "t.tsv";
  {
    std::ofstream out(p);
    out << "# vkunroll conv algorithm choices v1: x\n"
        << "good key\tdirect\t0.5\tdirect=0.5\twinograd\n"
        << "short line\tdirect\n"
        << "bad ms\tdirect\tfast\tdirect=1\tdirect\n"
        << "negative\tdirect\t-1\tdirect=1\tdirect\n";
  }
  std::vector<std::string> w;
  const ConvChoiceTable t = ConvChoiceTable::load(p.string(), &w);
  ASSERT_EQ(w.size(), 3u);
  EXPECT_NE(w[0].find(p.string() + ":3:"), std::string::npos) << w[0];
  EXPECT_NE(w[1].find(":4:"), std::string::npos) << w[1];
  EXPECT_NE(w[2].find(":5:"), std::string::npos) << w[2];
  EXPECT_EQ(t.entries().size(), 1u);
  ASSERT_NE(t.find("good key"), nullptr);
  // Another format's file: nothing of it is read.
  {
    std::ofstream out(p);
    out << "something else\ngood key\tdirect\t0.5\tdirect=0.5\twinograd\n";
  }
  w.clear();
  EXPECT_EQ(ConvChoiceTable::load(p.string(), &w).entries().size(), 0u);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find(":1:"), std::string::npos);
  fs::remove_all(dir);
}

TEST(ConvChoice, ParseNamesTheOption) {
  EXPECT_EQ(parse_conv_choice("auto", "--conv-choice"), ConvChoice::automatic);
  EXPECT_EQ(parse_conv_choice("retune", "--conv-choice"), ConvChoice::retune);
  try {
    parse_conv_choice("fastest", "--conv-choice");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--conv-choice 'fastest'"), std::string::npos);
  }
}

TEST(ConvChoice, KeysNameTheShapeWithTheBatchRoundedUp) {
  Context& ctx = vktest::context();
  const Conv2d conv(ctx, random_host({12, 8, 3, 3}, 1, 0.3f), random_host({1, 1, 1, 12}, 2, 0.1f), Conv2dParams{3, 2, 1, {}});
  EXPECT_EQ(conv_choice_key(conv, {3, 8, 20, 30}, true), "conv2d k3 s2 p1 8->12 fp32 res n<=4 20x30");
  EXPECT_EQ(conv_choice_key(conv, {1, 8, 20, 30}, false), "conv2d k3 s2 p1 8->12 fp32 n<=1 20x30");
  const ConvTranspose2d deconv(ctx, random_host({8, 4, 4, 4}, 3, 0.3f), random_host({1, 1, 1, 4}, 4, 0.1f));
  EXPECT_EQ(conv_choice_key(deconv, {2, 8, 5, 7}), "conv_transpose2d k4 s2 p1 8->4 fp32 n<=2 5x7");
}

TEST(ConvChoice, TimingNamesTheFastestCandidate) {
  Context& ctx = vktest::context();
  const Conv2d conv(ctx, random_host({16, 8, 3, 3}, 5, 0.3f), random_host({1, 1, 1, 16}, 6, 0.1f), Conv2dParams{3, 1, 1, {}});
  const Shape in{1, 8, 24, 20};
  const auto cands = conv.candidates(in);
  ASSERT_GE(cands.size(), 3u);  // blocked, winograd, direct at least
  for (ConvAlgo a : cands) EXPECT_NE(a, ConvAlgo::naive);
  const ConvChoiceEntry e = time_conv_algorithms(ctx, conv, in, true, ConvTimingBudget{1});
  double least = 1e300;
  size_t listed = 0;
  std::istringstream ts(e.timings);
  for (std::string item; ts >> item; ++listed) {
    ASSERT_EQ(item.find("rejected"), std::string::npos) << item;  // every lavapipe path agrees
    const auto eq = item.find('=');
    ASSERT_NE(eq, std::string::npos) << item;
    least = std::min(least, std::stod(item.substr(eq + 1)));
  }
  EXPECT_EQ(listed, cands.size());
  EXPECT_NEAR(e.ms, least, 1e-4);
  EXPECT_GT(e.ms, 0.0);
  EXPECT_EQ(e.heuristic, conv_algo_name(conv.choose_algorithm(in.h, in.w)));
  // 1x1 convs have the GEMM; transposed convs their own candidates.
  const Conv2d pw(ctx, random_host({8, 8, 1, 1}, 7, 0.3f), random_host({1, 1, 1, 8}, 8, 0.1f), Conv2dParams{1, 1, 0, {}});
  const auto pc = pw.candidates({1, 8, 16, 16});
  EXPECT_NE(std::find(pc.begin(), pc.end(), ConvAlgo::gemm), pc.end());
  EXPECT_EQ(std::find(pc.begin(), pc.end(), ConvAlgo::winograd), pc.end());
  const ConvTranspose2d deconv(ctx, random_host({8, 4, 4, 4}, 9, 0.3f), random_host({1, 1, 1, 4}, 10, 0.1f));
  const ConvChoiceEntry d = time_conv_algorithms(ctx, deconv, {1, 8, 6, 6}, ConvTimingBudget{1});
  EXPECT_TRUE(d.algo == "blocked" || d.algo == "direct") << d.algo;
}

TEST(ConvChoice, ADisagreeingResultIsRejected) {
  const std::vector<float> ref{0.5f, -2.f, 1.f, 0.f};
  EXPECT_EQ(conv_choice_disagreement(ref, {0.5005f, -2.f, 1.f, 0.f}, Precision::fp32), "");  // 5e-4 of range 2
  EXPECT_NE(conv_choice_disagreement(ref, {0.51f, -2.f, 1.f, 0.f}, Precision::fp32).find("rejected"), std::string::npos);
  EXPECT_EQ(conv_choice_disagreement(ref, {0.53f, -2.f, 1.f, 0.f}, Precision::fp16), "");
  EXPECT_NE(conv_choice_disagreement(ref, {0.6f, -2.f, 1.f, 0.f}, Precision::fp16), "");
  EXPECT_NE(conv_choice_disagreement(ref, {NAN, -2.f, 1.f, 0.f}, Precision::fp16), "");
  EXPECT_NE(conv_choice_disagreement(ref, {0.5f}, Precision::fp32), "");
}

// Retune times every shape once; cached then takes the table's algorithm for every conv call, and
// the outputs equal the heuristic's within fp32 rounding (the algorithms' parity).
TEST(ConvChoice, BackendTakesTheTablesAlgorithmAndKeepsTheResult) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  const ModelInputs in = random_inputs(2, 24, 32, w.config.N, 21);
  RunOptions opt;
  opt.mode = Mode::m;
  opt.outputs = {ModelOutput::out, ModelOutput::fused};
  Context& ctx = vktest::context();
  VulkanBackend heuristic(ctx);
  const auto ref = Model(heuristic, w).run(in, opt);
  EXPECT_EQ(heuristic.convs_from_table(), 0u);

  auto table = std::make_shared<ConvChoiceTable>();
  VulkanBackend vk(ctx);
  vk.set_conv_choice(table, ConvChoice::retune, 1);
  Model model(vk, w);
  const auto tuned = model.run(in, opt);
  EXPECT_GT(vk.convs_timed(), 5u);
  EXPECT_EQ(vk.convs_timed(), table->entries().size());
  const uint64_t calls = vk.convs_from_table();
  EXPECT_GE(calls, vk.convs_timed());
  // Every entry names one of its candidates.
  for (const auto& [key, e] : table->entries()) EXPECT_NE(e.timings.find(e.algo + "="), std::string::npos) << key;
  vk.set_conv_choice(table, ConvChoice::cached);
  const uint64_t timed = vk.convs_timed();
  const auto again = model.run(in, opt);
  EXPECT_EQ(vk.convs_timed(), timed);  // cached never times
  EXPECT_EQ(vk.convs_from_table(), 2 * calls);
  for (const auto& [name, t] : ref) {
    EXPECT_LE(max_abs_diff(t, tuned.at(name)), 1e-4) << name;
    EXPECT_LE(max_abs_diff(t, again.at(name)), 1e-4) << name;
  }
}

// An entry naming an algorithm the shape cannot take (a stale or foreign table) falls back to the
// heuristic instead of failing; measured times the shapes the table lacks.
TEST(ConvChoice, InapplicableEntryFallsBackAndMeasuredFillsGaps) {
  Context& ctx = vktest::context();
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  const ModelInputs in = random_inputs(1, 16, 16, w.config.N, 22);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  auto table = std::make_shared<ConvChoiceTable>();
  VulkanBackend probe(ctx);
  probe.set_conv_choice(table, ConvChoice::retune, 1);
  Model(probe, w).run(in, opt);
  ASSERT_FALSE(table->entries().empty());
  auto bad = std::make_shared<ConvChoiceTable>();
  for (const auto& [key, e] : table->entries()) bad->set(key, {"no-such-algorithm", 1.0, "", e.heuristic});
  VulkanBackend vk(ctx);
  vk.set_conv_choice(bad, ConvChoice::cached);
  VulkanBackend plain(ctx);
  const auto ref = Model(plain, w).run(in, opt);
  const auto out = Model(vk, w).run(in, opt);
  EXPECT_EQ(vk.convs_from_table(), 0u);
  EXPECT_EQ(max_abs_diff(ref.at(ModelOutput::fused), out.at(ModelOutput::fused)), 0.0);  // the same heuristic algorithms

  auto partial = std::make_shared<ConvChoiceTable>();
  partial->set(table->entries().begin()->first, table->entries().begin()->second);
  VulkanBackend m(ctx);
  m.set_conv_choice(partial, ConvChoice::measured, 1);
  Model(m, w).run(in, opt);
  EXPECT_EQ(m.convs_timed(), table->entries().size() - 1);
  EXPECT_EQ(partial->entries().size(), table->entries().size());
}

TEST(ConvChoice, AutomaticTimesOnlyOnGpus) {
  Context& ctx = vktest::context();
  const bool cpu_device = ctx.info().type == VK_PHYSICAL_DEVICE_TYPE_CPU;  // lavapipe
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  auto table = std::make_shared<ConvChoiceTable>();
  VulkanBackend vk(ctx);
  vk.set_conv_choice(table, ConvChoice::automatic);
  RunOptions opt;
  opt.outputs = {ModelOutput::fused};
  Model(vk, w).run(random_inputs(1, 16, 16, w.config.N, 23), opt);
  if (cpu_device) {
    EXPECT_EQ(vk.convs_timed(), 0u);  // on a CPU device auto reads the table and never times
    EXPECT_TRUE(table->entries().empty());
  } else {
    EXPECT_GT(vk.convs_timed(), 0u);  // on a GPU it times the shapes the table lacks
    EXPECT_EQ(table->entries().size(), vk.convs_timed());
  }
}

TEST(ConvChoice, PathIsKeyedByDeviceUuidAndDriver) {
  Context& ctx = vktest::context();
  const std::string p = conv_choice_path(ctx);
  ASSERT_FALSE(p.empty());  // the tests set VKUNROLL_CACHE_DIR
  EXPECT_NE(p.find(ctx.info().uuid_string()), std::string::npos) << p;
  EXPECT_NE(p.find(ctx.info().driver_version_string()), std::string::npos) << p;
  EXPECT_EQ(fs::path(p).parent_path().string(), Context::cache_directory());
}

// `vkunroll tune` writes the device's table; `unroll --conv-choice cached` takes its entries and
// says so in summary.json (each in a cache directory of its own).
TEST(ConvChoice, TuneWritesTheTableUnrollReads) {
  const fs::path dir = fresh_dir("cli");
  const std::string env = "VKUNROLL_CACHE_DIR=" + (dir / "cache").string() + " ";
  const std::string cli = VKUNROLL_CLI_PATH;
  if (!fs::exists(cli)) GTEST_SKIP() << cli << " is not here (the device bundle carries no CLI)";
  const std::string model = fixture("selfunroll_tiny.safetensors");
  ASSERT_EQ(std::system((env + cli + " tune --model " + model + " --size 40x30 --tile 0 --reps 1 --warm-ms 0 --budget-s 0 > " +
                         (dir / "tune.txt").string() + " 2>&1").c_str()), 0)
      << slurp(dir / "tune.txt");
  const std::string report = slurp(dir / "tune.txt");
  EXPECT_NE(report.find("FMA ceiling after"), std::string::npos) << report;
  EXPECT_NE(report.find("candidates timed in"), std::string::npos) << report;
  EXPECT_NE(report.find("budget arithmetic"), std::string::npos) << report;
  EXPECT_EQ(report.find("were not timed"), std::string::npos) << report;  // no budget: every shape timed
  EXPECT_NE(report.find("heuristic / measured"), std::string::npos) << report;
  std::vector<fs::path> tables;
  for (const auto& f : fs::directory_iterator(dir / "cache"))
    if (f.path().filename().string().rfind("conv-choices-", 0) == 0) tables.push_back(f.path());
  ASSERT_EQ(tables.size(), 1u);
  const ConvChoiceTable t = ConvChoiceTable::load(tables[0].string(), nullptr);
  EXPECT_GT(t.entries().size(), 5u);

  ASSERT_EQ(std::system((env + cli + " simulate --out " + (dir / "seq").string() +
                         " --size 40x30 --frames 2 --gt-per-frame 1 --seed 3 > /dev/null 2>&1").c_str()), 0);
  ASSERT_EQ(std::system((env + cli + " unroll " + (dir / "seq").string() + " --out " + (dir / "out").string() +
                         " --model " + model + " --mode s --sparse off --conv-choice cached --quiet --no-video > " +
                         (dir / "unroll.txt").string() + " 2>&1").c_str()), 0)
      << slurp(dir / "unroll.txt");
  const auto summary = nlohmann::json::parse(slurp(dir / "out" / "summary.json"));
  const auto& c = summary.at("conv_algorithms");
  EXPECT_EQ(c.at("choice"), "cached");
  EXPECT_EQ(c.at("table"), tables[0].string());
  EXPECT_GT(c.at("convs_from_table").get<uint64_t>(), 0u);
  EXPECT_EQ(c.at("shapes_timed").get<uint64_t>(), 0u);
  fs::remove_all(dir);
}

// Committed tables are matched by the device that measured them (the '# device' line): the same
// card and driver before the same model (vendor and device id) and driver, before the same model
// under another driver (used, and said); another model never; a file without the line is skipped
// with a warning naming it.
TEST(ConvChoice, CommittedTablesMatchTheDeviceModel) {
  const fs::path dir = fresh_dir("committed_match");
  const ConvDeviceIdentity here{"GPU X", "1.2.3", "uuid-here", 0x10de, 0x2335};
  auto write = [&](const std::string& file, ConvDeviceIdentity id, const std::string& algo) {
    ConvChoiceTable t;
    t.set("conv2d k3 s1 p1 8->8 fp32 n<=1 16x16", {algo, 1.0, algo + "=1.0000", "winograd"});
    t.save((dir / file).string(), id.name, id);
  };
  ConvDeviceIdentity other_model = here, other_driver = here, other_card = here;
  other_model.device_id = 0x2330, other_model.uuid = "uuid-other";
  other_driver.driver = "1.2.0", other_driver.uuid = "uuid-other";
  other_card.uuid = "uuid-other";
  write("1-other-model.tsv", other_model, "direct");
  std::vector<std::string> w;
  EXPECT_FALSE(find_committed_conv_table({dir.string()}, here, &w));
  write("2-other-driver.tsv", other_driver, "blocked");
  auto m = find_committed_conv_table({dir.string(), (dir / "absent").string()}, here, &w);
  ASSERT_TRUE(m);
  EXPECT_NE(m->how.find("driver 1.2.0 measured, 1.2.3 here"), std::string::npos) << m->how;
  EXPECT_EQ(m->table.find("conv2d k3 s1 p1 8->8 fp32 n<=1 16x16")->algo, "blocked");
  write("3-other-card.tsv", other_card, "gemm");
  m = find_committed_conv_table({dir.string()}, here, &w);
  EXPECT_EQ(m->how, "device model and driver");
  write("4-this-card.tsv", here, "winograd");
  m = find_committed_conv_table({dir.string()}, here, &w);
  EXPECT_EQ(m->how, "device uuid and driver");
  EXPECT_EQ(m->path, (dir / "4-this-card.tsv").string());
  EXPECT_EQ(m->table.identity().device_id, 0x2335u);
  EXPECT_TRUE(w.empty()) << w.front();
  {
    std::ofstream(dir / "5-anonymous.tsv") << "# vkunroll conv algorithm choices v1: x\nk\tdirect\t1\tdirect=1\tdirect\n";
  }
  find_committed_conv_table({dir.string()}, here, &w);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("5-anonymous.tsv: no '# device' line"), std::string::npos) << w[0];
  // Merged under this device's own table: its own timings win, and save() leaves the committed out.
  ConvChoiceTable own;
  own.set("conv2d k1 s1 p0 8->8 fp32 n<=1 16x16", {"gemm", 0.5, "gemm=0.5000", "gemm"});
  own.merge_committed(m->table);
  ASSERT_EQ(own.entries().size(), 2u);
  EXPECT_TRUE(own.find("conv2d k3 s1 p1 8->8 fp32 n<=1 16x16")->committed);
  own.save((dir / "cache.tsv").string(), "here", here);
  EXPECT_EQ(ConvChoiceTable::load((dir / "cache.tsv").string(), nullptr).entries().size(), 1u);
  fs::remove_all(dir);
}

// The report names the kernel that ran: a batch whose batch-1 choice differs (the GPU family takes
// igemm_l only where the whole batch's 128 x 128 tiles give two workgroups per shader core) counts
// the batch's algorithm in calls_by_algorithm, names it in the trace and in --profile's op, not
// choose_algorithm's.
TEST(ConvChoice, ReportNamesTheKernelTheBatchRan) {
  Context& ctx = vktest::context();
  const int64_t cin = 4, cout = 128, side = 128;
  std::mt19937 rng(56);
  const HostTensor w = ktest::random_tensor(Shape{cout, cin, 1, 1}, rng, -0.5f, 0.5f);
  ConvOptions gpu;
  gpu.gpu_family = true;
  Conv2d probe(ctx, w, HostTensor(Shape{1, 1, 1, cout}, std::vector<float>(cout, 0.f)), Conv2dParams{1, 1, 0, {}}, "wide",
               nullptr, gpu);
  const ConvAlgo one = probe.choose_algorithm(side, side);
  int64_t n = 2;
  while (n <= 16 && probe.gpu_choice(Shape{n, cin, side, side}) == one) ++n;
  ASSERT_LE(n, 16) << "no batch of " << side << "x" << side << " changes the GPU family's choice";
  const std::string ran = conv_algo_name(probe.gpu_choice(Shape{n, cin, side, side}));
  EXPECT_EQ(ran, "igemm_l");
  EXPECT_EQ(std::string(conv_algo_name(one)), "igemm_m");

  Profiler profile;
  VulkanBackend vk(ctx, &profile);
  vk.set_conv_options(gpu);
  const int id = vk.prepare_conv(ConvDesc{"wide", int(cin), int(cout), 1, 1, 0}, WeightTensor{{cout, cin, 1, 1}, w.data},
                                 WeightTensor{{cout}, std::vector<float>(cout, 0.f)});
  Buffer in = vk.alloc(Shape{n, cin, side, side}, "input");
  Buffer out = vk.alloc(Shape{n, cout, side, side}, "output");
  vk.upload(in.whole(), ktest::random_tensor(Shape{n, cin, side, side}, rng).data);
  Trace trace;
  const bool traced = ctx.info().timestamps;
  if (traced) ctx.set_trace(&trace);
  vk.conv(id, in.whole(), out.whole(), nullptr);
  vk.flush();
  ctx.set_trace(nullptr);
  EXPECT_EQ(vk.conv_calls_by_algorithm(), (std::map<std::string, uint64_t>{{ran, 1}}));
  if (ctx.info().timestamps) {  // the profile's op is the dispatch's name, which the kernel that ran gives
    EXPECT_EQ(profile.ops().count("wide_1x1_" + ran), 1u);
    EXPECT_EQ(profile.ops().count(std::string("wide_1x1_") + conv_algo_name(one)), 0u);
  }
  if (traced) {
    const std::string json = trace.json();
    EXPECT_NE(json.find(" " + ran), std::string::npos) << json;
    EXPECT_EQ(json.find(std::string(" ") + conv_algo_name(one)), std::string::npos) << json;
  }
}
