// Simulator cost, measured side by side in one run: what one time sample costs (luminance render,
// color render, event update) and a whole DAVIS346-sized sequence. Ratios tell where time goes.
//   vkunroll-bench-simulator [--size WxH] [--frames K] [--preset NAME] [--reps N]
#include <chrono>
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "bench_args.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/sim/recording.hpp"

using namespace vkunroll::sim;
using vkunroll::Clock;
using vkunroll::ms_since;
// CPU time of the whole process (all threads), ms: robust against a busy shared machine.
static double cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

int main(int argc, char** argv) {
  int w = 346, h = 260, frames = 3, reps = 200;
  std::string preset = "realistic";
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--size")) {
      const BenchSize z = bench_size_arg("vkunroll-bench-simulator", "--size", argv[i + 1], 1, 16384);
      w = static_cast<int>(z.w);
      h = static_cast<int>(z.h);
    } else if (!std::strcmp(argv[i], "--frames")) frames = static_cast<int>(bench_int_arg("vkunroll-bench-simulator", "--frames", argv[i + 1], 1, 100000));
    else if (!std::strcmp(argv[i], "--preset")) preset = argv[i + 1];
    else if (!std::strcmp(argv[i], "--reps")) reps = static_cast<int>(bench_int_arg("vkunroll-bench-simulator", "--reps", argv[i + 1], 1, 1000000));
    else {
      std::fprintf(stderr, "unknown option %s\n", argv[i]);
      return 2;
    }
  }
  SimulationConfig c = simulation_preset(preset);
  c.width = w;
  c.height = h;
  c.frames = frames;

  SceneOptions o;
  o.width = w;
  o.height = h;
  o.duration_us = c.end_us();
  auto t0 = Clock::now();
  Scene scene(build_scene(o));
  const double build_ms = ms_since(t0);

  cv::Mat lum, color;
  double c0 = cpu_ms();
  t0 = Clock::now();
  for (int r = 0; r < reps; ++r) scene.render_luminance(1000.0 + r * 50.0, lum);
  const double lum_ms = ms_since(t0) / reps, lum_cpu = (cpu_ms() - c0) / reps;
  c0 = cpu_ms();
  t0 = Clock::now();
  for (int r = 0; r < reps; ++r) scene.render(1000.0 + r * 50.0, color);
  const double color_ms = ms_since(t0) / reps, color_cpu = (cpu_ms() - c0) / reps;

  std::vector<cv::Mat> lums(reps + 1);
  for (int r = 0; r <= reps; ++r) scene.render_luminance(1000.0 + r * 50.0, lums[r]);
  EventSimulator ev(w, h, c.events);
  ev.reset(1000.0, lums[0]);
  c0 = cpu_ms();
  t0 = Clock::now();
  for (int r = 1; r <= reps; ++r) ev.advance(1000.0 + r * 50.0, lums[r]);
  const double event_ms = ms_since(t0) / reps, event_cpu = (cpu_ms() - c0) / reps;

  c0 = cpu_ms();
  t0 = Clock::now();
  const SimulatedSequence seq = simulate(c);
  const double seq_ms = ms_since(t0), seq_cpu = cpu_ms() - c0;

  std::printf("simulator bench, %dx%d, preset %s\n", w, h, preset.c_str());
  std::printf("  scene build (textures, sprites)   %8.1f ms\n", build_ms);
  std::printf("                                    wall ms     cpu ms   cpu ratio\n");
  std::printf("  luminance render, per sample   %9.3f  %9.3f   1.00\n", lum_ms, lum_cpu);
  std::printf("  color render, per sample       %9.3f  %9.3f   %.2f\n", color_ms, color_cpu, color_cpu / lum_cpu);
  std::printf("  event update, per sample       %9.3f  %9.3f   %.2f   (%zu events)\n", event_ms, event_cpu,
              event_cpu / lum_cpu, ev.events().size());
  const double n = static_cast<double>(seq.steps.samples);
  std::printf("  whole sequence, per sample     %9.3f  %9.3f   %.2f   (%d frames, %.0f samples, %zu events)\n",
              seq_ms / n, seq_cpu / n, seq_cpu / n / lum_cpu, frames, n, seq.events.size());
  std::printf("  whole sequence                 %9.1f  %9.1f\n", seq_ms, seq_cpu);
  return 0;
}
