#include "vkunroll/host/model/conv_choice.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <unistd.h>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"

namespace vkunroll {

namespace {

constexpr const char* kFormatLine = "# vkunroll conv algorithm choices v1";
constexpr const char* kIdentityLine = "# device\t";  // then vendor=0x.. device=0x.. driver= uuid= name=, tab-separated

std::string hex(uint32_t v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%x", v);
  return buf;
}

std::string identity_line(const ConvDeviceIdentity& d) {
  return std::string(kIdentityLine) + "vendor=" + hex(d.vendor_id) + "\tdevice=" + hex(d.device_id) + "\tdriver=" + d.driver +
         "\tuuid=" + d.uuid + "\tname=" + d.name;
}

// The identity line's fields; false (and `why`) where one is missing or not a number.
bool parse_identity(const std::string& line, ConvDeviceIdentity& d, std::string& why) {
  std::map<std::string, std::string> f;
  std::istringstream ls(line.substr(std::strlen(kIdentityLine)));
  for (std::string part; std::getline(ls, part, '\t');) {
    const size_t eq = part.find('=');
    if (eq != std::string::npos) f[part.substr(0, eq)] = part.substr(eq + 1);
  }
  for (const char* k : {"vendor", "device", "driver", "uuid", "name"})
    if (!f.count(k)) {
      why = std::string("the device line lacks ") + k + "=";
      return false;
    }
  try {
    d.vendor_id = static_cast<uint32_t>(std::stoul(f["vendor"], nullptr, 0));
    d.device_id = static_cast<uint32_t>(std::stoul(f["device"], nullptr, 0));
  } catch (const std::exception&) {
    why = "the device line's vendor= or device= is not a number";
    return false;
  }
  d.driver = f["driver"], d.uuid = f["uuid"], d.name = f["name"];
  return true;
}

int64_t batch_bucket(int64_t n) {
  int64_t b = 1;
  while (b < n) b *= 2;
  return b;
}

std::string shape_text(const Shape& in) {
  return "n<=" + std::to_string(batch_bucket(in.n)) + " " + std::to_string(in.h) + "x" + std::to_string(in.w);
}

std::string format_ms(double ms) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.4f", ms);
  return buf;
}

// The fastest of (name, ms) pairs, with every timing listed.
ConvChoiceEntry fastest(const std::vector<std::pair<std::string, double>>& t, const std::string& who) {
  if (t.empty()) throw InternalError(who + ": no algorithm applies to this shape");
  ConvChoiceEntry e{t.front().first, t.front().second, {}};
  for (const auto& [name, ms] : t) {
    if (ms < e.ms) e = {name, ms, {}};
  }
  for (const auto& [name, ms] : t) e.timings += (e.timings.empty() ? "" : " ") + name + "=" + format_ms(ms);
  return e;
}

}  // namespace

std::string conv_choice_disagreement(const std::vector<float>& reference, const std::vector<float>& result,
                                     Precision precision) {
  if (reference.size() != result.size()) return "rejected(" + std::to_string(result.size()) + " values, expected " +
                                                std::to_string(reference.size()) + ")";
  double err = 0, mx = 1;
  for (size_t i = 0; i < result.size(); ++i) {
    const double d = std::fabs(double(result[i]) - double(reference[i]));
    err = std::isnan(d) ? INFINITY : std::max(err, d);
    mx = std::max(mx, std::fabs(double(reference[i])));
  }
  // fp32: 1e-3 of the range (the parity tests measure <= 1e-4); fp16: 2e-2 (measured <= 3e-3).
  const double tol = (precision == Precision::fp16 ? 2e-2 : 1e-3) * mx;
  if (err <= tol) return {};
  char buf[96];
  std::snprintf(buf, sizeof buf, "rejected(max diff %.3g > %.3g)", err, tol);
  return buf;
}

ConvChoice parse_conv_choice(const std::string& s, const std::string& what) {
  for (ConvChoice c : {ConvChoice::automatic, ConvChoice::heuristic, ConvChoice::cached, ConvChoice::measured,
                       ConvChoice::retune, ConvChoice::gpu})
    if (s == conv_choice_name(c)) return c;
  throw UsageError(what + " '" + s + "': expected auto, heuristic, cached, measured, retune or gpu");
}

const char* conv_choice_name(ConvChoice c) {
  switch (c) {
    case ConvChoice::automatic: return "auto";
    case ConvChoice::heuristic: return "heuristic";
    case ConvChoice::cached: return "cached";
    case ConvChoice::measured: return "measured";
    case ConvChoice::retune: return "retune";
    case ConvChoice::gpu: return "gpu";
  }
  return "unknown";
}

const ConvChoiceEntry* ConvChoiceTable::find(const std::string& key) const {
  const auto it = entries_.find(key);
  return it == entries_.end() ? nullptr : &it->second;
}

void ConvChoiceTable::set(const std::string& key, ConvChoiceEntry entry) {
  entries_[key] = std::move(entry);
  changed_ = true;
}

ConvChoiceTable ConvChoiceTable::load(const std::string& path, std::vector<std::string>* warnings) {
  ConvChoiceTable t;
  std::ifstream in(path);
  if (!in) return t;
  std::string line;
  int number = 0;
  auto warn = [&](const std::string& what) {
    if (warnings) warnings->push_back(path + ":" + std::to_string(number) + ": " + what + " (line ignored)");
  };
  while (std::getline(in, line)) {
    ++number;
    if (number == 1) {
      if (line.rfind(kFormatLine, 0) != 0) {
        warn("expected the first line '" + std::string(kFormatLine) + "...': not a conv choice file of this version");
        return ConvChoiceTable{};
      }
      continue;
    }
    if (line.rfind(kIdentityLine, 0) == 0) {
      std::string why;
      if (!parse_identity(line, t.identity_, why)) warn(why);
      continue;
    }
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> f;
    std::istringstream ls(line);
    for (std::string part; std::getline(ls, part, '\t');) f.push_back(part);
    double ms = -1;
    if (f.size() == 5) {
      try {
        ms = std::stod(f[2]);
      } catch (const std::exception&) {
        ms = -1;
      }
    }
    if (f.size() != 5 || f[0].empty() || f[1].empty() || !(ms >= 0)) {
      warn("expected key, algorithm, milliseconds >= 0, timings and the heuristic's algorithm separated by tabs");
      continue;
    }
    t.entries_[f[0]] = {f[1], ms, f[3], f[4]};
  }
  return t;
}

void ConvChoiceTable::merge_committed(const ConvChoiceTable& committed) {
  for (const auto& [k, e] : committed.entries_)
    if (!entries_.count(k)) {
      entries_[k] = e;
      entries_[k].committed = true;
    }
}

bool is_conv_choice_table(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_symlink(path, ec) || !std::filesystem::is_regular_file(path, ec)) return false;
  std::ifstream in(path);
  std::string first;
  const std::string_view kind(kFormatLine, std::string_view(kFormatLine).rfind(' '));  // without its version
  return std::getline(in, first) && first.rfind(kind, 0) == 0;
}

void ConvChoiceTable::save(const std::string& path, const std::string& header, const ConvDeviceIdentity& identity) const {
  std::error_code exists_ec;
  if (std::filesystem::exists(std::filesystem::symlink_status(path, exists_ec)) && !is_conv_choice_table(path))
    throw IoError(path + ": exists and is not a vkunroll conv choice table (a link, a device or another file); refusing to "
                  "replace it: move it away or set VKUNROLL_CACHE_DIR to another folder");
  ConvChoiceTable merged = load(path, nullptr);
  for (const auto& [k, e] : entries_)
    if (!e.committed) merged.entries_[k] = e;
  const std::filesystem::path p(path);
  std::error_code ec;
  if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path(), ec);
  const std::string tmp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream out(tmp, std::ios::trunc);
    if (!out) throw IoError(tmp + ": cannot write the conv choice table");
    out << kFormatLine << ": " << header << "\n";
    if (identity.known()) out << identity_line(identity) << "\n";
    out << "# key\talgorithm\tms\ttimings of every candidate (ms)\theuristic's algorithm\n";
    for (const auto& [k, e] : merged.entries_)
      out << k << '\t' << e.algo << '\t' << format_ms(e.ms) << '\t' << e.timings << '\t' << e.heuristic << '\n';
    out.flush();
    if (!out) throw IoError(tmp + ": writing the conv choice table failed");
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw IoError(path + ": cannot replace the conv choice table (" + ec.message() + ")");
  }
}

std::string conv_choice_path(const Context& ctx) {
  const std::string dir = Context::cache_directory();
  if (dir.empty()) return {};
  return (std::filesystem::path(dir) /
          ("conv-choices-" + ctx.info().uuid_string() + "-" + ctx.info().driver_version_string() + ".tsv"))
      .string();
}

std::string conv_choice_header(const Context& ctx) {
  const DeviceInfo& i = ctx.info();
  return i.name + ", driver " + i.driver_version_string() + ", uuid " + i.uuid_string();
}

ConvDeviceIdentity conv_device_identity(const Context& ctx) {
  const DeviceInfo& i = ctx.info();
  return {i.name, i.driver_version_string(), i.uuid_string(), i.vendor_id, i.device_id};
}

std::optional<CommittedConvTable> find_committed_conv_table(const std::vector<std::string>& dirs, const ConvDeviceIdentity& device,
                                                            std::vector<std::string>* warnings) {
  std::optional<CommittedConvTable> best;
  int best_rank = 0;
  for (const std::string& dir : dirs) {
    std::error_code ec;
    if (!std::filesystem::is_directory(dir, ec)) continue;
    std::vector<std::string> files;
    for (const auto& f : std::filesystem::directory_iterator(dir, ec))
      if (f.path().extension() == ".tsv") files.push_back(f.path().string());
    std::sort(files.begin(), files.end());  // the same table wins on every machine
    for (const std::string& file : files) {
      ConvChoiceTable t = ConvChoiceTable::load(file, warnings);
      const ConvDeviceIdentity& id = t.identity();
      if (!id.known()) {
        if (warnings) warnings->push_back(file + ": no '# device' line naming the device it was measured on (table ignored)");
        continue;
      }
      const bool model = id.vendor_id == device.vendor_id && id.device_id == device.device_id;
      const int rank = !model ? 0 : id.driver != device.driver ? 1 : id.uuid != device.uuid ? 2 : 3;
      if (rank <= best_rank) continue;
      best_rank = rank;
      const std::string how = rank == 3   ? "device uuid and driver"
                              : rank == 2 ? "device model and driver"
                                          : "device model (" + id.name + "), driver " + id.driver + " measured, " +
                                                device.driver + " here";
      best = CommittedConvTable{file, how, std::move(t)};
    }
  }
  return best;
}

DeviceConvTable load_device_conv_table(const Context& ctx, const std::vector<std::string>& committed_dirs,
                                       std::vector<std::string>* warnings) {
  DeviceConvTable d;
  d.path = conv_choice_path(ctx);
  d.table = std::make_shared<ConvChoiceTable>(d.path.empty() ? ConvChoiceTable{} : ConvChoiceTable::load(d.path, warnings));
  if (auto c = find_committed_conv_table(committed_dirs, conv_device_identity(ctx), warnings)) {
    d.table->merge_committed(c->table);
    d.committed = c->path;
    d.committed_how = c->how;
  }
  return d;
}

ConvAlgo gpu_family_algorithm(const Conv2d& c, const Shape& in) { return c.gpu_choice(in); }

ConvTransposeAlgo gpu_family_algorithm(const ConvTranspose2d& c) { return c.gpu_choice(); }

std::string conv_choice_key(const Conv2d& c, const Shape& in, bool residual) {
  const Conv2dParams& p = c.params();
  return "conv2d k" + std::to_string(p.kernel) + " s" + std::to_string(p.stride) + " p" + std::to_string(p.pad) +
         " " + std::to_string(c.cin()) + "->" + std::to_string(c.cout()) + " " + precision_name(c.precision()) +
         (residual ? " res " : " ") + shape_text(in);
}

std::string conv_choice_key(const ConvTranspose2d& c, const Shape& in) {
  const ConvTranspose2dParams& p = c.params();
  return "conv_transpose2d k" + std::to_string(p.kernel) + " s" + std::to_string(p.stride) + " p" +
         std::to_string(p.pad) + " " + std::to_string(c.cin()) + "->" + std::to_string(c.cout()) + " " +
         precision_name(c.precision()) + " " + shape_text(in);
}

namespace {

// Uniform values in [-1, 1]: a timing input whose result can also be checked.
Tensor random_device_tensor(Context& ctx, const Shape& s, DType dt, uint32_t seed) {
  HostTensor h(s);
  uint32_t x = seed * 2654435761u + 12345u;
  for (auto& v : h.data) {
    x = x * 1664525u + 1013904223u;
    v = static_cast<float>(x >> 8) / static_cast<float>(1u << 23) - 1.f;
  }
  return to_device(ctx, h, dt);
}

using Recorder = std::function<void(CommandStream&)>;

// The least device ms of `record` under `budget` (ConvTimingBudget); wall ms where the queue has no
// timestamps.
double budget_gpu_ms(Context& ctx, const ConvTimingBudget& budget, const Recorder& record) {
  const auto w0 = Clock::now();
  for (int w = 0; w < 64 && ms_since(w0) < budget.warm_ms; ++w) {
    CommandStream warm(ctx);
    record(warm);
    warm.submit_and_wait();
  }
  const bool stamps = ctx.info().timestamps;
  double best = 1e300;
  const auto t0 = Clock::now();
  for (int r = 0; r < std::max(1, budget.reps); ++r) {
    Profiler prof;
    CommandStream cs(ctx, stamps ? &prof : nullptr);
    record(cs);
    const auto s0 = Clock::now();
    cs.submit_and_wait();
    best = std::min(best, stamps ? prof.total_ms() : ms_since(s0));
    if (budget.candidate_ms > 0 && ms_since(t0) >= budget.candidate_ms) break;
  }
  return best;
}

// Runs each named candidate once and checks its result in `out` against the first candidate's
// (blocked: the plainest; conv_choice_disagreement); times those that agree and names the fastest,
// listing the rejected ones after the timings. A census runs none.
ConvChoiceEntry census_entry(const std::vector<std::string>& names, const std::string& heuristic, double flop) {
  ConvChoiceEntry e{heuristic, 0, {}, heuristic};
  for (const std::string& n : names) e.timings += (e.timings.empty() ? "" : " ") + n + "=untimed";
  e.flop = flop;
  return e;
}

ConvChoiceEntry time_candidates(Context& ctx, const std::vector<std::pair<std::string, Recorder>>& candidates,
                                const Tensor& out, Precision precision, const ConvTimingBudget& budget, const std::string& who,
                                const std::string& heuristic) {
  // Every candidate recorded once first and dropped unsubmitted: a stream binds its pipelines only at
  // submit, so their builds run side by side on the compiler's workers instead of one per check below.
  for (const auto& c : candidates) {
    CommandStream cs(ctx);
    c.second(cs);
  }
  std::vector<float> reference;
  std::vector<std::pair<std::string, double>> t;
  std::string rejected;
  for (const auto& [name, record] : candidates) {
    {
      CommandStream cs(ctx);
      record(cs);
      cs.submit_and_wait();
    }
    HostTensor h = to_host(out);
    if (reference.empty()) {
      reference = std::move(h.data);
    } else if (const std::string why = conv_choice_disagreement(reference, h.data, precision); !why.empty()) {
      rejected += (rejected.empty() ? "" : " ") + name + "=" + why;
      continue;
    }
    t.emplace_back(name, budget_gpu_ms(ctx, budget, record));
  }
  ConvChoiceEntry e = fastest(t, who);
  e.heuristic = heuristic;
  e.timed = static_cast<int>(t.size());
  if (!rejected.empty()) e.timings += " " + rejected;
  return e;
}

}  // namespace

ConvChoiceEntry time_conv_algorithms(Context& ctx, const Conv2d& conv, const Shape& in, bool residual,
                                     const ConvTimingBudget& budget) {
  const std::string heuristic = conv_algo_name(conv.choose_algorithm(in.h, in.w));
  if (budget.census) {
    std::vector<std::string> names;
    for (ConvAlgo a : conv.candidates(in)) names.push_back(conv_algo_name(a));
    return census_entry(names, heuristic, conv.flop(in));
  }
  const DType dt = precision_dtype(conv.precision());
  Tensor x = random_device_tensor(ctx, in, dt, 1), y(ctx, conv.output_shape(in), dt);
  std::optional<Tensor> r;
  if (residual) r.emplace(random_device_tensor(ctx, conv.output_shape(in), dt, 2));
  std::vector<std::pair<std::string, Recorder>> candidates;
  for (ConvAlgo a : conv.candidates(in))
    candidates.emplace_back(conv_algo_name(a), [&, a](CommandStream& cs) {
      conv.record(cs, Slice(x), Slice(y), r ? std::optional<Slice>(Slice(*r)) : std::nullopt, a);
    });
  ConvChoiceEntry e = time_candidates(ctx, candidates, y, conv.precision(), budget, conv.name(), heuristic);
  e.flop = conv.flop(in);
  return e;
}

ConvChoiceEntry time_conv_algorithms(Context& ctx, const ConvTranspose2d& conv, const Shape& in,
                                     const ConvTimingBudget& budget) {
  const std::string heuristic = conv_transpose_algo_name(conv.choose_algorithm(in.h, in.w));
  if (budget.census) {
    std::vector<std::string> names;
    for (ConvTransposeAlgo a : conv.candidates()) names.push_back(conv_transpose_algo_name(a));
    return census_entry(names, heuristic, conv.flop(in));
  }
  const DType dt = precision_dtype(conv.precision());
  Tensor x = random_device_tensor(ctx, in, dt, 3), y(ctx, conv.output_shape(in), dt);
  std::vector<std::pair<std::string, Recorder>> candidates;
  for (ConvTransposeAlgo a : conv.candidates())
    candidates.emplace_back(conv_transpose_algo_name(a),
                            [&, a](CommandStream& cs) { conv.record(cs, Slice(x), Slice(y), a); });
  ConvChoiceEntry e = time_candidates(ctx, candidates, y, conv.precision(), budget, "conv_transpose2d", heuristic);
  e.flop = conv.flop(in);
  return e;
}

namespace {

// fma_ceiling*.comp: 64 invocations a group, 8 vec4 chains each, `iters` rounds of FMAs.
constexpr uint32_t kCeilingGroups = 256;

struct CeilingRun {
  Tensor sink;
  const Pipeline* pipeline;
  double flop;
};

CeilingRun ceiling_run(Context& ctx, bool half, double gflop) {
  const uint32_t iters = std::max<uint32_t>(16, static_cast<uint32_t>(std::lround(gflop * 1e9 / (2.0 * 4 * 8 * 64 * kCeilingGroups))));
  return {Tensor(ctx, {1, 1, 1, kCeilingGroups * 64 * 4}),
          &kernel_pipeline(ctx, half ? "fma_ceiling_half" : "fma_ceiling", {iters}, 2 * sizeof(float)),
          2.0 * 4 * 8 * iters * kCeilingGroups * 64.0};
}

void record_ceiling(CommandStream& cs, const CeilingRun& c) {
  const struct {
    float a, b;
  } push{0.999f, 0.001f};
  cs.dispatch(*c.pipeline, {out(c.sink)}, push, Groups{kCeilingGroups}, {"fma_ceiling", c.flop, 0});
}

}  // namespace

double fma_ceiling_gflops(Context& ctx, bool half, int reps, double gflop) {
  if (half && !ctx.info().shader_float16) return 0;
  const CeilingRun c = ceiling_run(ctx, half, gflop);
  const double ms = budget_gpu_ms(ctx, {reps, 0, 1, false}, [&](CommandStream& cs) { record_ceiling(cs, c); });
  return c.flop / (ms * 1e6);
}

void warm_device(Context& ctx, double ms) {
  const CeilingRun c = ceiling_run(ctx, false, 2.147483648);
  const auto t0 = Clock::now();
  do {
    CommandStream cs(ctx);
    for (int i = 0; i < 4; ++i) record_ceiling(cs, c);
    cs.submit_and_wait();
  } while (ms_since(t0) < ms);
}

}  // namespace vkunroll
