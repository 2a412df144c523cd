#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>

#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/host/sim/recording.hpp"

namespace vkunroll::cli {

namespace {

void parse_size(const std::string& s, int& w, int& h) {
  int a = 0, b = 0;
  char x = 0, extra = 0;
  if (std::sscanf(s.c_str(), "%d%c%d%c", &a, &x, &b, &extra) != 3 || (x != 'x' && x != 'X') || a < 2 || b < 2)
    throw Error("vkunroll simulate: --size '" + s + "': expected WIDTHxHEIGHT, e.g. 346x260");
  w = a;
  h = b;
}

const char* kHelp =
    "usage: vkunroll simulate --out DIR [options]\n\n"
    "Simulates a rolling-shutter camera + event camera looking at a moving scene and writes the generic\n"
    "sequence layout: rs/*.png, gs/*.png (sharp global-shutter truth), events.h5|events.txt, meta.json.\n"
    "The same options and seed give the same bytes. See docs/simulator.md.\n\n"
    "  --out DIR               output folder (created)\n"
    "  --preset NAME           clean | realistic | noisy (event + frame noise model)   [realistic]\n"
    "  --seed S                scene, motion, thresholds and noise                     [1]\n"
    "  --size WxH              sensor size                                             [346x260]\n"
    "  --frames K              RS frames                                               [10]\n"
    "  --gt-per-frame M        ground-truth instants per frame period                  [5]\n"
    "  --fps F                 RS frame rate                                           [20]\n"
    "  --line-delay-us D       row-to-row start delay                                  [100]\n"
    "  --exposure-us E         row exposure                                            [3000]\n"
    "  --readout DIR           top-down | bottom-up                                    [top-down]\n"
    "  --motion NAME           static | pan | accelerate | rotate | zoom | shake | mixed [mixed]\n"
    "  --speed X               multiply all motion speeds                              [1]\n"
    "  --texture NAME|FILE     checkerboard | bars | noise | text | mixed | an image   [mixed]\n"
    "  --sprites N             foreground objects                                      [2]\n"
    "  --flicker-amp A         global flicker depth, 0..1                              [0]\n"
    "  --flicker-hz F          flicker frequency                                       [100]\n"
    "  --events-format FMT     h5 | txt | both                                         [h5]\n"
    "  --bit-depth B           8 | 16                                                  [8]\n"
    "  --gray                  write 1-channel PNGs (default: 3-channel color)\n"
    "  --gamma G               output encoding gamma (textures are linearized with it) [2.2]\n"
    "  --supersample S         anti-aliasing samples per pixel per axis                [1]\n"
    "  --lead-in-us T          events start this long before frame 0                   [10000]\n"
    "  --step-fraction F       adaptive step: max log change per sample / min(C)       [0.5]\n"
    "  event model overrides (default: the preset's values):\n"
    "  --c-on C --c-off C --sigma S --refractory-us R --leak-hz L --shot-hz N --cutoff-hz F --eps E\n"
    "  --full-well E --read-noise R   frame sensor noise overrides\n"
    "  --quiet                 print nothing on success\n";

}  // namespace

int cmd_simulate(const Argv& argv) {
  Args args("simulate", argv,
            {"out", "preset", "seed", "size", "frames", "gt-per-frame", "fps", "line-delay-us", "exposure-us",
             "readout", "motion", "speed", "texture", "sprites", "flicker-amp", "flicker-hz", "events-format",
             "bit-depth", "gamma", "supersample", "lead-in-us", "step-fraction", "c-on", "c-off", "sigma",
             "refractory-us", "leak-hz", "shot-hz", "cutoff-hz", "eps", "full-well", "read-noise"},
            {"gray", "quiet"});
  if (args.help()) {
    std::cout << kHelp;
    return 0;
  }
  if (!args.positionals().empty())
    throw Error("vkunroll simulate: unexpected argument '" + args.positionals()[0] + "' (see vkunroll simulate --help)");
  const std::string out = args.require("out");
  sim::SimulationConfig c = sim::simulation_preset(args.get_or("preset", "realistic"));
  const long long seed = args.integer("seed", 1);
  if (seed < 0) throw Error("vkunroll simulate: --seed must be >= 0");
  c.seed = static_cast<uint64_t>(seed);
  c.events.seed = c.seed;
  if (auto s = args.get("size")) parse_size(*s, c.width, c.height);
  c.frames = static_cast<int>(args.integer("frames", c.frames));
  c.gt_per_frame = static_cast<int>(args.integer("gt-per-frame", c.gt_per_frame));
  c.fps = args.number("fps", c.fps);
  c.line_delay_us = args.number("line-delay-us", c.line_delay_us);
  c.exposure_us = args.number("exposure-us", c.exposure_us);
  c.readout = args.get_or("readout", c.readout);
  c.motion = sim::parse_motion_kind(args.get_or("motion", "mixed"));
  c.speed_scale = args.number("speed", c.speed_scale);
  if (auto t = args.get("texture")) {
    try {
      c.texture = sim::parse_texture_kind(*t);
    } catch (const Error&) {
      // Not a procedural name: an image file.
      if (!std::ifstream(*t))
        throw Error("vkunroll simulate: --texture '" + *t +
                    "' is neither checkerboard, bars, noise, text, mixed nor a readable image file");
      c.texture_file = *t;
    }
  }
  c.sprites = static_cast<int>(args.integer("sprites", c.sprites));
  c.flicker_amplitude = args.number("flicker-amp", c.flicker_amplitude);
  c.flicker_hz = args.number("flicker-hz", c.flicker_hz);
  c.events_format = args.get_or("events-format", c.events_format);
  c.bit_depth = static_cast<int>(args.integer("bit-depth", c.bit_depth));
  c.color = !args.has("gray");
  c.gamma = args.number("gamma", c.gamma);
  c.supersample = static_cast<int>(args.integer("supersample", c.supersample));
  c.lead_in_us = args.number("lead-in-us", c.lead_in_us);
  c.step_fraction = args.number("step-fraction", c.step_fraction);
  c.events.c_on = args.number("c-on", c.events.c_on);
  c.events.c_off = args.number("c-off", c.events.c_off);
  c.events.sigma = args.number("sigma", c.events.sigma);
  c.events.refractory_us = args.number("refractory-us", c.events.refractory_us);
  c.events.leak_hz = args.number("leak-hz", c.events.leak_hz);
  c.events.shot_hz = args.number("shot-hz", c.events.shot_hz);
  c.events.cutoff_hz = args.number("cutoff-hz", c.events.cutoff_hz);
  c.events.eps = args.number("eps", c.events.eps);
  c.frame_noise.full_well_e = args.number("full-well", c.frame_noise.full_well_e);
  c.frame_noise.read_noise = args.number("read-noise", c.frame_noise.read_noise);
  c.validate();

  const auto t0 = std::chrono::steady_clock::now();
  const sim::SimulatedSequence seq = sim::simulate(c);
  const auto t1 = std::chrono::steady_clock::now();
  if (!args.has("quiet")) {
    const auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
    const auto& s = seq.event_stats;
    std::printf("wrote %s: %d RS frames %dx%d, %zu ground-truth frames, %zu events (%llu ON, %llu OFF, %llu shot noise, "
                "%llu dropped by refractory)\n",
                out.c_str(), c.frames, c.width, c.height, seq.gt.size(), seq.events.size(),
                static_cast<unsigned long long>(s.on), static_cast<unsigned long long>(s.off),
                static_cast<unsigned long long>(s.shot), static_cast<unsigned long long>(s.dropped_refractory));
    std::printf("time steps: %llu samples (mean %.1f us, min %.2f us), %llu split, %llu over the limit at the minimum step\n",
                static_cast<unsigned long long>(seq.steps.samples), seq.steps.mean_dt_us, seq.steps.min_dt_us,
                static_cast<unsigned long long>(seq.steps.rejected), static_cast<unsigned long long>(seq.steps.over_limit));
    std::printf("simulate %.0f ms\n", ms(t0, t1));
  }
  sim::write_sequence(c, seq, out);
  if (!args.has("quiet"))
    std::printf("write %.0f ms\n", std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count());
  return 0;
}

}  // namespace vkunroll::cli
