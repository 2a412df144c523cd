// vkunroll voxelize: the row-aware event tensors ev1, ev2, ev3 of (frame, target) pairs of a
// sequence, written as float32 safetensors [frames x targets, 2N, H, W], frame-major.
#include <chrono>
#include <iostream>
#include <nlohmann/json.hpp>

#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

const char* kUsage =
    "usage: vkunroll voxelize SEQUENCE --frames LIST (--times LIST | --times-us LIST) --out FILE.safetensors\n"
    "                         [--bins N] [--crop x,y,w,h] [--target-exposure US] [--cpu] [--device D]\n"
    "                         [--layout auto|generic|gev-rs|gev-rs-real|dre|fastec] [--line-delay US]\n"
    "                         [--exposure US] [--readout top-down|bottom-up] [--t0s LIST] [--frame-period US]\n"
    "                         [--gev-half-row] [--on-bad error|drop|sort] [--batch PAIRS]\n\n"
    "Writes float32 tensors ev1, ev2, ev3 of shape [frames x targets, 2N, H, W] (frame-major: pair i is\n"
    "frame i / targets, target i % targets) and, in __metadata__, every pair's frame and exact t* (us).\n\n"
    "  --frames LIST      frame indices: '0,3,7', 'a:b' (a..b inclusive) or 'a:b:n' (n evenly spaced)\n"
    "  --times LIST       normalized targets tau (t* = t0 + tau * (last row end - t0); <0 or >1 is\n"
    "                     inter-frame): '-0.25,0.5,1.25' or 'start:stop:count' (count values, both ends\n"
    "                     included: 0:1:5 = 0,0.25,0.5,0.75,1). Values are exact ('1/3', '0.1').\n"
    "  --times-us LIST    absolute targets t* in microseconds, same syntax (the same t* for every frame)\n"
    "  --bins N           temporal bins (default 16; 2N channels)\n"
    "  --crop x,y,w,h     sensor window; rows keep their own full-sensor times\n"
    "  --target-exposure  ev3 window length in us (default: the frame's exposure)\n"
    "  --cpu              use the CPU reference instead of the GPU builder\n"
    "  timing overrides   --line-delay, --exposure (us, exact: '73000/259'), --readout, --t0s LIST (one per\n"
    "                     frame of the sequence), --frame-period (Gev-RS-Real), --gev-half-row (Gev-RS)\n";

SensorCrop parse_crop(const std::string& s) {
  std::vector<int> v;
  size_t pos = 0;
  while (pos <= s.size()) {
    const size_t comma = s.find(',', pos);
    const std::string item = s.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    try {
      size_t used = 0;
      v.push_back(std::stoi(item, &used));
      if (used != item.size()) throw std::invalid_argument("trailing");
    } catch (const std::exception&) {
      throw Error("--crop: '" + s + "' is not x,y,w,h (four integers)");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (v.size() != 4) throw Error("--crop: '" + s + "' is not x,y,w,h (four integers)");
  return {v[0], v[1], v[2], v[3]};
}

}  // namespace

int cmd_voxelize(const Argv& argv) {
  Args args("voxelize", argv,
            {"frames", "times", "times-us", "bins", "crop", "out", "target-exposure", "device", "layout", "line-delay",
             "exposure", "readout", "t0s", "frame-period", "on-bad", "batch"},
            {"cpu", "gev-half-row"});
  if (args.help()) {
    std::cout << kUsage;
    return 0;
  }
  if (args.positionals().size() != 1) throw Error("voxelize: expected one SEQUENCE folder\n" + std::string(kUsage));
  if (args.has("times") == args.has("times-us")) throw Error("voxelize: give exactly one of --times and --times-us");
  const std::string out_path = args.require("out");
  const std::string seq_path = args.positionals()[0];

  SequenceOptions so;
  if (auto v = args.get("layout")) so.layout = parse_sequence_layout(*v);
  if (auto v = args.get("line-delay")) so.line_delay_us = Rational::parse(*v, "--line-delay");
  if (auto v = args.get("exposure")) so.exposure_us = Rational::parse(*v, "--exposure");
  if (auto v = args.get("readout")) so.readout = parse_readout(*v);
  if (auto v = args.get("t0s")) so.t0s_us = parse_value_list(*v, "--t0s");
  if (auto v = args.get("frame-period")) so.frame_period_us = Rational::parse(*v, "--frame-period");
  so.gev_half_row = args.has("gev-half-row");
  if (auto v = args.get("on-bad")) {
    if (*v == "error") so.events.on_bad = BadEventPolicy::error;
    else if (*v == "drop") so.events.on_bad = BadEventPolicy::drop;
    else if (*v == "sort") so.events.on_bad = BadEventPolicy::sort;
    else throw Error("--on-bad: '" + *v + "' (expected error, drop or sort)");
  }
  const Sequence seq = load_sequence(seq_path, so);

  const std::vector<int> frames = parse_frame_list(args.require("frames"), "--frames");
  for (int f : frames) (void)seq.frame(f);
  const bool tau = args.has("times");
  const std::vector<Rational> targets =
      parse_value_list(tau ? *args.get("times") : *args.get("times-us"), tau ? "--times" : "--times-us");
  EventTensorSpec spec;
  spec.bins = static_cast<int>(args.integer("bins", 16));
  if (auto c = args.get("crop")) spec.crop = parse_crop(*c);
  const SensorCrop crop = resolve_crop(spec.crop, seq.width, seq.height);
  std::optional<Rational> texp;
  if (auto v = args.get("target-exposure")) texp = Rational::parse(*v, "--target-exposure");

  // Pairs, frame-major.
  std::vector<EventTensorPair> pairs;
  nlohmann::json pair_meta = nlohmann::json::array();
  for (int f : frames)
    for (const auto& v : targets) {
      const RowTiming& tm = seq.frame(f).timing;
      const Rational ts = tau ? tm.target_time(v) : v;
      pairs.push_back({tm, ts, texp});
      pair_meta.push_back({{"frame", f}, {"target", v.str()}, {"t_star_us", ts.str()}, {"t_star_us_float", ts.to_double()}});
    }
  const int64_t P = static_cast<int64_t>(pairs.size());
  const std::vector<int64_t> shape = {P, 2 * spec.bins, crop.height, crop.width};
  const size_t slice = static_cast<size_t>(2 * spec.bins) * crop.height * crop.width;

  nlohmann::json frames_meta = nlohmann::json::array();
  for (int f : frames) {
    const auto& tm = seq.frame(f).timing;
    frames_meta.push_back({{"frame", f}, {"image", seq.frame(f).image}, {"t0_us", tm.t0.str()},
                           {"line_delay_us", tm.line_delay.str()}, {"exposure_us", tm.exposure.str()},
                           {"readout", readout_name(tm.readout)}});
  }
  std::map<std::string, std::string> meta = {
      {"format", "vkunroll-event-tensors-1"},
      {"sequence", seq.root},
      {"layout", sequence_layout_name(seq.layout)},
      {"bins", std::to_string(spec.bins)},
      {"crop", std::to_string(crop.x0) + "," + std::to_string(crop.y0) + "," + std::to_string(crop.width) + "," +
                   std::to_string(crop.height)},
      {"target_kind", tau ? "tau" : "absolute_us"},
      {"frames", frames_meta.dump()},
      {"pairs", pair_meta.dump()},
      {"order", "frame-major: pair = frame_index * targets + target_index"},
  };
  SafetensorsStreamWriter writer(out_path,
                                 {{"ev1", StDType::F32, shape}, {"ev2", StDType::F32, shape}, {"ev3", StDType::F32, shape}},
                                 meta);

  std::unique_ptr<Context> ctx;
  std::unique_ptr<EventTensorBuilder> builder;
  if (!args.has("cpu")) {
    ContextOptions co;
    if (auto d = args.get("device")) co.device = *d;
    ctx = std::make_unique<Context>(co);
    builder = std::make_unique<EventTensorBuilder>(*ctx);
  }
  // Pairs in batches that keep host memory bounded (three tensors of `batch` pairs).
  int64_t batch = args.integer("batch", 0);
  if (batch <= 0) batch = std::max<int64_t>(1, static_cast<int64_t>((256ull << 20) / (3 * slice * 4)));
  const auto t_start = std::chrono::steady_clock::now();
  size_t events_read = 0, events_used = 0;
  EventTensors t;
  for (int64_t p0 = 0; p0 < P; p0 += batch) {
    const int64_t np = std::min(batch, P - p0);
    const std::vector<EventTensorPair> part(pairs.begin() + p0, pairs.begin() + p0 + np);
    const auto jobs = event_tensor_jobs(part);
    const auto [lo, hi] = event_time_window(jobs, spec, seq.width, seq.height);
    EventReadReport report;
    EventStream ev;
    if (lo < hi) {
      ev = seq.read_events(lo, hi, &report);
    } else {
      ev.width = seq.width;
      ev.height = seq.height;
    }
    if (report.dropped()) std::cerr << "voxelize: " << report.summary() << "\n";
    events_read += ev.size();
    // Reused across batches: the builder overwrites the same host storage (no fresh pages).
    if (builder) builder->build(ev, part, spec, t);
    else t = build_event_tensors_ref(ev, part, spec);
    events_used += t.events_considered;
    const size_t off = static_cast<size_t>(p0) * slice * 4, bytes = static_cast<size_t>(np) * slice * 4;
    writer.write("ev1", off, t.ev1.data(), bytes);
    writer.write("ev2", off, t.ev2.data(), bytes);
    writer.write("ev3", off, t.ev3.data(), bytes);
  }
  writer.finish();
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  std::cout << "wrote " << out_path << ": ev1, ev2, ev3 float32 [" << P << ", " << 2 * spec.bins << ", " << crop.height
            << ", " << crop.width << "] (" << frames.size() << " frames x " << targets.size() << " targets), "
            << events_read << " events read, " << events_used << " in the tensors' windows, "
            << (builder ? "GPU" : "CPU") << ", " << secs << " s\n";
  for (const auto& n : seq.notes) std::cout << "  timing: " << n << "\n";
  return 0;
}

}  // namespace vkunroll::cli
