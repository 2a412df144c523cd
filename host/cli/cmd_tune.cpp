// vkunroll tune: the conv algorithm tuner (host/model/conv_choice_tune.hpp) on the command line.
#include <cstdio>
#include <memory>
#include <sstream>

#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/cli/exit_codes.hpp"
#include "vkunroll/host/model/conv_choice_tune.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/output_file.hpp"

namespace vkunroll::cli {

namespace {

struct TuneArgs {
  std::string model, sizes = "346x260,640x480", precision = "fp32", modes = "s,m";
  int tile = 32, halo = 32;
  bool no_compare = false;
  TuneOptions options;
  DeviceArgs device;
};

int run_tune(TuneArgs& a) {
  const Weights weights = tune_model_weights(a.model);
  TuneOptions& o = a.options;
  if (a.precision == "all")
    o.precisions = {Precision::fp32, Precision::fp16};
  else
    o.precisions = {parse_precision(a.precision, "precision")};
  std::vector<std::pair<int, int>> frames;
  std::stringstream ss(a.sizes);
  for (std::string item; std::getline(ss, item, ',');) {
    int w = 0, h = 0;
    parse_size(item, "--size", w, h);
    frames.emplace_back(w, h);
  }
  if (frames.empty()) throw UsageError("--size '" + a.sizes + "': expected one or more WIDTHxHEIGHT, e.g. 346x260");
  o.sizes = tune_sizes(frames, a.tile, a.halo);
  o.s = a.modes.find('s') != std::string::npos;
  o.m = a.modes.find('m') != std::string::npos;
  o.compare = !a.no_compare;
  o.device = a.device.device;
  apply_threads(a.device.threads);
  o.report = [](const std::string& line) {  // the command's report is its standard output
    std::printf("%s\n", line.c_str());
    std::fflush(stdout);
  };
  // The table under the output rule (host/unroll/output_paths.hpp), checked before any timing: a table
  // vkunroll wrote is merged and replaced; anything else at its name, or a folder that cannot take
  // it, is refused now with the reason.
  o.check_table = [](const std::string& table) {
    check_output_file_rule(table, output_path("tune.table"), ExistingOutput::overwrite);
    check_output_folder_writable(table, output_path("tune.table").field);
  };
  tune_conv_choices(weights, o);
  return kExitOk;
}

}  // namespace

Command add_tune(CLI::App& parent) {
  auto a = std::make_shared<TuneArgs>();
  TuneOptions& o = a->options;
  CLI::App* c = parent.add_subcommand("tune", "time every conv algorithm per shape on this device, keep the fastest");
  c->description(
      "Runs the model at each --size (S, and M where the model has it, batch 2) and on the sparse tiles\n"
      "(--tile plus --halo on each side, batch 1 and 4), timing every algorithm that applies to each conv\n"
      "shape; the fastest goes into this device's table in the cache directory (conv-choices-<uuid>-<driver>.tsv,\n"
      "beside the pipeline cache), which `unroll --conv-choice auto` reads. The device is warmed first (--warm-ms\n"
      "on the FMA ceiling kernel); each candidate runs once checked, then is timed for at most --candidate-ms\n"
      "or --reps submits; no shape is timed after --budget-s (shared evenly by the precisions). The FMA ceiling\n"
      "is printed beside every shape.\n"
      "Then it times the model with the kernels' heuristic and with the measured choice, side by side.\n"
      "--plan counts the shapes and candidates (nothing timed) and prints the budget arithmetic.");
  c->add_option("--model", a->model, "SelfUnroll weights (safetensors), or 'published': the published configuration "
                "with random weights (the shapes the benches race)")->required()->type_name("FILE");
  c->add_option("--size", a->sizes, "frame sizes, comma-separated")->capture_default_str()->type_name("WxH[,WxH]");
  c->add_option("--modes", a->modes, "s, m or s,m")->check(CLI::IsMember({"s", "m", "s,m", "m,s"}))->capture_default_str()->type_name("M");
  c->add_option("--tile", a->tile, "sparse tile interior to tune for (0: none)")->check(int_range(0, 4096))->capture_default_str()->type_name("N");
  c->add_option("--halo", a->halo, "the tiles' halo")->check(int_range(0, 4096))->capture_default_str()->type_name("N");
  c->add_option("--precision", a->precision, "fp32 | fp16 | all")
      ->check(CLI::IsMember({"fp32", "fp16", "all"}))->capture_default_str()->type_name("P");
  c->add_option("--reps", o.reps, "timed submits per candidate at most (the least counts)")->check(int_range(1, 1000))->capture_default_str()->type_name("N");
  c->add_option("--candidate-ms", o.candidate_ms, "wall ms of timed submits per candidate at most (at least one; 0: --reps)")
      ->check(finite_range(0, 60000))->capture_default_str()->type_name("MS");
  // Bounded: the warm-up is spent in full, so a huge value would hang the tuner.
  c->add_option("--warm-ms", o.warm_ms, "ms of FMA work before the timings, to bring the clocks up (at most a minute)")
      ->check(finite_range(0, 60000))->capture_default_str()->type_name("MS");
  c->add_option("--budget-s", o.budget_s, "no shape is timed after this many seconds (0: no limit); the rest keep the heuristic")
      ->check(finite_at_least(0))->capture_default_str()->type_name("S");
  c->add_flag("--plan", o.plan, "count the conv shapes and candidates, time nothing, write no table");
  c->add_flag("--no-compare", a->no_compare, "skip the model timing with the heuristic against the measured choice");
  add_device_options(c, a->device);
  return {c, [a] { return run_tune(*a); }};
}

}  // namespace vkunroll::cli
