// vkunroll-bench-kernels: throughput of every conv and transposed-conv shape of the published
// SelfUnroll model (D=10, G0=96, G=48, C=5, UNet base 32) for a 346x260 input, side by side with
// the naive shader and a pure-FMA ceiling kernel measured in the same run.
// GFLOP/s always counts the direct convolution's 2 x multiply-adds.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include <nlohmann/json.hpp>

#include "bench_args.hpp"
#include "bench_process.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/half.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/profiler.hpp"

using namespace vkunroll;

namespace {

struct ConvShape {
  std::string name;  // where the model uses it (first use)
  bool transposed = false;
  int k = 3, s = 1;
  int64_t cin = 0, cout = 0, h = 0, w = 0;  // input extent
  int uses = 1;      // how many convs of the model have this shape (per batch item)
  bool quick = false;
  std::string key() const {
    return (transposed ? "T" : "C") + std::to_string(k) + "s" + std::to_string(s) + ":" + std::to_string(cin) + ">" +
           std::to_string(cout) + "@" + std::to_string(h) + "x" + std::to_string(w);
  }
  std::string shape_str() const {
    return std::to_string(cin) + "->" + std::to_string(cout) + " k" + std::to_string(k) + " s" + std::to_string(s) +
           " @" + std::to_string(h) + "x" + std::to_string(w);
  }
};

void add(std::vector<ConvShape>& v, ConvShape c) {
  for (auto& o : v)
    if (o.key() == c.key()) {
      o.uses += c.uses;
      o.quick = o.quick || c.quick;
      return;
    }
  v.push_back(std::move(c));
}

// Every named conv algorithm (what --all-algos times, and a row's name records): the enum's values
// after `automatic` that have a name, so that an algorithm added to the kernels is benched too.
std::vector<ConvAlgo> all_conv_algos() {
  std::vector<ConvAlgo> out;
  for (uint32_t v = static_cast<uint32_t>(ConvAlgo::naive); v < 32; ++v)
    if (std::string(conv_algo_name(static_cast<ConvAlgo>(v))) != "unknown") out.push_back(static_cast<ConvAlgo>(v));
  return out;
}
const std::vector<ConvAlgo> kConvAlgos = all_conv_algos();
std::vector<ConvTransposeAlgo> all_conv_transpose_algos() {
  std::vector<ConvTransposeAlgo> out;
  for (uint32_t v = static_cast<uint32_t>(ConvTransposeAlgo::naive); v < 32; ++v)
    if (std::string(conv_transpose_algo_name(static_cast<ConvTransposeAlgo>(v))) != "unknown")
      out.push_back(static_cast<ConvTransposeAlgo>(v));
  return out;
}
const std::vector<ConvTransposeAlgo> kConvTransposeAlgos = all_conv_transpose_algos();

// The UNet of section 2.4 at the size-adapter-padded extent h x w.
void unet_shapes(std::vector<ConvShape>& v, const std::string& net, int64_t in, int64_t out, int depth, int64_t h,
                 int64_t w) {
  auto width = [](int i) { return int64_t{32} << i; };
  auto lh = [&](int i) { return h >> i; };
  auto lw = [&](int i) { return w >> i; };
  add(v, {net + ".head", false, 3, 1, in, 32, h, w});
  for (int i = 0; i < depth; ++i) {
    const std::string d = net + ".down_path." + std::to_string(i);
    add(v, {d + ".conv1 (ResBlock)", false, 3, 1, width(i), width(i), lh(i), lw(i), 2});
    add(v, {d + ".conv2", false, 1, 1, width(i), width(i), lh(i), lw(i)});
    add(v, {d + ".down", false, 3, 2, width(i), width(i + 1), lh(i), lw(i)});
  }
  add(v, {net + ".bottom (ResBlocks)", false, 3, 1, width(depth), width(depth), lh(depth), lw(depth), 4});
  for (int i = depth - 1; i >= 0; --i) {
    const std::string u = net + ".up_path." + std::to_string(i);
    add(v, {u + ".deconv", true, 4, 2, width(i + 1), width(i), lh(i + 1), lw(i + 1)});
    add(v, {u + ".conv_skip", false, 1, 1, width(i), width(i), lh(i), lw(i)});
    add(v, {u + ".conv1", false, 3, 1, 2 * width(i), width(i), lh(i), lw(i)});
    add(v, {u + ".conv2 (ResBlock)", false, 3, 1, width(i), width(i), lh(i), lw(i), 2});
  }
  add(v, {net + ".pred", false, 3, 1, 32, out, h, w});
}

std::vector<ConvShape> model_shapes() {
  const int64_t H = 260, W = 346, h2 = H / 2, w2 = W / 2, D = 10, G0 = 96, G = 48, C = 5, N2 = 32;
  std::vector<ConvShape> v;
  add(v, {"SFENet1", false, 5, 1, 4 * (3 + 3 * N2), G0, h2, w2, 1, true});
  add(v, {"SFENet2", false, 3, 1, G0, G0, h2, w2});
  for (int64_t c = 0; c < C; ++c)
    add(v, {"RDBs.d.convs." + std::to_string(c), false, 3, 1, G0 + c * G, G, h2, w2, static_cast<int>(D), c == 1});
  add(v, {"RDBs.d.LFF", false, 1, 1, G0 + C * G, G0, h2, w2, static_cast<int>(D), true});
  add(v, {"GFF.0", false, 1, 1, D * G0, G0, h2, w2});
  add(v, {"GFF.1", false, 3, 1, G0, G0, h2, w2});
  add(v, {"UPNet.0", false, 3, 1, G0, 256, h2, w2});
  add(v, {"UPNet.2", false, 3, 1, 64, 3, H, W});
  const int64_t ph = 288, pw = 352;  // size adapter: 260x346 -> 288x352
  unet_shapes(v, "flownet", N2 + N2 + 3, 2, 4, ph, pw);  // cat(ev1, ev2, rs): 67
  unet_shapes(v, "fusion_net", 3 + 3 + 2 + N2 + 3, 3, 3, ph, pw);
  unet_shapes(v, "attfusion_net", 3 + 3 + N2 + N2 + 2 + 2, 1, 3, ph, pw);
  for (auto& s : v)  // the quick subset: one of each kind
    if (s.name == "flownet.down_path.0.down" || s.name == "flownet.up_path.0.deconv") s.quick = true;
  return v;
}

HostTensor random_host(Shape s, std::mt19937& rng, float scale) {
  std::uniform_real_distribution<float> d(-scale, scale);
  HostTensor t(s);
  for (auto& x : t.data) x = d(rng);
  return t;
}

struct Timing {
  double ms = 0;
  int reps = 0;
};

// GPU time of `record` (runtime's best_gpu_ms: the best of `reps` submits after a warm-up of at least 25 ms). `total`
// (for --profile) gets every timed dispatch.
template <class F>
Timing time_gpu(Context& ctx, int reps, Profiler* total, F record) {
  return {best_gpu_ms(ctx, reps, record, total), reps};
}

// The same-run peer: PyTorch conv2d / conv_transpose2d (tools/bench/bench_conv_peer.py) per shape key, best of
// `reps`, on the CPU or a CUDA GPU; keys "fp16:KEY" hold CUDA's half-precision times. Empty (and said)
// where PyTorch cannot run.
std::map<std::string, double> torch_peer_ms(const std::vector<ConvShape>& shapes, int threads, int reps,
                                             const std::string& device) {
  const std::string dir = std::filesystem::temp_directory_path().string();
  const std::string in = dir + "/vkunroll-conv-peer-" + std::to_string(getpid()) + ".json", out = in + ".out";
  nlohmann::json list = nlohmann::json::array();
  for (const ConvShape& c : shapes)
    list.push_back({{"key", c.key()}, {"transposed", c.transposed}, {"k", c.k}, {"s", c.s}, {"cin", c.cin},
                    {"cout", c.cout}, {"h", c.h}, {"w", c.w}});
  std::ofstream(in) << list.dump();
  const std::string cmd = "/usr/bin/python3 " + std::string(VKUNROLL_SOURCE_DIR) + "/tools/bench/bench_conv_peer.py " + in + " " + out +
                          " --threads " + std::to_string(threads) + " --reps " + std::to_string(reps) + " --device " + device;
  const CommandOutput run = run_command(cmd, /*with_stderr=*/true);
  const std::string failure = run.status == 0      ? std::string()
                              : !run.text.empty()  ? run.text
                              : run.status < 0     ? "could not be started"
                                                   : "exit status " + std::to_string(run.status);
  std::map<std::string, double> ms;
  try {
    if (failure.empty()) {
      const auto j = nlohmann::json::parse(std::ifstream(out));
      for (const auto& [key, v] : j.at("ms").items()) ms[key] = v.get<double>();
      if (j.contains("ms_fp16"))
        for (const auto& [key, v] : j.at("ms_fp16").items()) ms["fp16:" + key] = v.get<double>();
      if (device == "cuda")
        std::printf("peer: PyTorch %s conv2d on %s (CUDA, cudnn.benchmark, TF32 off; fp16 rows against its half), "
                    "best of %d, timed before our rows\n", j.at("torch").get<std::string>().c_str(),
                    j.value("device", std::string("?")).c_str(), reps);
      else
        std::printf("peer: PyTorch %s conv2d on the CPU, %d thread(s), best of %d, timed before our rows\n",
                    j.at("torch").get<std::string>().c_str(), threads, reps);
    }
  } catch (const std::exception& e) {
    std::printf("peer: could not read %s: %s\n", out.c_str(), e.what());
  }
  if (!failure.empty()) std::printf("peer: PyTorch did not run (%s): %s\n", cmd.c_str(), failure.c_str());
  std::filesystem::remove(in);
  std::filesystem::remove(out);
  return ms;
}

// ---- --fp16-error-model: CPU emulations behind the fp16 kernels' arithmetic (docs/kernels.md) -------
// One conv output = sum of n products of fp16 inputs in [-1, 1] and fp16 weights +-1/sqrt(n):
// accumulated in fp32 (then stored as fp16) or in fp16 (a fused multiply-add rounded to half
// after every step); max and rms error against the exact sum over 20000 outputs.
void accumulation_error_table() {
  std::mt19937 rng(7);
  std::printf("fp16 accumulation (emulated), error against the exact sum of n fp16 products:\n");
  for (int n : {27, 153, 864, 1296, 2592, 960}) {
    std::uniform_real_distribution<float> dx(-1, 1), dw(-1 / std::sqrt(float(n)), 1 / std::sqrt(float(n)));
    double m32 = 0, m16 = 0;
    for (int t = 0; t < 20000; ++t) {
      double exact = 0;
      float a32 = 0, a16 = 0;
      for (int i = 0; i < n; ++i) {
        const float x = round_to_half(dx(rng)), w = round_to_half(dw(rng));
        exact += static_cast<double>(x) * w;
        a32 = std::fma(x, w, a32);
        a16 = round_to_half(std::fma(x, w, a16));
      }
      m32 = std::max(m32, std::fabs(round_to_half(a32) - exact));
      m16 = std::max(m16, std::fabs(a16 - exact));
    }
    std::printf("  n %4d: max |error| fp32 accumulation %.2e, fp16 accumulation %.2e\n", n, m32, m16);
  }
}

// Winograd F(4x4, 3x3) on a cin x 16 x 16 fp16 input, 16 output channels, weights +-1/sqrt(9 cin):
// max error against the direct conv when V, U or both are rounded to fp16, beside a direct conv
// with fp16 weights.
void winograd_rounding_table() {
  static const double BT[6][6] = {{4, 0, -5, 0, 1, 0},  {0, -4, -4, 1, 1, 0}, {0, 4, -4, -1, 1, 0},
                                  {0, -2, -1, 2, 1, 0}, {0, 2, -1, -2, 1, 0}, {0, 4, 0, -5, 0, 1}};
  static const double G[6][3] = {{1.0 / 4, 0, 0},           {-1.0 / 6, -1.0 / 6, -1.0 / 6}, {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                 {1.0 / 24, 1.0 / 12, 1.0 / 6}, {1.0 / 24, -1.0 / 12, 1.0 / 6}, {0, 0, 1}};
  static const double AT[4][6] = {{1, 1, 1, 1, 1, 0}, {0, 1, -1, 2, -2, 0}, {0, 1, 1, 4, 4, 0}, {0, 1, -1, 8, -8, 1}};
  std::printf("Winograd F(4,3) with fp16 operands (emulated), max error against the exact conv:\n");
  const int H = 16, W = 16, cout = 16;
  for (int cin : {17, 96, 288}) {
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> d(-1, 1), dw(-1 / std::sqrt(9.f * cin), 1 / std::sqrt(9.f * cin));
    std::vector<float> x(static_cast<size_t>(cin * H * W)), w(static_cast<size_t>(cout * cin * 9));
    for (auto& v : x) v = round_to_half(d(rng));
    for (auto& v : w) v = dw(rng);
    double err[4] = {0, 0, 0, 0};  // direct with fp16 weights; V fp16; U fp16; both
    for (int co = 0; co < cout; ++co)
      for (int t = 0; t < (H / 4) * (W / 4); ++t) {
        const int ty = t / (W / 4), tx = t % (W / 4);
        double M[3][6][6] = {};
        for (int ci = 0; ci < cin; ++ci) {
          double dd[6][6], tv[6][6], V[6][6], gg[6][3], U[6][6];
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
              const int yy = ty * 4 - 1 + i, xx = tx * 4 - 1 + j;
              dd[i][j] = (yy >= 0 && yy < H && xx >= 0 && xx < W) ? x[static_cast<size_t>((ci * H + yy) * W + xx)] : 0;
            }
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
              tv[i][j] = 0;
              for (int k = 0; k < 6; ++k) tv[i][j] += BT[i][k] * dd[k][j];
            }
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
              V[i][j] = 0;
              for (int k = 0; k < 6; ++k) V[i][j] += tv[i][k] * BT[j][k];
            }
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 3; ++j) {
              gg[i][j] = 0;
              for (int k = 0; k < 3; ++k) gg[i][j] += G[i][k] * w[static_cast<size_t>(((co * cin + ci) * 3 + k) * 3 + j)];
            }
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
              U[i][j] = 0;
              for (int k = 0; k < 3; ++k) U[i][j] += gg[i][k] * G[j][k];
              const double v16 = round_to_half(static_cast<float>(V[i][j])), u16 = round_to_half(static_cast<float>(U[i][j]));
              M[0][i][j] += U[i][j] * v16;
              M[1][i][j] += u16 * V[i][j];
              M[2][i][j] += u16 * v16;
            }
        }
        for (int i = 0; i < 4; ++i)
          for (int j = 0; j < 4; ++j) {
            const int oy = ty * 4 + i, ox = tx * 4 + j;
            double ref = 0, ref16 = 0;
            for (int ci = 0; ci < cin; ++ci)
              for (int k = 0; k < 9; ++k) {
                const int yy = oy - 1 + k / 3, xx = ox - 1 + k % 3;
                if (yy < 0 || yy >= H || xx < 0 || xx >= W) continue;
                const double xv = x[static_cast<size_t>((ci * H + yy) * W + xx)];
                const float wv = w[static_cast<size_t>((co * cin + ci) * 9 + k)];
                ref += xv * wv;
                ref16 += xv * round_to_half(wv);
              }
            err[0] = std::max(err[0], std::fabs(ref16 - ref));
            for (int m = 0; m < 3; ++m) {
              double y = 0;
              for (int a = 0; a < 6; ++a)
                for (int b = 0; b < 6; ++b) y += AT[i][a] * M[m][a][b] * AT[j][b];
              err[m + 1] = std::max(err[m + 1], std::fabs(y - ref));
            }
          }
      }
    std::printf("  cin %3d: direct, fp16 weights %.2e; Winograd V fp16 %.2e, U fp16 %.2e, both %.2e\n", cin, err[0],
                err[1], err[2], err[3]);
  }
}

// Against the same-run peer, per precision (chosen algorithms): the slowest shape, how many are
// over 2x PyTorch's time, and the model's conv time (shapes weighted by their uses) over PyTorch's.
void print_peer_summary(const nlohmann::json& rows) {
  struct Sum {
    double ours = 0, torch = 0, worst = 0;
    int over2 = 0, n = 0;
    std::string worst_name;
  };
  std::map<std::string, Sum> by;
  for (const auto& row : rows) {
    if (!row["chosen"].get<bool>() || !row.contains("torch_ms")) continue;
    Sum& s = by[row["precision"].get<std::string>()];
    const double r = row["ratio_to_torch"].get<double>(), uses = row["uses"].get<double>();
    s.ours += uses * row["ms"].get<double>(), s.torch += uses * row["torch_ms"].get<double>(), s.n++;
    if (r > 2) s.over2++;
    if (r > s.worst) s.worst = r, s.worst_name = row["name"].get<std::string>() + " [" + row["shape"].get<std::string>() + "]";
  }
  for (const auto& [pr, s] : by)
    std::printf("against PyTorch (%s, chosen algorithms): %d of %d shapes over 2x; slowest %.2fx (%s); all convs "
                "weighted by use %.2fx (%.0f ms against %.0f ms)\n",
                pr.c_str(), s.over2, s.n, s.worst, s.worst_name.c_str(), s.torch > 0 ? s.ours / s.torch : 0.0, s.ours, s.torch);
}

constexpr const char* kHelp =
    "usage: vkunroll-bench-kernels [--quick] [--json FILE] [--profile] [--reps N] [--no-naive]\n"
    "                              [--naive-full] [--all-algos] [--algos A,B] [--only NAME_SUBSTRING]\n"
    "                              [--shape K,S,CIN,COUT,H,W]... [--blocked-cob N] [--blocked-px N]\n"
    "                              [--direct-cob N] [--direct-px N] [--direct-py N] [--gemm-cob N]\n"
    "                              [--gemm-tv N] [--pointwise-cob N] [--pointwise-px N] [--pointwise-single]\n"
    "                              [--winograd-tile 6|8] (5x5: 8 = F(4x4, 5x5), 6 = four F(4x4, 3x3); 3x3: 6 = F(4x4, 3x3), 8 = F(6x6, 3x3))\n"
    "                              [--precision fp32|fp16|fp32,fp16] [--fp16-error-model] [--conv-choice heuristic|gpu]\n"
    "                              [--no-torch] [--torch-threads N] [--torch-device cpu|cuda]\n"
    "Times every conv / transposed-conv shape of the published SelfUnroll model at 346x260\n"
    "(the algorithm `automatic` picks, and the naive shader for comparison) against an FMA\n"
    "ceiling kernel measured in the same run. GFLOP/s counts the direct convolution's work.\n"
    "Times are the best of --reps (default 2) rounds, each timing every algorithm of a shape once\n"
    "(interleaved, after a round that builds the pipelines). The naive shader runs on the\n"
    "full shape for the 3x3 RDB conv 144->48 and on a band of rows elsewhere (--naive-full:\n"
    "everywhere; slow). --all-algos also times every other applicable algorithm, --algos A,B\n"
    "only the named ones (e.g. direct,gemm). --shape (repeatable) times that conv2d shape\n"
    "(pad K/2) instead of the model's. The --blocked-cob ... flags set the convs' ConvOptions\n"
    "(docs/kernels.md, \"Conv options\"; 0 = the kernel's choice); --pointwise-single makes the\n"
    "pointwise conv fetch single pixels instead of pairs. --precision fp32,fp16 times\n"
    "each shape in both precisions (fp16 rows judged against the better of the fp32 and the fp16\n"
    "FMA ceiling, the latter from fma_ceiling_half.comp where the device has shaderFloat16).\n"
    "--conv-choice gpu: the chosen row is the GPU kernels' rule (gpu_conv_heuristic) on any device.\n"
    "--fp16-error-model prints the CPU emulations behind the fp16 kernels' fp32 arithmetic\n"
    "(fp16 accumulation, Winograd with fp16 operands) and exits.\n"
    "The peer: PyTorch's conv2d on the CPU (--torch-threads, default 2) times every shape first,\n"
    "in the same run; `x torch` is our time over its (fp16 rows against its fp32). B/FLOP is the\n"
    "bytes the algorithm's dispatches read and write per direct-conv FLOP (--no-torch: no peer).\n"
    "FMA/gB and FMA/sB: the FMAs per byte of global and of shared-memory traffic that the algorithm's\n"
    "tiles imply (Conv2d::cost; 0: no shared-memory tiles), the number to reason with without a GPU.\n"
    "--torch-device cuda: the peer on the CUDA GPU (the race per shape), fp16 rows against its half.\n";

// Everything the command line sets.
struct KernelBenchArgs {
  std::string json_path, only;
  std::vector<ConvShape> custom;  // --shape: these instead of the model's shapes
  ConvOptions conv_options;       // --blocked-cob ... (validated by the convs)
  std::vector<Precision> precisions{Precision::fp32};  // --precision fp32,fp16
  bool profile = false, quick = false, naive = true, all_algos = false, naive_full = false, pointwise_pairs = true;
  bool gpu_choice = false;  // --conv-choice gpu
  std::string algo_filter;  // --algos: ",name,name," (empty: every algorithm)
  int reps = 2, torch_threads = 2;
  bool torch = true;
  std::string torch_device = "cpu";
  bool wanted(const char* name) const {
    return algo_filter.empty() || algo_filter.find("," + std::string(name) + ",") != std::string::npos;
  }
};

// --precision's list; empty where it is not fp32, fp16 or both.
std::vector<Precision> parse_precisions(const std::string& value) {
  std::vector<Precision> out;
  std::string list = value + ",";
  for (size_t pos; (pos = list.find(',')) != std::string::npos; list.erase(0, pos + 1)) {
    const std::string name = list.substr(0, pos);
    if (name != "fp32" && name != "fp16") return {};
    out.push_back(parse_precision(name));
  }
  return out;
}

// --shape K,S,CIN,COUT,H,W; nullopt where it is not six positive integers.
std::optional<ConvShape> parse_shape(const std::string& v) {
  ConvShape c;
  c.name = "custom";
  long long k, st, ci, co, h, w;
  char tail = 0;
  if (std::sscanf(v.c_str(), "%lld,%lld,%lld,%lld,%lld,%lld%c", &k, &st, &ci, &co, &h, &w, &tail) != 6 || k < 1 || st < 1 ||
      ci < 1 || co < 1 || h < 1 || w < 1)
    return std::nullopt;
  c.k = static_cast<int>(k), c.s = static_cast<int>(st), c.cin = ci, c.cout = co, c.h = h, c.w = w;
  return c;
}

// -1: parsed, run the bench; else the exit status (help, the error model, or a bad argument, said).
int parse_args(int argc, char** argv, KernelBenchArgs& a) {
  const std::vector<std::pair<std::string, int*>> option_flags{
      {"--blocked-cob", &a.conv_options.blocked_cob}, {"--blocked-px", &a.conv_options.blocked_px},
      {"--direct-cob", &a.conv_options.direct_cob},   {"--direct-px", &a.conv_options.direct_px},
      {"--direct-py", &a.conv_options.direct_py},     {"--gemm-cob", &a.conv_options.gemm_cob},
      {"--gemm-tv", &a.conv_options.gemm_tv},         {"--pointwise-cob", &a.conv_options.pointwise_cob},
      {"--pointwise-px", &a.conv_options.pointwise_px}, {"--winograd-tile", &a.conv_options.winograd_tile}};
  const char* bench = "vkunroll-bench-kernels";
  for (int i = 1; i < argc; ++i) {
    const std::string f = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << bench << ": " << f << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    const auto flag = std::find_if(option_flags.begin(), option_flags.end(), [&](const auto& o) { return o.first == f; });
    if (flag != option_flags.end()) *flag->second = static_cast<int>(bench_int_arg(bench, f, value(), 0, 4096));
    else if (f == "--json") a.json_path = value();
    else if (f == "--profile") a.profile = true;
    else if (f == "--quick") a.quick = true;
    else if (f == "--no-naive") a.naive = false;
    else if (f == "--naive-full") a.naive_full = true;
    else if (f == "--pointwise-single") a.pointwise_pairs = false;
    else if (f == "--all-algos") a.all_algos = true;
    else if (f == "--algos") a.all_algos = true, a.algo_filter = "," + value() + ",";
    else if (f == "--only") a.only = value();
    else if (f == "--fp16-error-model") {
      accumulation_error_table();
      winograd_rounding_table();
      return 0;
    } else if (f == "--precision") {
      a.precisions = parse_precisions(value());
      if (a.precisions.empty()) {
        std::cerr << bench << ": --precision: expected fp32, fp16 or fp32,fp16\n";
        return 2;
      }
    } else if (f == "--conv-choice") {
      const std::string v = value();
      if (v != "heuristic" && v != "gpu") {
        std::cerr << bench << ": --conv-choice '" << v << "': expected heuristic or gpu\n";
        return 2;
      }
      a.gpu_choice = v == "gpu";
    } else if (f == "--shape") {
      const std::string v = value();
      const std::optional<ConvShape> c = parse_shape(v);
      if (!c) {
        std::cerr << bench << ": --shape '" << v << "': expected K,STRIDE,CIN,COUT,H,W (positive integers)\n";
        return 2;
      }
      a.custom.push_back(*c);
    } else if (f == "--reps") a.reps = static_cast<int>(bench_int_arg(bench, f, value(), 1, 1000));
    else if (f == "--no-torch") a.torch = false;
    else if (f == "--torch-device") {
      a.torch_device = value();
      if (a.torch_device != "cpu" && a.torch_device != "cuda") {
        std::cerr << bench << ": --torch-device '" << a.torch_device << "': expected cpu or cuda\n";
        return 2;
      }
    } else if (f == "--torch-threads") a.torch_threads = static_cast<int>(bench_int_arg(bench, f, value(), 1, 1024));
    else if (f == "-h" || f == "--help") {
      std::cout << kHelp;
      return 0;
    } else {
      std::cerr << bench << ": unknown argument '" << f << "' (see --help)\n";
      return 2;
    }
  }
  return -1;
}

// One shape's conv (or transposed conv) in one precision, with the algorithms to time: the chosen one
// first, then (--all-algos, --algos) every other that applies.
struct ConvUnderTest {
  bool transposed = false;
  std::optional<Conv2d> conv;
  std::optional<ConvTranspose2d> deconv;
  Shape os;
  double flop = 0;
  std::vector<std::string> algos;

  void record(CommandStream& cs, const std::string& algo, const Tensor& in, const Tensor& out) const {
    if (transposed) {
      for (ConvTransposeAlgo a : kConvTransposeAlgos)
        if (algo == conv_transpose_algo_name(a)) deconv->record(cs, Slice(in), Slice(out), a);
    } else {
      for (ConvAlgo a : kConvAlgos)
        if (algo == conv_algo_name(a)) conv->record(cs, Slice(in), Slice(out), std::nullopt, a);
    }
  }
  Shape output_shape(const Shape& in) const { return transposed ? deconv->output_shape(in) : conv->output_shape(in); }
  double flop_of(const Shape& in) const { return transposed ? deconv->flop(in) : conv->flop(in); }
  // What the algorithm's tiles imply (kernels/igemm.hpp ConvCost): FMAs and global/shared bytes.
  ConvCost cost(const std::string& algo, const Shape& in) const {
    if (transposed) {
      for (ConvTransposeAlgo a : kConvTransposeAlgos)
        if (algo == conv_transpose_algo_name(a)) return deconv->cost(a, in);
    } else {
      for (ConvAlgo a : kConvAlgos)
        if (algo == conv_algo_name(a)) return conv->cost(a, in);
    }
    return {};
  }
};

void make_conv(Context& ctx, const KernelBenchArgs& a, const ConvShape& c, Precision prec, const Shape& in, std::mt19937& rng,
               ConvUnderTest& u) {
  ConvOptions options = a.conv_options;
  options.precision = prec;
  const float ws = 1.f / std::sqrt(static_cast<float>(c.cin * c.k * c.k));
  u.transposed = c.transposed;
  if (c.transposed) {
    u.deconv.emplace(ctx, random_host({c.cin, c.cout, c.k, c.k}, rng, ws), random_host({1, 1, 1, c.cout}, rng, 0.1f),
                     ConvTranspose2dParams{c.k, c.s, 1, leaky_relu(0.1f)}, c.name, options);
    const ConvTransposeAlgo chosen = a.gpu_choice ? gpu_family_algorithm(*u.deconv) : u.deconv->choose_algorithm(c.h, c.w);
    u.algos.push_back(conv_transpose_algo_name(chosen));
    if (a.all_algos)
      for (ConvTransposeAlgo t : kConvTransposeAlgos)
        if (t != chosen && u.deconv->supports(t) && a.wanted(conv_transpose_algo_name(t))) u.algos.push_back(conv_transpose_algo_name(t));
  } else {
    u.conv.emplace(ctx, random_host({c.cout, c.cin, c.k, c.k}, rng, ws), random_host({1, 1, 1, c.cout}, rng, 0.1f),
                   Conv2dParams{c.k, c.s, c.k / 2, leaky_relu(0.1f)}, c.name, nullptr, options);
    u.conv->set_pointwise_pairs(a.pointwise_pairs);
    const ConvAlgo chosen = a.gpu_choice ? gpu_family_algorithm(*u.conv, in) : u.conv->choose_algorithm(c.h, c.w);
    u.algos.push_back(conv_algo_name(chosen));
    if (a.all_algos)
      for (ConvAlgo t : kConvAlgos)
        if (t != chosen && u.conv->supports(t) && a.wanted(conv_algo_name(t))) u.algos.push_back(conv_algo_name(t));
  }
  u.os = u.output_shape(in);
  u.flop = u.flop_of(in);
}

// The naive shader is 10-50x slower: it runs on the full shape for the issue's target shape (the 3x3
// RDB conv 144->48) and on a band of input rows (same width and channels, so the same per-pixel work)
// elsewhere; its GFLOP/s is that of what it ran.
struct NaiveTiming {
  Timing t;
  double flop = 0;
  int64_t rows = 0;
};
std::optional<NaiveTiming> time_naive(Context& ctx, const KernelBenchArgs& a, const ConvShape& c, const ConvUnderTest& u,
                                      DType dt, std::mt19937& rng, Profiler* prof) {
  if (!a.naive || u.algos.front() == "naive") return std::nullopt;
  const bool full = c.name == "RDBs.d.convs.1" || a.naive_full;
  NaiveTiming n;
  n.rows = full ? c.h : std::min<int64_t>(c.h, c.transposed ? 8 : 16 * c.s);
  Tensor xb = to_device(ctx, random_host({1, c.cin, n.rows, c.w}, rng, 1.f), dt);
  Tensor yb(ctx, u.output_shape(xb.shape()), dt);
  n.flop = u.flop_of(xb.shape());
  n.t = time_gpu(ctx, 1, prof, [&](CommandStream& cs) { u.record(cs, "naive", xb, yb); });
  return n;
}

// Interleaved rounds (every algorithm once per round, the best per algorithm kept) after a round that
// builds the pipelines: timed one after another, whichever ran first read slower. Per algorithm its
// best time and the bytes its dispatches moved per run.
std::vector<std::pair<Timing, double>> time_rounds(Context& ctx, int reps, const ConvUnderTest& u, const Tensor& x,
                                                   const Tensor& y, Profiler* prof) {
  std::vector<std::pair<Timing, double>> best(u.algos.size());
  for (int round = -1; round < reps; ++round)
    for (size_t ai = 0; ai < u.algos.size(); ++ai) {
      Profiler moved;
      const Timing t = time_gpu(ctx, 1, &moved, [&](CommandStream& cs) { u.record(cs, u.algos[ai], x, y); });
      double bytes = 0;
      for (const auto& [op, st] : moved.ops()) {
        bytes += st.bytes;
        if (prof && round >= 0) prof->record(op, st.total_ms, st.flop, st.bytes);
      }
      if (round < 0) continue;
      Timing& b = best[ai].first;
      best[ai].second = bytes;
      if (b.reps == 0 || t.ms < b.ms) b.ms = t.ms;
      b.reps++;
    }
  return best;
}

// One row: printed, and its JSON record.
nlohmann::json report_row(const ConvShape& c, Precision prec, const std::string& algo, bool chosen, const Timing& t,
                          double moved_bytes, double flop, double ceiling, double torch_ms, const std::optional<NaiveTiming>& naive,
                          const ConvCost& cost) {
  const double gf = flop / (t.ms * 1e6), frac = gf / ceiling;
  // The arithmetic intensity the tile sizes imply: the number to reason with where no GPU is at hand.
  const double fma_per_global = cost.global_bytes > 0 ? cost.fma / cost.global_bytes : 0;
  const double fma_per_shared = cost.shared_bytes > 0 ? cost.fma / cost.shared_bytes : 0;
  const double nms = naive ? naive->t.ms : 0, ngf = naive ? naive->flop / (nms * 1e6) : 0;
  const double bytes_per_flop = moved_bytes / flop;
  std::printf("%-34s %-26s %-4s %-9s %9.2f %8.2f %5.1f%% %6.3f %7.1f %7.1f %9.2f %6.2fx %10.2f %8.2f %6.1fx%s%s\n", c.name.c_str(),
              c.shape_str().c_str(), precision_name(prec), algo.c_str(), t.ms, gf, 100 * frac, bytes_per_flop, fma_per_global,
              fma_per_shared, torch_ms,
              torch_ms > 0 ? t.ms / torch_ms : 0.0, nms, ngf, ngf > 0 ? gf / ngf : 0.0,
              naive && naive->rows < c.h ? (" (naive: " + std::to_string(naive->rows) + " rows)").c_str() : "",
              chosen ? "" : "  (forced)");
  std::fflush(stdout);
  nlohmann::json row{{"op", c.transposed ? "conv_transpose2d" : "conv2d"}, {"name", c.name}, {"shape", c.shape_str()},
                     {"kernel", c.k}, {"stride", c.s}, {"cin", c.cin}, {"cout", c.cout}, {"h", c.h}, {"w", c.w},
                     {"uses", c.uses}, {"algo", algo}, {"precision", precision_name(prec)}, {"chosen", chosen},
                     {"ms", t.ms}, {"gflop", flop * 1e-9}, {"gflops", gf}, {"ceiling_gflops", ceiling},
                     {"fraction_of_ceiling", frac}, {"bytes_moved", moved_bytes}, {"bytes_per_flop", bytes_per_flop},
                     {"model_fma", cost.fma}, {"model_global_bytes", cost.global_bytes}, {"model_shared_bytes", cost.shared_bytes},
                     {"fma_per_global_byte", fma_per_global}, {"fma_per_shared_byte", fma_per_shared}};
  if (torch_ms > 0) {
    row["torch_ms"] = torch_ms;
    row["ratio_to_torch"] = t.ms / torch_ms;
  }
  if (naive) {
    row["naive_ms"] = nms;
    row["naive_rows"] = naive->rows;
    row["naive_gflops"] = ngf;
    row["speedup_vs_naive"] = gf / ngf;
  }
  return row;
}

// Every row of one shape in one precision.
void bench_shape(Context& ctx, const KernelBenchArgs& a, const ConvShape& c, Precision prec, double ceiling,
                 const std::map<std::string, double>& peer, Profiler* prof, std::mt19937& rng, nlohmann::json& rows) {
  const DType dt = precision_dtype(prec);
  const HostTensor x = random_host({1, c.cin, c.h, c.w}, rng, 1.f);
  Tensor xd = to_device(ctx, x, dt);
  ConvUnderTest u;
  make_conv(ctx, a, c, prec, xd.shape(), rng, u);
  Tensor yd(ctx, u.os, dt);
  auto peer_it = prec == Precision::fp16 ? peer.find("fp16:" + c.key()) : peer.end();
  if (peer_it == peer.end()) peer_it = peer.find(c.key());
  const double torch_ms = peer_it == peer.end() ? 0.0 : peer_it->second;
  const std::optional<NaiveTiming> naive = time_naive(ctx, a, c, u, dt, rng, prof);
  const auto best = time_rounds(ctx, a.reps, u, xd, yd, prof);
  for (size_t ai = 0; ai < u.algos.size(); ++ai)
    rows.push_back(report_row(c, prec, u.algos[ai], ai == 0, best[ai].first, best[ai].second, u.flop, ceiling, torch_ms, naive,
                              u.cost(u.algos[ai], xd.shape())));
}

// The machine is shared: the ceiling is measured again at the end and every shape judged against the
// better of the two (the conservative fraction); then the target shape, the peer summary and the
// lowest fractions.
void finish_report(Context& ctx, nlohmann::json& rows, double ceiling32, double ceiling16, bool any16) {
  const double ceiling_end = fma_ceiling_gflops(ctx);
  const double ceil_best = std::max(ceiling32, ceiling_end);
  std::printf("FMA ceiling again at the end: %.2f GFLOP/s; fractions below use %.2f\n", ceiling_end, ceil_best);
  const double ceil16_best = any16 ? std::max({ceil_best, ceiling16, fma_ceiling_gflops(ctx, true)}) : 0;
  if (any16) std::printf("fp16 rows use the better of both ceilings in both measurements: %.2f\n", ceil16_best);
  std::map<std::string, std::pair<double, std::string>> worst_by_prec;  // lowest fraction per precision
  for (auto& row : rows) {
    const std::string pr = row["precision"].get<std::string>();
    const double cb = pr == "fp16" ? ceil16_best : ceil_best;
    row["ceiling_gflops"] = cb;
    row["fraction_of_ceiling"] = row["gflops"].get<double>() / cb;
    auto& w = worst_by_prec.try_emplace(pr, 1e9, "").first->second;
    if (row["chosen"].get<bool>() && row["fraction_of_ceiling"].get<double>() < w.first)
      w = {row["fraction_of_ceiling"].get<double>(), row["name"].get<std::string>() + " [" + row["shape"].get<std::string>() + "]"};
    if (row["chosen"].get<bool>() && row["name"] == "RDBs.d.convs.1" && row.contains("speedup_vs_naive"))
      std::printf("target 3x3 RDB conv 144->48 @130x173 (%s): %s %.2f GFLOP/s = %.1f%% of the ceiling, %.1fx the naive shader\n",
                  pr.c_str(), row["algo"].get<std::string>().c_str(), row["gflops"].get<double>(),
                  100 * row["fraction_of_ceiling"].get<double>(), row["speedup_vs_naive"].get<double>());
  }
  print_peer_summary(rows);
  for (const auto& [pr, w] : worst_by_prec)
    if (w.first < 1e9)
      std::printf("lowest fraction of the ceiling (chosen algorithms, %s): %.1f%% (%s)\n", pr.c_str(), 100 * w.first,
                  w.second.c_str());
}

int run_bench(const KernelBenchArgs& a) {
  ContextOptions opt;
  Context ctx(opt);
  Profiler total;
  Profiler* prof = a.profile ? &total : nullptr;
  const double ceiling32 = fma_ceiling_gflops(ctx);
  const bool any16 = std::find(a.precisions.begin(), a.precisions.end(), Precision::fp16) != a.precisions.end();
  const double ceiling16 = any16 ? fma_ceiling_gflops(ctx, true) : 0;
  std::printf("device: %s\nFMA ceiling: %.2f GFLOP/s (fma_ceiling, 8 vec4 chains per invocation)\n", ctx.info().name.c_str(),
              ceiling32);
  if (any16)
    std::printf("fp16 FMA ceiling: %.2f GFLOP/s (fma_ceiling_half, 8 f16vec4 chains; 0: no shaderFloat16)\n", ceiling16);
  if (a.gpu_choice) std::printf("conv choice: the GPU kernels' rule (gpu_conv_heuristic) on this device\n");
  std::vector<ConvShape> shapes;
  for (const ConvShape& c : a.custom.empty() ? model_shapes() : a.custom)
    if ((!a.quick || c.quick) && (a.only.empty() || c.name.find(a.only) != std::string::npos)) shapes.push_back(c);
  const std::map<std::string, double> peer =
      a.torch ? torch_peer_ms(shapes, a.torch_threads, a.reps, a.torch_device) : std::map<std::string, double>{};
  // FMA/gB and FMA/sB: FMAs per byte of global and of shared-memory traffic, from the tile sizes (0: none).
  std::printf("%-34s %-26s %-4s %-9s %9s %8s %6s %6s %7s %7s %9s %7s %10s %8s %7s\n", "op (first use)", "shape (in->out k s @HxW)",
              "prec", "algo", "ms", "GFLOP/s", "%ceil", "B/FLOP", "FMA/gB", "FMA/sB", "torch ms", "x torch", "naive ms", "naive GF",
              "speedup");
  nlohmann::json rows = nlohmann::json::array();
  std::mt19937 rng(42);
  for (const ConvShape& c : shapes)
    for (const Precision prec : a.precisions)  // fp16 kernels compute in fp32 from fp16 storage: the better of both ceilings
      bench_shape(ctx, a, c, prec, prec == Precision::fp16 ? std::max(ceiling32, ceiling16) : ceiling32, peer, prof, rng, rows);
  finish_report(ctx, rows, ceiling32, ceiling16, any16);
  if (!a.json_path.empty()) {
    std::ofstream f(a.json_path);
    if (!f) throw Error("cannot write --json file '" + a.json_path + "'");
    f << rows.dump(2) << "\n";
    std::printf("wrote %s (%zu rows)\n", a.json_path.c_str(), rows.size());
  }
  if (a.profile) total.print(std::cout);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  KernelBenchArgs a;
  if (const int status = parse_args(argc, argv, a); status >= 0) return status;
  try {
    return run_bench(a);
  } catch (const std::exception& e) {
    std::cerr << "vkunroll-bench-kernels: " << e.what() << "\n";
    return 1;
  }
}
