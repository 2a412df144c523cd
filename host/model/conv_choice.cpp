#include "vkunroll/host/model/conv_choice.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <unistd.h>

#include "vkunroll/base/error.hpp"
#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"

namespace vkunroll {

namespace {

constexpr const char* kFormatLine = "# vkunroll conv algorithm choices v1";

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
  if (t.empty()) throw Error(who + ": no algorithm applies to this shape");
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
                       ConvChoice::retune})
    if (s == conv_choice_name(c)) return c;
  throw UsageError(what + " '" + s + "': expected auto, heuristic, cached, measured or retune");
}

const char* conv_choice_name(ConvChoice c) {
  switch (c) {
    case ConvChoice::automatic: return "auto";
    case ConvChoice::heuristic: return "heuristic";
    case ConvChoice::cached: return "cached";
    case ConvChoice::measured: return "measured";
    case ConvChoice::retune: return "retune";
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

void ConvChoiceTable::save(const std::string& path, const std::string& header) const {
  ConvChoiceTable merged = load(path, nullptr);
  for (const auto& [k, e] : entries_) merged.entries_[k] = e;
  const std::filesystem::path p(path);
  std::error_code ec;
  if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path(), ec);
  const std::string tmp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream out(tmp, std::ios::trunc);
    if (!out) throw Error(tmp + ": cannot write the conv choice table");
    out << kFormatLine << ": " << header << "\n"
        << "# key\talgorithm\tms\ttimings of every candidate (ms)\theuristic's algorithm\n";
    for (const auto& [k, e] : merged.entries_)
      out << k << '\t' << e.algo << '\t' << format_ms(e.ms) << '\t' << e.timings << '\t' << e.heuristic << '\n';
    out.flush();
    if (!out) throw Error(tmp + ": writing the conv choice table failed");
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw Error(path + ": cannot replace the conv choice table (" + ec.message() + ")");
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

// Runs each named candidate once and checks its result in `out` against the first candidate's
// (blocked: the plainest; conv_choice_disagreement); times those that agree and names the fastest,
// listing the rejected ones after the timings.
ConvChoiceEntry time_candidates(Context& ctx, const std::vector<std::pair<std::string, Recorder>>& candidates,
                                const Tensor& out, Precision precision, int reps, const std::string& who) {
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
    t.emplace_back(name, best_gpu_ms(ctx, reps, record));
  }
  ConvChoiceEntry e = fastest(t, who);
  if (!rejected.empty()) e.timings += " " + rejected;
  return e;
}

}  // namespace

ConvChoiceEntry time_conv_algorithms(Context& ctx, const Conv2d& conv, const Shape& in, bool residual, int reps) {
  const DType dt = precision_dtype(conv.precision());
  Tensor x = random_device_tensor(ctx, in, dt, 1), y(ctx, conv.output_shape(in), dt);
  std::optional<Tensor> r;
  if (residual) r.emplace(random_device_tensor(ctx, conv.output_shape(in), dt, 2));
  std::vector<std::pair<std::string, Recorder>> candidates;
  for (ConvAlgo a : conv.candidates(in))
    candidates.emplace_back(conv_algo_name(a), [&, a](CommandStream& cs) {
      conv.record(cs, Slice(x), Slice(y), r ? std::optional<Slice>(Slice(*r)) : std::nullopt, a);
    });
  ConvChoiceEntry e = time_candidates(ctx, candidates, y, conv.precision(), reps, conv.name());
  e.heuristic = conv_algo_name(conv.choose_algorithm(in.h, in.w));
  return e;
}

ConvChoiceEntry time_conv_algorithms(Context& ctx, const ConvTranspose2d& conv, const Shape& in, int reps) {
  const DType dt = precision_dtype(conv.precision());
  Tensor x = random_device_tensor(ctx, in, dt, 3), y(ctx, conv.output_shape(in), dt);
  std::vector<std::pair<std::string, Recorder>> candidates;
  for (ConvTransposeAlgo a : conv.candidates())
    candidates.emplace_back(conv_transpose_algo_name(a),
                            [&, a](CommandStream& cs) { conv.record(cs, Slice(x), Slice(y), a); });
  ConvChoiceEntry e = time_candidates(ctx, candidates, y, conv.precision(), reps, "conv_transpose2d");
  e.heuristic = conv_transpose_algo_name(conv.choose_algorithm(in.h, in.w));
  return e;
}

}  // namespace vkunroll
