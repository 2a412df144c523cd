#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/output_folder.hpp"

namespace vkunroll::cli {

namespace {

struct SimulateArgs {
  std::string out, preset = "realistic", size, readout, motion = "mixed", texture, events_format;
  long long seed = 1;
  bool gray = false, quiet = false, overwrite = false;
  // Overrides of the preset's values (unset: the preset's).
  std::optional<int> frames, gt_per_frame, sprites, bit_depth, supersample;
  std::optional<double> fps, line_delay_us, exposure_us, speed, flicker_amp, flicker_hz, gamma, lead_in_us, step_fraction,
      c_on, c_off, sigma, refractory_us, leak_hz, shot_hz, cutoff_hz, eps, hot_pixels, hot_hz, jitter_us, full_well,
      read_noise;
};

template <class T>
void set(T& field, const std::optional<T>& v) {
  if (v) field = *v;
}

sim::SimulationConfig to_config(const SimulateArgs& a) {
  sim::SimulationConfig c;
  try {
    c = sim::simulation_preset(a.preset);
    c.motion = sim::parse_motion_kind(a.motion);
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  c.seed = static_cast<uint64_t>(a.seed);
  c.events.seed = c.seed;
  if (!a.size.empty()) parse_size(a.size, "--size", c.width, c.height);
  set(c.frames, a.frames);
  set(c.gt_per_frame, a.gt_per_frame);
  set(c.fps, a.fps);
  set(c.line_delay_us, a.line_delay_us);
  set(c.exposure_us, a.exposure_us);
  if (!a.readout.empty()) c.readout = a.readout;
  set(c.speed_scale, a.speed);
  if (!a.texture.empty()) sim::set_texture(c, a.texture);
  set(c.sprites, a.sprites);
  set(c.flicker_amplitude, a.flicker_amp);
  set(c.flicker_hz, a.flicker_hz);
  if (!a.events_format.empty()) c.events_format = a.events_format;
  set(c.bit_depth, a.bit_depth);
  c.color = !a.gray;
  set(c.gamma, a.gamma);
  set(c.supersample, a.supersample);
  set(c.lead_in_us, a.lead_in_us);
  set(c.step_fraction, a.step_fraction);
  set(c.events.c_on, a.c_on);
  set(c.events.c_off, a.c_off);
  set(c.events.sigma, a.sigma);
  set(c.events.refractory_us, a.refractory_us);
  set(c.events.leak_hz, a.leak_hz);
  set(c.events.shot_hz, a.shot_hz);
  set(c.events.cutoff_hz, a.cutoff_hz);
  set(c.events.eps, a.eps);
  set(c.events.hot_fraction, a.hot_pixels);
  set(c.events.hot_hz, a.hot_hz);
  set(c.events.jitter_us, a.jitter_us);
  set(c.frame_noise.full_well_e, a.full_well);
  set(c.frame_noise.read_noise, a.read_noise);
  try {
    c.validate();
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  return c;
}

int run_simulate(const SimulateArgs& a) {
  const sim::SimulationConfig c = to_config(a);
  // Staged and renamed into place whole: a killed run leaves no sequence, an earlier one is never
  // mixed with this one's files (and replaced only with --overwrite, if it holds only its own).
  OutputFolder folder(a.out, a.overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse, output_path("simulate.out"));
  Stopwatch clock;
  const sim::SimulatedSequence seq = sim::simulate(c);
  const double simulate_ms = clock.ms();
  clock.restart();
  if (!a.quiet) {
    const auto& s = seq.event_stats;
    std::printf("wrote %s: %d RS frames %dx%d, %zu ground-truth frames, %zu events (%llu ON, %llu OFF, %llu shot noise, "
                "%llu dropped by refractory)\n",
                a.out.c_str(), c.frames, c.width, c.height, seq.gt.size(), seq.events.size(),
                static_cast<unsigned long long>(s.on), static_cast<unsigned long long>(s.off),
                static_cast<unsigned long long>(s.shot), static_cast<unsigned long long>(s.dropped_refractory));
    std::printf("time steps: %llu samples (mean %.1f us, min %.2f us), %llu split, %llu over the limit at the minimum step\n",
                static_cast<unsigned long long>(seq.steps.samples), seq.steps.mean_dt_us, seq.steps.min_dt_us,
                static_cast<unsigned long long>(seq.steps.rejected), static_cast<unsigned long long>(seq.steps.over_limit));
    std::printf("simulate %.0f ms\n", simulate_ms);
  }
  try {
    sim::write_sequence(c, seq, folder.staging().string());
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::unspecified) throw;
    throw IoError(e.text());
  }
  folder.commit();
  if (!a.quiet)
    std::printf("write %.0f ms\n", clock.ms());
  return 0;
}

}  // namespace

Command add_simulate(CLI::App& parent) {
  auto a = std::make_shared<SimulateArgs>();
  CLI::App* c = parent.add_subcommand("simulate", "simulate RS frames, GS ground truth and events from a moving scene");
  c->description(
      "Simulates a rolling-shutter camera + event camera looking at a moving scene and writes the generic\n"
      "sequence layout: rs/*.png, gs/*.png (sharp global-shutter truth), events.h5|events.txt, meta.json.\n"
      "The same options and seed give the same bytes. See docs/simulator.md. Unset values: the preset's.");
  add_output_option(c, "simulate.out", a->out)->required();
  c->add_option("--preset", a->preset, "clean | realistic | noisy (event + frame noise model)")
      ->check(CLI::IsMember({"clean", "realistic", "noisy"}))->capture_default_str()->type_name("NAME");
  c->add_option("--seed", a->seed, "scene, motion, thresholds and noise")->check(int_range(0, 1LL << 62))->capture_default_str();
  c->add_option("--size", a->size, "sensor size WxH (default 346x260)")->type_name("WxH");
  c->add_option("--frames", a->frames, "RS frames (default 10)")->check(int_range(1, 100000));
  c->add_option("--gt-per-frame", a->gt_per_frame, "ground-truth instants per frame period (default 5)")->check(int_range(0, 10000));
  c->add_option("--fps", a->fps, "RS frame rate (default 20)")->check(finite_at_least(0, true));
  c->add_option("--line-delay-us", a->line_delay_us, "row-to-row start delay (default 100)")->check(finite_at_least(0));
  c->add_option("--exposure-us", a->exposure_us, "row exposure (default 3000)")->check(finite_at_least(0, true));
  c->add_option("--readout", a->readout, "top-down | bottom-up")->check(CLI::IsMember({"top-down", "bottom-up"}))->type_name("DIR");
  c->add_option("--motion", a->motion, "static | pan | accelerate | rotate | zoom | shake | mixed")
      ->check(CLI::IsMember({"static", "pan", "accelerate", "rotate", "zoom", "shake", "mixed"}))->capture_default_str()->type_name("NAME");
  c->add_option("--speed", a->speed, "multiply all motion speeds (default 1)")->check(finite_at_least(0));
  c->add_option("--texture", a->texture, "checkerboard | bars | noise | text | mixed | an image file (default mixed)")->type_name("NAME|FILE");
  c->add_option("--sprites", a->sprites, "foreground objects (default 2)")->check(int_range(0, 1000));
  c->add_option("--flicker-amp", a->flicker_amp, "global flicker depth, 0..1 (default 0)")->check(finite_at_least(0) & CLI::Range(0.0, 1.0));
  c->add_option("--flicker-hz", a->flicker_hz, "flicker frequency (default 100)")->check(finite_at_least(0));
  c->add_option("--events-format", a->events_format, "h5 | txt | both (default h5)")->check(CLI::IsMember({"h5", "txt", "both"}))->type_name("FMT");
  c->add_option("--bit-depth", a->bit_depth, "8 | 16 (default 8)")->check(CLI::IsMember({8, 16}));
  c->add_flag("--gray", a->gray, "write 1-channel PNGs (default: 3-channel color)");
  c->add_option("--gamma", a->gamma, "output encoding gamma; textures are linearized with it (default 2.2)")->check(finite_at_least(0, true));
  c->add_option("--supersample", a->supersample, "anti-aliasing samples per pixel per axis (default 1)")->check(int_range(1, 16));
  c->add_option("--lead-in-us", a->lead_in_us, "events start this long before frame 0 (default 10000)")->check(finite_at_least(0));
  c->add_option("--step-fraction", a->step_fraction, "adaptive step: max log change per sample / min(C) (default 0.5)")
      ->check(finite_at_least(0, true));
  const std::string g = "Event and frame noise model (default: the preset's)";
  c->add_option("--c-on", a->c_on, "ON contrast threshold")->check(finite_at_least(0, true))->group(g);
  c->add_option("--c-off", a->c_off, "OFF contrast threshold")->check(finite_at_least(0, true))->group(g);
  c->add_option("--sigma", a->sigma, "threshold mismatch (std)")->check(finite_at_least(0))->group(g);
  c->add_option("--refractory-us", a->refractory_us, "refractory period")->check(finite_at_least(0))->group(g);
  c->add_option("--leak-hz", a->leak_hz, "leak event rate")->check(finite_at_least(0))->group(g);
  c->add_option("--shot-hz", a->shot_hz, "shot noise rate")->check(finite_at_least(0))->group(g);
  c->add_option("--cutoff-hz", a->cutoff_hz, "photoreceptor cutoff")->check(finite_at_least(0))->group(g);
  c->add_option("--eps", a->eps, "log offset")->check(finite_at_least(0, true))->group(g);
  c->add_option("--hot-pixels", a->hot_pixels, "fraction of hot pixels, 0..1 (default 0)")->check(finite_at_least(0))->group(g);
  c->add_option("--hot-hz", a->hot_hz, "each hot pixel's event rate (default 0)")->check(finite_at_least(0))->group(g);
  c->add_option("--jitter-us", a->jitter_us, "timestamp jitter (std, default 0)")->check(finite_at_least(0))->group(g);
  c->add_option("--full-well", a->full_well, "frame sensor full well (electrons)")->check(finite_at_least(0, true))->group(g);
  c->add_option("--read-noise", a->read_noise, "frame sensor read noise (std, fraction of full scale)")->check(finite_at_least(0))->group(g);
  c->add_flag("--quiet", a->quiet, "print nothing on success");
  c->add_flag("--overwrite", a->overwrite, "replace an existing sequence in --out (one that vkunroll wrote)");
  return {c, [a] { return run_simulate(*a); }};
}

}  // namespace vkunroll::cli
