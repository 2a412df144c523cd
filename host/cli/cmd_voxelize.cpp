// vkunroll voxelize: the row-aware event tensors ev1, ev2, ev3 of (frame, target) pairs of a
// sequence, written as float32 safetensors [frames x targets, 2N, H, W], frame-major.
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/unroll/output_file.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

struct VoxelizeArgs {
  std::string sequence, frames, times, times_us, out, crop, target_exposure;
  int bins = 16;
  int64_t batch = 0;
  bool cpu = false, overwrite = false;
  SequenceTimingArgs timing;
  DeviceArgs device;
};

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
      throw UsageError("--crop '" + s + "': expected x,y,w,h (four integers)");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (v.size() != 4) throw UsageError("--crop '" + s + "': expected x,y,w,h (four integers)");
  if (v[0] < 0 || v[1] < 0) throw UsageError("--crop '" + s + "': x and y must be >= 0");
  if (v[2] <= 0 || v[3] <= 0) throw UsageError("--crop '" + s + "': the width and height must be positive");
  return {v[0], v[1], v[2], v[3]};
}

// Writes of the output file failing are I/O errors (exit 74), whatever the writer calls them.
template <class F>
void output_io(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::unspecified) throw;
    throw IoError(e.text());
  }
}

// The targets and frames of the command line, parsed and range-checked.
struct VoxelizeTargets {
  bool tau = false;  // --times (normalized) rather than --times-us
  std::vector<Rational> targets;
  std::vector<int> frames;
  std::optional<Rational> exposure;  // --target-exposure
};

VoxelizeTargets parse_targets(const VoxelizeArgs& a) {
  VoxelizeTargets t;
  t.tau = !a.times.empty();
  if (t.tau == !a.times_us.empty()) throw UsageError("give exactly one of --times and --times-us");
  try {
    t.targets = parse_value_list(t.tau ? a.times : a.times_us, t.tau ? "times" : "times_us");
    t.frames = parse_frame_list(a.frames, "frames");
    if (!a.target_exposure.empty()) t.exposure = Rational::parse(a.target_exposure, "--target-exposure");
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  for (const Rational& v : t.targets)
    if (!(std::abs(v.to_double()) <= (t.tau ? kMaxTau : kMaxTimeUs)))
      throw UsageError(std::string(t.tau ? "--times " : "--times-us ") + v.str() + ": out of range (" +
                       (t.tau ? "a normalized target must lie within +-1e6 frame spans)" : "times must lie within +-2^53 us)"));
  if (t.exposure && (*t.exposure <= Rational(0) || t.exposure->to_double() > kMaxTimeUs))
    throw UsageError("--target-exposure " + t.exposure->str() + ": expected a window length > 0 us (and within 2^53 us)");
  return t;
}

// The (frame, target) pairs, frame-major, and their description for the file's metadata.
std::vector<EventTensorPair> voxelize_pairs(const Sequence& seq, const VoxelizeTargets& t, nlohmann::json& pair_meta) {
  std::vector<EventTensorPair> pairs;
  pair_meta = nlohmann::json::array();
  try {
    for (int f : t.frames)
      for (const auto& v : t.targets) {
        const RowTiming& tm = seq.frame(f).timing;
        const Rational ts = t.tau ? tm.target_time(v) : v;
        check_target_in_recording(seq, ts.to_double(), t.tau ? "times" : "times_us");
        pairs.push_back({tm, ts, t.exposure});
        pair_meta.push_back({{"frame", f}, {"target", v.str()}, {"t_star_us", ts.str()}, {"t_star_us_float", ts.to_double()}});
      }
  } catch (const TimeRangeError& e) {
    throw UsageError(std::string(t.tau ? "--times" : "--times-us") + ": a target is out of the range of exact time arithmetic (" +
                     e.what() + ")");
  }
  return pairs;
}

std::map<std::string, std::string> voxelize_metadata(const Sequence& seq, const VoxelizeTargets& t, const EventTensorSpec& spec,
                                                     const SensorCrop& crop, const nlohmann::json& pair_meta) {
  nlohmann::json frames_meta = nlohmann::json::array();
  for (int f : t.frames) {
    const auto& tm = seq.frame(f).timing;
    frames_meta.push_back({{"frame", f}, {"image", seq.frame(f).image}, {"t0_us", tm.t0.str()},
                           {"line_delay_us", tm.line_delay.str()}, {"exposure_us", tm.exposure.str()},
                           {"readout", readout_name(tm.readout)}});
  }
  return {
      {"format", "vkunroll-event-tensors-1"},
      {kSafetensorsWrittenBy, std::string(kWrittenByVkunroll) + " voxelize"},
      {"sequence", seq.root},
      {"layout", sequence_layout_name(seq.layout)},
      {"bins", std::to_string(spec.bins)},
      {"crop", std::to_string(crop.x0) + "," + std::to_string(crop.y0) + "," + std::to_string(crop.width) + "," +
                   std::to_string(crop.height)},
      {"target_kind", t.tau ? "tau" : "absolute_us"},
      {"frames", frames_meta.dump()},
      {"pairs", pair_meta.dump()},
      {"order", "frame-major: pair = frame_index * targets + target_index"},
  };
}

struct VoxelizeCounts {
  size_t events_read = 0, events_used = 0;
};

// The tensors of `pairs` in batches that keep host memory bounded (three tensors of `batch`
// pairs), each written at its place in the file. builder null: the CPU reference.
VoxelizeCounts write_tensors(const Sequence& seq, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec,
                             size_t slice, int64_t batch, EventTensorBuilder* builder, SafetensorsStreamWriter& writer) {
  const int64_t P = static_cast<int64_t>(pairs.size());
  if (batch <= 0) batch = std::max<int64_t>(1, static_cast<int64_t>((256ull << 20) / (3 * slice * 4)));
  VoxelizeCounts counts;
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
    counts.events_read += ev.size();
    // Reused across batches: the builder overwrites the same host storage (no fresh pages).
    if (builder) builder->build(ev, part, spec, t);
    else t = build_event_tensors_ref(ev, part, spec);
    counts.events_used += t.events_considered;
    const size_t off = static_cast<size_t>(p0) * slice * 4, bytes = static_cast<size_t>(np) * slice * 4;
    output_io([&] {
      writer.write("ev1", off, t.ev1.data(), bytes);
      writer.write("ev2", off, t.ev2.data(), bytes);
      writer.write("ev3", off, t.ev3.data(), bytes);
    });
  }
  return counts;
}

int run_voxelize(const VoxelizeArgs& a) {
  SequenceOptions so = sequence_options(a.timing);
  check_output_file(a.out, "--out");
  check_output_file_rule(a.out, output_path("voxelize.out"), a.overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse,
                         {{opt("sequence"), a.sequence}, {opt("events") + " file", so.events_file.value_or("")}});
  const VoxelizeTargets targets = parse_targets(a);
  EventTensorSpec spec;
  spec.bins = a.bins;
  if (!a.crop.empty()) spec.crop = parse_crop(a.crop);
  std::error_code ec;
  if (!std::filesystem::exists(a.sequence, ec)) throw InputMissingError("SEQUENCE " + a.sequence + ": no such folder");
  const Sequence seq = load_sequence(a.sequence, so);
  for (const auto& w : seq.warnings) std::cerr << "voxelize: warning: " << w << "\n";
  for (const auto& f : seq.event_files) check_output_apart(a.out, "out", {{"event file", f}});
  for (int f : targets.frames) (void)seq.frame(f);
  SensorCrop crop;
  try {
    crop = resolve_crop(spec.crop, seq.width, seq.height);
  } catch (const Error& e) {
    throw UsageError("--crop " + a.crop + ": " + e.what());
  }
  nlohmann::json pair_meta;
  const std::vector<EventTensorPair> pairs = voxelize_pairs(seq, targets, pair_meta);
  const int64_t P = static_cast<int64_t>(pairs.size());
  const std::vector<int64_t> shape = {P, 2 * spec.bins, crop.height, crop.width};
  const size_t slice = static_cast<size_t>(2 * spec.bins) * crop.height * crop.width;  // > 0: bins and crop checked
  std::unique_ptr<SafetensorsStreamWriter> writer;
  output_io([&] {
    writer = std::make_unique<SafetensorsStreamWriter>(
        a.out, std::vector<SafetensorsStreamWriter::Spec>{{"ev1", StDType::F32, shape}, {"ev2", StDType::F32, shape}, {"ev3", StDType::F32, shape}},
        voxelize_metadata(seq, targets, spec, crop, pair_meta));
  });

  std::unique_ptr<Context> ctx;
  std::unique_ptr<EventTensorBuilder> builder;
  if (!a.cpu) {
    ContextOptions co;
    co.device = a.device.device;
    ctx = std::make_unique<Context>(co);
    builder = std::make_unique<EventTensorBuilder>(*ctx);
  }
  const Stopwatch writing;
  const VoxelizeCounts counts = write_tensors(seq, pairs, spec, slice, a.batch, builder.get(), *writer);
  output_io([&] { writer->finish(); });
  const double secs = writing.seconds();
  std::cout << "wrote " << a.out << ": ev1, ev2, ev3 float32 [" << P << ", " << 2 * spec.bins << ", " << crop.height << ", "
            << crop.width << "] (" << targets.frames.size() << " frames x " << targets.targets.size() << " targets), "
            << counts.events_read << " events read, " << counts.events_used << " in the tensors' windows, "
            << (builder ? "GPU" : "CPU") << ", " << secs << " s\n";
  if (counts.events_read == 0) std::cerr << "voxelize: warning: no events in the pairs' windows: every tensor is zero\n";
  for (const auto& n : seq.notes) std::cout << "  timing: " << n << "\n";
  return 0;
}

}  // namespace

Command add_voxelize(CLI::App& parent) {
  auto a = std::make_shared<VoxelizeArgs>();
  CLI::App* c = parent.add_subcommand("voxelize", "row-aware event tensors ev1/ev2/ev3 of (frame, target) pairs -> safetensors");
  c->description(
      "Writes float32 tensors ev1, ev2, ev3 of shape [frames x targets, 2N, H, W] (frame-major: pair i is\n"
      "frame i / targets, target i % targets) and, in __metadata__, every pair's frame and exact t* (us).");
  c->add_option("SEQUENCE", a->sequence, "a sequence folder (any layout unroll reads)")->required();
  c->add_option("--frames", a->frames, "frame indices: '0,3,7', 'a:b' (a..b inclusive) or 'a:b:n' (n evenly spaced)")
      ->required()->type_name("LIST");
  auto* times = c->add_option("--times", a->times,
                              "normalized targets tau (t* = t0 + tau * (last row end - t0); <0 or >1 is inter-frame): "
                              "'-0.25,0.5,1.25' or 'start:stop:count'; exact ('1/3', '0.1')")
                    ->type_name("LIST");
  c->add_option("--times-us", a->times_us, "absolute targets t* in microseconds, same syntax (the same t* for every frame)")
      ->excludes(times)->type_name("LIST");
  add_output_option(c, "voxelize.out", a->out)->required();
  c->add_flag("--overwrite", a->overwrite, "replace an existing --out file (only one vkunroll wrote)");
  c->add_option("--bins", a->bins, "temporal bins N (2N channels)")->check(int_range(1, 4096))->capture_default_str()->type_name("N");
  c->add_option("--crop", a->crop, "sensor window x,y,w,h (w, h > 0); rows keep their own full-sensor times")->type_name("X,Y,W,H");
  c->add_option("--target-exposure", a->target_exposure, "ev3 window length in us, > 0 (default: the frame's exposure)")
      ->type_name("US");
  c->add_flag("--cpu", a->cpu, "use the CPU reference instead of the GPU builder");
  c->add_option("--batch", a->batch, "pairs per batch (0: as many as fit in 256 MiB)")->check(int_range(0, 1 << 30))->type_name("PAIRS");
  add_device_options(c, a->device);
  add_sequence_timing(c, a->timing);
  return {c, [a] {
            apply_threads(a->device.threads);
            return run_voxelize(*a);
          }};
}

}  // namespace vkunroll::cli
