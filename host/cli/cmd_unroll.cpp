// vkunroll unroll: a recording -> GS video (host/unroll/unroll.hpp does the work).
#include <iostream>
#include <memory>

#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/follow_source.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/unroll/value_list.hpp"

namespace vkunroll::cli {

namespace {

struct UnrollArgs {
  std::optional<std::string> frames;  // given empty: an error (never "all frames" by accident)
  std::string sequence, out, trace, model, mode = "auto", times = "0.5", times_us, channel_order, backend = "vulkan",
                           precision = "fp32", sparse = "exact", frame_format, bit_depth, conv_choice = "auto",
                           gate_radius = "auto";
  std::optional<double> contrast, gamma, fps;
  double sparse_threshold = 0.05;
  bool sparse_split = false, profile = false;
  int64_t tile = 0, halo = -1;
  bool quiet = false, no_video = false, overwrite = false, resume = false;
  SequenceTimingArgs timing;
  DeviceArgs device;
  FollowOptions follow;
};

UnrollOptions to_options(const UnrollArgs& a) {
  UnrollOptions o;
  o.sequence = a.sequence;
  o.out_dir = a.out;
  o.trace_path = a.trace;
  o.mode = parse_unroll_mode(a.mode, "mode");
  const ModelChoice model = choose_model(o.mode, a.model);  // no --model: the shipped default
  o.session.model_path = model.path;
  o.model_source = model.source;
  try {
    o.times = parse_target_times(a.times, a.times_us);
    if (a.frames) {
      if (a.frames->empty()) throw UsageError("--frames: empty value: expected frames like 0:3 or 1,4 (leave the option out for all)");
      o.frames = parse_frame_list(*a.frames, "frames");
    }
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  if (!a.channel_order.empty()) o.channel_order = parse_channel_order(a.channel_order, "channel_order");
  o.session.device = a.device.device;
  o.session.cpu_threads = a.device.threads;
  o.session.backend = parse_backend_kind(a.backend, "backend");
  o.session.precision = parse_precision(a.precision, "precision");
  o.session.conv_choice = parse_conv_choice(a.conv_choice, "--conv-choice");
  o.session.profile_ops = a.profile;
  o.contrast = a.contrast;
  o.gamma = a.gamma;
  o.gate_radius = parse_gate_radius(a.gate_radius, "gate_radius");
  o.tile = a.tile;
  o.halo = a.halo;
  o.sparse = parse_sparse_policy(a.sparse, "sparse");
  o.sparse_threshold = a.sparse_threshold;
  o.sparse_split = a.sparse_split;
  o.quiet = a.quiet;
  o.output.write_video = !a.no_video;
  o.output.video_fps = a.fps;
  if (!a.bit_depth.empty()) o.output.frame_format = a.bit_depth == "16" ? FrameFormat::png16 : FrameFormat::png8;
  if (!a.frame_format.empty()) o.output.frame_format = parse_frame_format(a.frame_format, "frame_format");
  o.output.existing = a.resume ? ExistingOutput::resume : a.overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse;
  o.sequence_options = sequence_options(a.timing);
  o.follow = a.follow;
  o.command_line = command_line();
  o.option_spelling = flag_for;
  return o;
}

void add_model_options(CLI::App* c, UnrollArgs& a) {
  const std::string g = "Model";
  c->add_option("--model", a.model, "SelfUnroll weights (safetensors; tools/model/convert_checkpoint.py converts checkpoints); default: the "
                "shipped model (VKUNROLL_MODEL, else share/vkunroll/models/" + std::string(kDefaultModelFile) + ")")
      ->group(g)->type_name("FILE");
  c->add_option("--mode", a.mode,
                "s | m | physics (the weight-free event double integral) | auto: M when the next frame exists, else S; "
                "physics when no model file is found | choose: per target, S inside the frame's exposure span, else M")
      ->check(CLI::IsMember({"auto", "s", "m", "physics", "choose"}))->capture_default_str()->group(g)->type_name("M");
  c->add_option("--channel-order", a.channel_order, "rgb | bgr: the model's input order (default: its metadata)")
      ->check(CLI::IsMember({"rgb", "bgr"}))->group(g)->type_name("O");
  c->add_option("--contrast", a.contrast, "physics: the contrast threshold c (default: estimated from the sequence)")
      ->check(finite_at_least(0, true))->group(g)->type_name("C");
  c->add_option("--gate-radius", a.gate_radius,
                "physics-informed variant: its event gate radius; auto: 2 on a noisy recording (the contrast estimate "
                "measures its noise), else the model's; model: the weights' metadata; or N (0-15)")
      ->capture_default_str()->group(g)->type_name("R");
  c->add_option("--gamma", a.gamma, "physics: decode gamma of the frames (default: meta.json source.settings.gamma, else 1)")
      ->check(finite_at_least(0, true))->group(g)->type_name("G");
  c->add_option("--tile", a.tile,
                "run the model on N x N tiles (a multiple of 32); 0: 32 when sparse, else whole frames when they fit "
                "the device's buffers, else the largest tile that fits")
      ->check(int_range(0, 1 << 20))->capture_default_str()->group(g)->type_name("N");
  c->add_option("--halo", a.halo, "context pixels around each tile (a multiple of 32); -1: 32 when sparse, 64 for dense tiles")
      ->check(int_range(-1, 1 << 20))->capture_default_str()->group(g)->type_name("N");
  c->add_option("--sparse", a.sparse,
                "off: every tile runs | exact: tiles without an ev1/ev2 event in them or their halo (gated model: within "
                "its gate radius) keep the RS pixels (gated model: clamp(phys, 0, 1)) | "
                "fast: also tiles below --sparse-threshold")
      ->check(CLI::IsMember({"off", "exact", "fast"}))->capture_default_str()->group(g)->type_name("P");
  c->add_option("--sparse-threshold", a.sparse_threshold, "fast: events per pixel (ev1 + ev2 over a tile and its halo, or its gate radius)")
      ->check(finite_at_least(0))->capture_default_str()->group(g)->type_name("X");
  c->add_flag("--sparse-split", a.sparse_split,
              "sparse: a group of active tiles whose bounding box holds inactive tiles runs as rectangles of its "
              "tiles where those read fewer pixels (faster; less context where a rectangle cuts a mover)")
      ->group(g);
  c->add_option("--backend", a.backend, "vulkan | cpu (the CPU reference backend)")
      ->check(CLI::IsMember({"vulkan", "cpu"}))->capture_default_str()->group(g)->type_name("B");
  c->add_option("--precision", a.precision, "fp32 | fp16 (Vulkan backend: weights and buffers in f16, event tensors and physics in f32; docs/model.md)")
      ->check(CLI::IsMember({"fp32", "fp16"}))->capture_default_str()->group(g)->type_name("P");
  c->add_option("--conv-choice", a.conv_choice,
                "conv algorithm per shape: auto (the device's measured table from `vkunroll tune`; a missing shape is "
                "timed on first use on a GPU) | heuristic | cached | measured (time missing shapes on any device) | retune | "
                "gpu (the GPU kernels' rule on any device, lavapipe included: for tests and counting dispatches)")
      ->check(CLI::IsMember({"auto", "heuristic", "cached", "measured", "retune", "gpu"}))->capture_default_str()->group(g)->type_name("C");
  c->add_flag("--profile", a.profile,
              "Vulkan: every kernel's GPU time and calls per GS frame in summary.json (gpu_ms_per_gs_frame_by_op)")
      ->group(g);
  add_output_option(c, "unroll.trace", a.trace)->group(g)->type_name("FILE.json");
}

void add_output_options(CLI::App* c, UnrollArgs& a) {
  const std::string g = "Output";
  add_output_option(c, "unroll.out", a.out)->required()->group(g);
  auto* ow = c->add_flag("--overwrite", a.overwrite, "replace an existing output folder (at the end, whole)")->group(g);
  c->add_flag("--resume", a.resume,
              "continue an output (or a killed run's staging folder): GS frames already written and valid are kept")
      ->excludes(ow)->group(g);
  auto* ff = c->add_option("--frame-format", a.frame_format,
                           "png8 | png16 | npy (float32 [H,W,3] RGB, not clamped; see docs/reliability.md)  [png8]")
                 ->check(CLI::IsMember({"png8", "png16", "npy"}))->group(g)->type_name("F");
  c->add_option("--bit-depth", a.bit_depth, "8 | 16: same as --frame-format png8 | png16 (kept for older scripts)")
      ->check(CLI::IsMember({"8", "16"}))->excludes(ff)->group(g)->type_name("B");
  c->add_option("--fps", a.fps, "frame rate of gs_video.mp4 (default: 10x slow motion of the recording, 1 to 60)")
      ->check(finite_at_least(0, true) & CLI::Range(0.0, 1000.0))->group(g)->type_name("F");
  c->add_flag("--no-video", a.no_video, "skip gs_video.mp4")->group(g);
  c->add_flag("--quiet", a.quiet, "print nothing but warnings and errors")->group(g);
}

// A live recording (docs/follow.md): events from a pipe, frames as they appear.
void add_follow_options(CLI::App* c, UnrollArgs& a) {
  const std::string g = "Live stream";
  c->add_flag("--follow", a.follow.enabled,
              "live: meta.json lists the frames to come; each GS frame is written as soon as its image exists and the "
              "events have passed its window; ends at the stream's end, after --follow-idle-s, or on SIGINT")->group(g);
  c->add_option("--follow-events", a.follow.events, "EVT 3.0 raw stream: a pipe, a growing file, or - (stdin)")
      ->check(non_empty())->capture_default_str()->group(g)->type_name("FILE");
  c->add_option("--follow-idle-s", a.follow.idle_s, "no new events and no awaited frame for this long: the stream ended (0: never; else 0.1 to 1e6)")
      ->check(finite_at_least(0))->capture_default_str()->group(g)->type_name("S");
  c->add_option("--follow-max-events", a.follow.max_events, "events held at most (the ring of events later frames need)")
      ->check(int_range(1024, int64_t(1) << 34))->capture_default_str()->group(g)->type_name("N");
}

}  // namespace

Command add_unroll(CLI::App& parent) {
  auto a = std::make_shared<UnrollArgs>();
  CLI::App* c = parent.add_subcommand("unroll", "turn a recording (RS frames + events) into GS frames, video and metrics");
  c->description(
      "Turns a recording into global-shutter frames: a file per GS frame (frames/), gs_video.mp4, a contact\n"
      "sheet, metrics.csv and summary.json (PSNR/SSIM where the sequence has ground truth; provenance).");
  c->add_option("SEQUENCE", a->sequence, "a folder: the generic layout (meta.json), Gev-RS, Gev-RS-Real, DRE or Fastec")
      ->required();
  const std::string gi = "Targets";
  auto* times = c->add_option("--times", a->times,
                              "normalized targets per frame: 0 = first row's exposure start, 1 = last row's exposure end; "
                              "ranges start:stop:count, lists -0.25,0.5,1.25; 'gt': exactly the ground-truth instants, "
                              "named after their files")
                    ->capture_default_str()->group(gi)->type_name("LIST");
  c->add_option("--times-us", a->times_us, "absolute targets in microseconds (each goes to the frame that spans it)")
      ->excludes(times)->group(gi)->type_name("LIST");
  c->add_option("--frames", a->frames, "frames to unroll: 'a:b' (inclusive) or a list (default: all)")->group(gi)->type_name("A:B");
  add_model_options(c, *a);
  add_output_options(c, *a);
  add_follow_options(c, *a);
  add_device_options(c, a->device);
  add_sequence_timing(c, a->timing);
  return {c, [a, c] {
            apply_threads(a->device.threads);
            // Options that do not apply are refused, never ignored.
            if (!a->follow.enabled)
              for (const char* f : {"--follow-events", "--follow-idle-s", "--follow-max-events"})
                if (c->count(f)) throw UsageError(std::string(f) + " applies only with --follow");
            const nlohmann::json summary = run_unroll(to_options(*a));
            return summary.contains("follow") ? follow_exit_code(summary["follow"]) : 0;
          }};
}

}  // namespace vkunroll::cli
