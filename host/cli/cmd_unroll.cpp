// vkunroll unroll: a recording -> GS video (host/unroll/unroll.hpp does the work).
#include <iostream>

#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/unroll/value_list.hpp"

namespace vkunroll::cli {

int cmd_unroll(const Argv& argv) {
  Args args("unroll", argv,
            {"out", "model", "mode", "times", "times-us", "frames", "layout", "events", "line-delay-us", "exposure-us",
             "readout", "t0s-us", "channel-order", "device", "backend", "precision", "contrast", "gamma", "bit-depth",
             "on-bad", "tile", "halo", "sparse", "sparse-threshold"},
            {"quiet", "no-video", "gev-half-row"});
  if (args.help() || args.positionals().empty()) {
    std::cout <<
        "usage: vkunroll unroll SEQUENCE --out DIR [--model M.safetensors] [--mode s|m|choose|physics|auto]\n"
        "                       [--times LIST|gt | --times-us LIST] [--frames A:B] [options]\n\n"
        "Turns a recording into global-shutter frames: a PNG per GS frame (frames/), gs_video.mp4, a contact\n"
        "sheet, metrics.csv and summary.json (PSNR/SSIM where the sequence has ground truth).\n\n"
        "  SEQUENCE             a folder: the generic layout (meta.json), Gev-RS, Gev-RS-Real, DRE or Fastec\n"
        "  --layout L           generic | gev-rs | gev-rs-real | dre | fastec (default: detected)\n"
        "  --model FILE         SelfUnroll weights (safetensors, see tools/convert_checkpoint.py)\n"
        "  --mode M             s | m | physics | auto: M when the next frame exists, else S; physics\n"
        "                       (the weight-free event double integral) when no model is given  [auto]\n"
        "                       choose: per target, S when t* lies in the frame's exposure span, else M\n"
        "  --tile N             run the model on N x N tiles (multiple of 32); 0: 32 when sparse, else whole\n"
        "                       frames when they fit the device's buffers, else the largest tile that fits [0]\n"
        "  --halo N             context pixels around each tile (multiple of 32; see docs/tiling.md);\n"
        "                       -1: 32 when sparse, 64 for dense tiles                             [-1]\n"
        "  --sparse P           off: every tile runs | exact: tiles with no ev1/ev2 event in them or their\n"
        "                       halo keep the RS pixels | fast: also tiles below --sparse-threshold  [exact]\n"
        "  --sparse-threshold X events per pixel (ev1 + ev2 over a tile and its halo) for fast   [0.05]\n"
        "  --times LIST         normalized targets per frame: 0 = first row's exposure start, 1 = last\n"
        "                       row's exposure end; ranges start:stop:count, lists -0.25,0.5,1.25;\n"
        "                       'gt' renders exactly the ground-truth instants, named after their files [0.5]\n"
        "  --times-us LIST      absolute targets in microseconds (each goes to the frame that spans it)\n"
        "  --frames A:B         frames to unroll (inclusive; or a list)                         [all]\n"
        "  --events FILE        override the sequence's event file\n"
        "  --line-delay-us D --exposure-us E --readout top-down|bottom-up --t0s-us LIST   timing overrides\n"
        "  --on-bad P           events breaking a rule: error | drop | sort                    [error]\n"
        "  --channel-order O    rgb | bgr (default: from the model's metadata)\n"
        "  --contrast C         physics: contrast threshold (default: estimated from the sequence)\n"
        "  --gamma G            physics: decode gamma of the frames (default: meta.json source.settings.gamma, else 1)\n"
        "  --device D --backend vulkan|cpu --precision fp32|fp16   where and how to run\n"
        "  --bit-depth 8|16     PNG depth of the GS frames                                      [8]\n"
        "  --no-video           skip gs_video.mp4;  --quiet  print nothing but errors\n";
    return args.help() ? 0 : 2;
  }
  if (args.positionals().size() != 1) throw Error("vkunroll unroll: exactly one SEQUENCE folder expected");
  UnrollOptions o;
  o.sequence = args.positionals()[0];
  o.out_dir = args.require("out");
  o.session.model_path = args.get_or("model", "");
  o.mode = parse_unroll_mode(args.get_or("mode", "auto"), "--mode");
  if (args.has("times") && args.has("times-us")) throw Error("vkunroll unroll: give --times or --times-us, not both");
  o.times = parse_target_times(args.get_or("times", "0.5"), args.get_or("times-us", ""));
  if (auto v = args.get("frames")) o.frames = parse_frame_list(*v, "--frames");
  if (auto v = args.get("channel-order")) o.channel_order = parse_channel_order(*v, "--channel-order");
  o.session.device = args.get_or("device", "");
  o.session.backend = parse_backend_kind(args.get_or("backend", "vulkan"), "--backend");
  o.session.precision = parse_precision(args.get_or("precision", "fp32"), "--precision");
  if (args.has("contrast")) o.contrast = args.number("contrast", 0.2);
  if (args.has("gamma")) o.gamma = args.number("gamma", 1.0);
  o.output.bit_depth = static_cast<int>(args.integer("bit-depth", 8));
  o.tile = args.integer("tile", 0);
  o.halo = args.integer("halo", -1);
  o.sparse = parse_sparse_policy(args.get_or("sparse", "exact"), "--sparse");
  o.sparse_threshold = args.number("sparse-threshold", 0.05);
  o.quiet = args.has("quiet");
  o.output.write_video = !args.has("no-video");
  SequenceOptions& so = o.sequence_options;
  if (auto l = args.get("layout")) so.layout = parse_sequence_layout(*l);
  if (auto v = args.get("line-delay-us")) so.line_delay_us = Rational::parse(*v, "--line-delay-us");
  if (auto v = args.get("exposure-us")) so.exposure_us = Rational::parse(*v, "--exposure-us");
  if (auto v = args.get("readout")) so.readout = parse_readout(*v);
  if (auto v = args.get("t0s-us")) so.t0s_us = parse_value_list(*v, "--t0s-us");
  so.gev_half_row = args.has("gev-half-row");
  if (auto v = args.get("on-bad")) {
    if (*v == "error") so.events.on_bad = BadEventPolicy::error;
    else if (*v == "drop") so.events.on_bad = BadEventPolicy::drop;
    else if (*v == "sort") so.events.on_bad = BadEventPolicy::sort;
    else throw Error("--on-bad '" + *v + "' (expected error, drop or sort)");
  }
  if (auto v = args.get("events")) so.events_file = *v;
  run_unroll(o);
  return 0;
}

}  // namespace vkunroll::cli
