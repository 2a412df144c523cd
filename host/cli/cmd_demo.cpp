// vkunroll demo: simulate a built-in scene and unroll it with the default model and with the
// physics unroller (the baseline every model must beat), and print both against the truth.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/output_folder.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/unroll.hpp"

namespace vkunroll::cli {

namespace fs = std::filesystem;

namespace {
void print_result(const char* what, const nlohmann::json& s) {
  std::cout << std::fixed << std::setprecision(2);
  std::string label = what;
  label.resize(std::max<size_t>(label.size() + 2, 36), ' ');
  std::cout << "  " << label;
  if (s.contains("metrics"))
    std::cout << "PSNR " << s["metrics"]["mean_psnr"].get<double>() << " dB  SSIM " << std::setprecision(4)
              << s["metrics"]["mean_ssim"].get<double>() << std::setprecision(2) << "  ";
  std::cout << s["ms_per_gs_frame_total"].get<double>() << " ms per GS frame\n";
}


struct DemoArgs {
  std::string out = "vkunroll-demo", model, size = "160x120", texture;
  int frames = 4;
  long long seed = 2024;
  bool physics_only = false;
  DeviceArgs device;
};

int run_demo(const DemoArgs& a) {
  const fs::path out = a.out;
  check_output_folder(a.out, "--out");  // it holds sequence/, physics/ and model/
  std::error_code ec;
  if (fs::is_symlink(fs::symlink_status(out, ec)))  // the output rule: never over, nor through, a link
    throw UsageError("--out " + a.out + ": is a symbolic link; name the folder itself");
  sim::SimulationConfig cfg = sim::simulation_preset("realistic");
  cfg.seed = static_cast<uint64_t>(a.seed);
  char x = 0, extra = 0;
  if (std::sscanf(a.size.c_str(), "%d%c%d%c", &cfg.width, &x, &cfg.height, &extra) != 3 || x != 'x' || cfg.width < 16 ||
      cfg.height < 16 || cfg.width > 4096 || cfg.height > 4096)
    throw UsageError("--size '" + a.size + "': expected WxH, each 16 to 4096, e.g. 160x120");
  cfg.frames = a.frames;
  cfg.gt_per_frame = 3;
  cfg.line_delay_us = 25900.0 / cfg.height;  // the same 25.9 ms readout as the 260-row default
  if (!a.texture.empty()) sim::set_texture(cfg, a.texture);
  try {
    cfg.validate();
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  // All three outputs are checked before any is written: one that holds what vkunroll did not write
  // refuses the demo with nothing new beside it (the checks take and release each lock).
  const ModelChoice choice = choose_model(a.physics_only ? UnrollMode::physics : UnrollMode::automatic, a.model);
  for (const char* sub : {"sequence", "physics", "model"})
    if (std::string(sub) != "model" || !choice.path.empty())
      OutputFolder(out / sub, ExistingOutput::overwrite, output_path("demo.out"),
                   std::string(sub) == "sequence" ? &sequence_output_layout() : &unroll_output_layout());
  const Stopwatch simulating;
  const auto seq = sim::simulate(cfg);
  try {
    // The demo's own earlier sequence is replaced whole, never mixed with this one's files.
    OutputFolder folder(out / "sequence", ExistingOutput::overwrite, output_path("demo.out"), &sequence_output_layout());
    sim::write_sequence(cfg, seq, folder.staging().string());
    folder.commit();
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::unspecified) throw;
    throw IoError(e.text());
  }
  const double sim_s = simulating.seconds();
  std::cout << "demo: simulated " << cfg.frames << " RS frames at " << cfg.width << "x" << cfg.height << " with "
            << seq.events.size() << " events (preset realistic, seed " << cfg.seed << ") in " << std::setprecision(3)
            << sim_s << " s -> " << (out / "sequence").string() << "\n";

  UnrollOptions o;
  o.sequence = (out / "sequence").string();
  o.times = {TargetTimes::Kind::ground_truth, {}};
  o.session.device = a.device.device;
  o.session.cpu_threads = a.device.threads;
  o.quiet = true;
  o.out_dir = (out / "physics").string();
  o.mode = UnrollMode::physics;
  o.output.existing = ExistingOutput::overwrite;  // the demo's own folders from an earlier demo
  o.command_line = command_line();
  o.option_spelling = flag_for;
  const nlohmann::json phys = run_unroll(o);
  nlohmann::json learned;
  const std::string& model = choice.path;
  if (!model.empty()) {
    o.session.model_path = model;
    o.model_source = choice.source;
    o.mode = UnrollMode::automatic;
    o.out_dir = (out / "model").string();
    learned = run_unroll(o);
  }
  std::cout << "demo: " << phys["targets"].get<int>() << " GS frames at the ground-truth instants (inside and between frames)\n";
  std::cout << std::fixed << std::setprecision(2) << "  " << std::left << std::setw(36) << "RS input"
            << "PSNR " << phys["metrics"]["rs_mean_psnr"].get<double>() << " dB  SSIM " << std::setprecision(4)
            << phys["metrics"]["rs_mean_ssim"].get<double>() << "\n";
  print_result("physics unroller", phys);
  if (!learned.is_null()) {
    print_result(("model (" + learned["mode"].get<std::string>() + ")").c_str(), learned);
    const double gain = learned["metrics"]["mean_psnr"].get<double>() - phys["metrics"]["mean_psnr"].get<double>();
    std::cout << "demo: the model is " << std::showpos << gain << std::noshowpos << " dB PSNR against physics\n"
              << "demo: model " << model << " (" << spell_fields(choice.source, flag_for) << "), sha256 " << learned["model"]["sha256"].get<std::string>()
              << "\n";
  }
  std::cout << "demo: outputs in " << fs::absolute(out).string() << " (physics/"
            << (learned.is_null() ? "" : ", model/") << ": frames/, gs_video.mp4, contact_sheet.png, summary.json)\n";
  return 0;
}

}  // namespace

Command add_demo(CLI::App& parent) {
  auto a = std::make_shared<DemoArgs>();
  CLI::App* c = parent.add_subcommand("demo", "simulate a built-in scene and unroll it (the default model and physics)");
  c->description(
      "Simulates a built-in scene (deterministic; realistic event noise) with ground truth, unrolls it with\n"
      "the default model (or --model, or VKUNROLL_MODEL) and with the weight-free\n"
      "physics unroller, and prints where the outputs are and their PSNR/SSIM against the truth, beside\n"
      "the RS input's. Earlier demo outputs in --out are replaced.");
  add_output_option(c, "demo.out", a->out)->capture_default_str();
  c->add_option("--model", a->model, "weights to run instead of the default model")->type_name("FILE");
  c->add_option("--texture", a->texture, "the scene's background: mixed (default), checkerboard, bars, noise, text or an image file (a photograph)")
      ->type_name("NAME|FILE");
  c->add_option("--size", a->size, "sensor size")->capture_default_str()->type_name("WxH");
  c->add_option("--frames", a->frames, "RS frames")->check(int_range(2, 1000))->capture_default_str()->type_name("K");
  c->add_option("--seed", a->seed, "scene seed")->check(int_range(0, 1LL << 62))->capture_default_str()->type_name("S");
  c->add_flag("--physics-only", a->physics_only, "run only the physics unroller");
  add_device_options(c, a->device);
  return {c, [a] {
            apply_threads(a->device.threads);
            return run_demo(*a);
          }};
}

}  // namespace vkunroll::cli
