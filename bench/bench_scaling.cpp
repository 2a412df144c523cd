// vkunroll-bench-scaling: how a GS frame's time grows with the frame's pixels and with its events,
// for the physics unroller and SelfUnroll-S (the default model, dense), through UnrollSession.
// Inputs are synthetic: a random RS image and events uniform over the pixels and the frame's span
// (time only; accuracy is the report's business, vkunroll-bench-report).
//
//   vkunroll-bench-scaling [--sizes 346x260,640x480,1280x720] [--events 1e4,1e5,1e6,1e7]
//                          [--pixel-rows-events 1e5] [--events-size 346x260] [--modes physics,s]
//                          [--model FILE] [--reps 2] [--json FILE]
//
// Per row: the best of --reps (after the first, which also builds pipelines), ms per GS frame,
// the GPU's share (timestamps), the wait and the host stages, and the cost per megapixel and per
// million events; the closing lines compare the largest row with the smallest: linear growth
// gives a cost per unit ratio of 1.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "bench_args.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/session.hpp"

using namespace vkunroll;

namespace {

struct Row {
  std::string axis;  // "pixels" or "events"
  int w = 0, h = 0;
  size_t events = 0;
  std::string mode;
  double ms = 0, gpu_ms = 0, wait_ms = 0;
  nlohmann::json host_ms, gpu_by_stage;
  bool host_path = false;
};

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> v;
  size_t a = 0;
  for (size_t b; (b = s.find(',', a)) != std::string::npos; a = b + 1) v.push_back(s.substr(a, b - a));
  v.push_back(s.substr(a));
  return v;
}

std::pair<int, int> parse_size(const std::string& s) {
  int w = 0, h = 0;
  char tail = 0;
  if (std::sscanf(s.c_str(), "%dx%d%c", &w, &h, &tail) != 2 || w < 8 || h < 8 || w > 8192 || h > 8192)
    throw UsageError("vkunroll-bench-scaling: size '" + s + "': expected WxH, 8..8192 each");
  return {w, h};
}

size_t parse_count(const std::string& s) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end || !(v >= 1 && v <= 1e8)) throw UsageError("vkunroll-bench-scaling: event count '" + s + "': expected 1..1e8");
  return static_cast<size_t>(v);
}

// A frame read out in 20 ms (any height), 3 ms exposure; `n` events uniform over pixels and span.
FrameInput synthetic_frame(int w, int h, size_t n, EventStream& ev) {
  std::mt19937_64 rng(7);
  FrameInput in;
  in.rs1 = cv::Mat(h, w, CV_32FC3);
  cv::randu(in.rs1, 0.1, 0.9);
  in.timing1 = {Rational(0), Rational(20000, h), Rational(3000), h, Readout::top_down};
  const int64_t span = (in.timing1.last_end() - in.timing1.t0).floor();
  ev = EventStream();
  ev.width = w, ev.height = h;
  std::vector<int64_t> t(n);
  std::uniform_int_distribution<int64_t> dt(0, span);
  for (auto& v : t) v = dt(rng);
  std::sort(t.begin(), t.end());
  ev.reserve(n);
  std::uniform_int_distribution<int> dx(0, w - 1), dy(0, h - 1), dp(0, 1);
  for (int64_t v : t) ev.push(v, static_cast<uint16_t>(dx(rng)), static_cast<uint16_t>(dy(rng)), dp(rng) ? 1 : -1);
  in.events = &ev;
  return in;
}

Row time_row(UnrollSession& session, const std::string& axis, int w, int h, size_t n, const std::string& mode, int reps) {
  EventStream ev;
  const FrameInput in = synthetic_frame(w, h, n, ev);
  const std::vector<FrameTarget> targets{
      {in.timing1.target_time(Rational(1, 2)), mode == "s" ? FrameTarget::Method::s : FrameTarget::Method::physics}};
  Row best;
  for (int r = 0; r < reps + 1; ++r) {  // the first builds pipelines for the new shapes: not counted
    const SessionStats before = session.stats();
    const DeviceTraffic t0 = session.traffic();
    const Stopwatch unrolling;
    session.unroll(in, targets);
    const double ms = unrolling.ms();
    if (r == 0 || (r > 1 && ms >= best.ms)) continue;
    const DeviceTraffic d = session.traffic() - t0;
    best = {axis, w, h, n, mode, ms, d.gpu_ms, d.wait_ms, nlohmann::json::object(), nlohmann::json::object(),
            session.stats().host_path_targets > before.host_path_targets};
    for (const auto& [stage, v] : session.stats().ms)
      best.host_ms[stage_name(stage)] = v - (before.ms.count(stage) ? before.ms.at(stage) : 0.0);
    for (const auto& [k, v] : d.gpu_ms_by_stage)
      if (v > 0) best.gpu_by_stage[k.empty() ? "other" : k] = v;
  }
  std::printf("%-6s %5dx%-5d %9zu %-8s %10.1f %8.1f %8.1f %9.2f %11.3f%s\n", axis.c_str(), w, h, n, mode.c_str(), best.ms,
              best.gpu_ms, best.wait_ms, best.ms / (double(w) * h / 1e6), best.ms / (double(n) / 1e6),
              best.host_path ? "  (host path: event tensors beyond one binding)" : "");
  std::fflush(stdout);
  return best;
}

// Largest against smallest row of an axis and mode: the cost per unit's ratio (1: linear).
void print_growth(const std::vector<Row>& rows, const std::string& axis, const std::string& mode) {
  std::vector<const Row*> r;
  for (const Row& x : rows)
    if (x.axis == axis && x.mode == mode) r.push_back(&x);
  if (r.size() < 2) return;
  auto units = [&](const Row* x) { return axis == "pixels" ? double(x->w) * x->h : double(x->events); };
  const Row* lo = r.front();
  const Row* hi = r.back();
  const double grow_units = units(hi) / units(lo), grow_ms = hi->ms / lo->ms;
  std::printf("%s, %s: %.1fx the %s cost %.2fx the time; per unit %.2fx (1.00 = linear; below: a fixed cost is shared)\n",
              mode.c_str(), axis.c_str(), grow_units, axis.c_str(), grow_ms, grow_ms / grow_units);
}

}  // namespace

int main(int argc, char** argv) try {
  std::string sizes = "346x260,640x480,1280x720", counts = "1e4,1e5,1e6,1e7", modes = "physics,s", model, json_path;
  std::string events_size = "346x260", pixel_rows_events = "1e5";
  int reps = 2;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError("vkunroll-bench-scaling: " + a + " needs a value");
      return argv[++i];
    };
    if (a == "--sizes") sizes = next();
    else if (a == "--events") counts = next();
    else if (a == "--events-size") events_size = next();
    else if (a == "--pixel-rows-events") pixel_rows_events = next();
    else if (a == "--modes") modes = next();
    else if (a == "--model") model = next();
    else if (a == "--json") json_path = next();
    else if (a == "--reps") reps = static_cast<int>(bench_int_arg("vkunroll-bench-scaling", a, next(), 1, 1000));
    else if (a == "-h" || a == "--help") {
      std::cout << "usage: vkunroll-bench-scaling [--sizes 346x260,640x480,1280x720] [--events 1e4,1e5,1e6,1e7]\n"
                   "         [--pixel-rows-events 1e5] [--events-size 346x260] [--modes physics,s] [--model FILE]\n"
                   "         [--reps 2] [--json FILE]\n";
      return 0;
    } else throw UsageError("vkunroll-bench-scaling: unknown argument '" + a + "' (see --help)");
  }
  for (const std::string& m : split(modes))
    if (m != "physics" && m != "s") throw UsageError("vkunroll-bench-scaling: --modes '" + m + "': expected physics or s");
  if (model.empty() && modes.find('s') != std::string::npos) model = find_default_model().path;
  SessionOptions so;
  so.model_path = model;
  so.announce = false;
  UnrollSession session(so);
  TileOptions dense;
  dense.sparse = SparsePolicy::off;  // the dense cost: sparse rows are the report's
  session.set_tiling(dense);
  std::printf("device: %s; model: %s; best of %d after a pipeline-building run; synthetic uniform events\n",
              session.context() ? session.context()->info().name.c_str() : "cpu", model.empty() ? "none" : model.c_str(), reps);
  std::printf("%-6s %11s %9s %-8s %10s %8s %8s %9s %11s\n", "axis", "size", "events", "mode", "ms/GS", "GPU ms", "wait ms",
              "ms/Mpx", "ms/Mevents");
  std::vector<Row> rows;
  for (const std::string& m : split(modes)) {
    for (const std::string& s : split(sizes)) {
      const auto [w, h] = parse_size(s);
      rows.push_back(time_row(session, "pixels", w, h, parse_count(pixel_rows_events), m, reps));
    }
    const auto [w, h] = parse_size(events_size);
    for (const std::string& c : split(counts)) rows.push_back(time_row(session, "events", w, h, parse_count(c), m, reps));
  }
  for (const std::string& m : split(modes)) {
    print_growth(rows, "pixels", m);
    print_growth(rows, "events", m);
  }
  if (!json_path.empty()) {
    nlohmann::json j = nlohmann::json::array();
    for (const Row& r : rows)
      j.push_back({{"axis", r.axis}, {"width", r.w}, {"height", r.h}, {"events", r.events}, {"mode", r.mode}, {"ms", r.ms},
                   {"gpu_ms", r.gpu_ms}, {"wait_ms", r.wait_ms}, {"host_ms", r.host_ms}, {"gpu_ms_by_stage", r.gpu_by_stage},
                   {"host_path", r.host_path}});
    std::ofstream f(json_path);
    if (!(f << j.dump(1) << "\n")) throw Error("vkunroll-bench-scaling: cannot write --json " + json_path);
  }
  return 0;
} catch (const UsageError& e) {
  std::cerr << e.what() << "\n";
  return 2;
} catch (const std::exception& e) {
  std::cerr << "vkunroll-bench-scaling: " << e.what() << "\n";
  return 1;
}
