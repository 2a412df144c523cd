// vkunroll infer: the network on raw input tensors (rs, ev1, ev2, ev3) from a safetensors file,
// every intermediate written under the reference's names. This is how anyone checks vkunroll
// against a PyTorch run of the same weights.
#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <set>
#include <sstream>

#include "vkunroll/host/model/make_backend.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/output_file.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

HostTensor input_array(const SafetensorsFile& f, const std::string& path, const std::string& name) {
  if (!f.has(name)) throw DataError(path + ": no tensor '" + name + "' (expected rs, ev1, ev2, ev3)");
  const SafetensorsTensor& t = f.get(name);
  if (t.shape.size() != 4) {
    std::ostringstream os;
    for (size_t i = 0; i < t.shape.size(); ++i) os << (i ? "x" : "") << t.shape[i];
    throw DataError(path + ": tensor '" + name + "' has shape " + os.str() + ", expected 4 dimensions (B, C, H, W)");
  }
  if (t.dtype != StDType::F32 && t.dtype != StDType::F16 && t.dtype != StDType::BF16 && t.dtype != StDType::F64)
    throw DataError(path + ": tensor '" + name + "' has dtype " + st_dtype_name(t.dtype) + ", expected a float type");
  return {Shape{t.shape[0], t.shape[1], t.shape[2], t.shape[3]}, t.to_f32()};
}

// --outputs: reference names of ModelOutput, each once; an empty list or name is refused.
std::vector<ModelOutput> requested_outputs(const std::optional<std::string>& list) {
  if (!list) return {};
  const std::string shown = list->size() > 64 ? list->substr(0, 64) + "..." : *list;
  std::vector<ModelOutput> out;
  std::stringstream ss(*list + ",");
  for (std::string item; std::getline(ss, item, ',');) {
    if (item.empty()) throw UsageError("--outputs '" + shown + "': an empty name (expected a comma-separated list of sys, E, flow, warped, fused, m, out)");
    const ModelOutput o = parse_output(item);
    if (std::find(out.begin(), out.end(), o) != out.end()) throw UsageError("--outputs: '" + item + "' is named twice");
    out.push_back(o);
  }
  return out;
}

struct InferArgs {
  std::string model, inputs, out, mode, precision = "fp32", backend = "vulkan";
  std::optional<std::string> outputs;
  int max_items = 0;
  bool overwrite = false;
  DeviceArgs device;
};

int run_infer(const InferArgs& a) {
  const Precision precision = parse_precision(a.precision, "precision");
  if (precision == Precision::fp16 && a.backend != "vulkan") throw fp16_needs_vulkan();  // before the inputs are read
  check_output_file(a.out, "--out");
  check_output_file_rule(a.out, output_path("infer.out"), a.overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse,
                         {{"--inputs file", a.inputs}, {"--model file", a.model}});
  const std::vector<ModelOutput> outputs = requested_outputs(a.outputs);
  std::error_code ec;
  for (const auto& [opt, path] : {std::pair<const char*, std::string>{"--model", a.model}, {"--inputs", a.inputs}})
    if (!std::filesystem::exists(path, ec)) throw InputMissingError(std::string(opt) + " " + path + ": no such file");
  const Weights weights = load_weights(a.model);
  for (const auto& n : weights.notes) std::cerr << "note: " << a.model << ": " << n << "\n";
  const SafetensorsFile in_file = read_safetensors(a.inputs);
  ModelInputs in{input_array(in_file, a.inputs, "rs"), input_array(in_file, a.inputs, "ev1"),
                 input_array(in_file, a.inputs, "ev2"), input_array(in_file, a.inputs, "ev3")};
  // The physics-informed variant also reads the physics estimate; other models refuse it.
  if (weights.config.physics_input) {
    if (!in_file.has("phys"))
      throw DataError(a.inputs + ": tensor 'phys' [B, 3, H, W] is missing: " + a.model + " is the physics-informed variant");
    in.phys = input_array(in_file, a.inputs, "phys");
  } else if (in_file.has("phys")) {
    throw DataError(a.inputs + ": tensor 'phys' is given, but " + a.model + " is not the physics-informed variant");
  }
  std::vector<std::string> ignored;
  for (const auto& n : in_file.names())
    if (n != "rs" && n != "ev1" && n != "ev2" && n != "ev3" && n != "phys") ignored.push_back(n);
  if (!ignored.empty()) {
    std::cerr << "note: " << a.inputs << ": ignoring " << ignored.size() << " other tensor(s):";
    for (const auto& n : ignored) std::cerr << " " << n;
    std::cerr << "\n";
  }

  RunOptions opt;
  const int64_t B = in.rs.shape.n;
  const std::string mode = a.mode.empty() ? (weights.config.moa && B % 2 == 0 ? "m" : "s") : a.mode;
  if (mode == "m" && B % 2) throw UsageError("--mode m needs an even batch (items 2k and 2k+1 are frames 1 and 2), " + a.inputs + " has " + std::to_string(B));
  opt.mode = mode == "m" ? Mode::m : Mode::s;
  opt.outputs = outputs;
  (void)Model::resolve_outputs(outputs, opt.mode);
  opt.max_items = a.max_items;

  const OpenedBackend opened = make_backend({.kind = parse_backend_kind(a.backend, "backend"),
                                             .precision = precision,
                                             .device = a.device.device,
                                             .cpu_threads = a.device.threads});
  const std::unique_ptr<Context>& ctx = opened.context;
  const std::unique_ptr<Backend>& backend = opened.backend;
  Stopwatch clock;
  Model model(*backend, weights);
  const double weights_s = clock.seconds();
  clock.restart();
  const auto out = model.run(in, opt);
  const double run_s = clock.seconds();

  std::map<std::string, const HostTensor*> by_name;  // the file's tensors in name order
  for (const auto& [o, arr] : out) by_name[output_name(o)] = &arr;
  std::vector<SafetensorsTensorRef> views;
  for (const auto& [name, t] : by_name)
    views.push_back({name, StDType::F32, {t->shape.n, t->shape.c, t->shape.h, t->shape.w}, t->data.data(),
                     t->data.size() * sizeof(float)});
  const std::map<std::string, std::string> md{{"mode", mode},
                                              {"precision", precision_name(precision)},
                                              {"backend", backend->name()},
                                              {"device", ctx ? ctx->info().name : "cpu"},
                                              {"model", a.model},
                                              {"config", weights.config.summary()},
                                              {kSafetensorsWrittenBy, std::string(kWrittenByVkunroll) + " infer"}};
  try {
    write_safetensors(a.out, views, md);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::unspecified) throw;
    throw IoError(e.text());
  }
  std::cerr << "infer: SelfUnroll-" << (mode == "m" ? "M" : "S") << " on " << in.rs.shape.str() << " ("
            << weights.config.summary() << ") on " << backend->name() << ": weights "
            << weights_s << " s, run " << run_s
            << " s, peak intermediates " << (backend->peak_bytes() >> 20) << " MiB; wrote " << out.size() << " tensors to "
            << a.out << "\n";
  return 0;
}

}  // namespace

Command add_infer(CLI::App& parent) {
  auto a = std::make_shared<InferArgs>();
  CLI::App* c = parent.add_subcommand("infer", "run SelfUnroll-S/-M on raw input tensors, write every intermediate");
  c->description(
      "Runs SelfUnroll on raw tensors: rs [B,3,H,W], ev1/ev2/ev3 [B,2N,H,W] (F32/F16/BF16), fed as given\n"
      "(images in the model's channel order, see its metadata). --mode m needs B even: items 2k and 2k+1\n"
      "are RS frames 1 and 2 toward target k. Writes every intermediate (sys, E, flow, warped, fused; m and\n"
      "out in mode m) as F32 under the reference's names.");
  c->add_option("--model", a->model, "SelfUnroll weights (safetensors)")->required()->type_name("FILE");
  c->add_option("--inputs", a->inputs, "input tensors rs, ev1, ev2, ev3 (safetensors)")->required()->type_name("FILE");
  add_output_option(c, "infer.out", a->out)->required();
  c->add_flag("--overwrite", a->overwrite, "replace an existing --out file (only one vkunroll wrote)");
  c->add_option("--mode", a->mode, "s | m (default: m when the model has MOA weights and B is even, else s)")
      ->check(CLI::IsMember({"s", "m"}))->type_name("M");
  c->add_option("--backend", a->backend, "vulkan | cpu (the CPU reference, slow)")
      ->check(CLI::IsMember({"vulkan", "cpu"}))->capture_default_str()->type_name("B");
  c->add_option("--precision", a->precision, "fp32 | fp16 (fp16: weights and activations stored in fp16 on the Vulkan backend; outputs are F32)")
      ->check(CLI::IsMember({"fp32", "fp16"}))->capture_default_str()->type_name("P");
  c->add_option("--outputs", a->outputs, "the tensors to write, e.g. sys,E,flow,warped,fused,m,out (default: all)")->check(non_empty())->type_name("LIST");
  c->add_option("--max-items", a->max_items, "batch items run together (0: all)")->check(int_range(0, 1 << 20))->type_name("K");
  add_device_options(c, a->device);
  return {c, [a] {
            apply_threads(a->device.threads);
            return run_infer(*a);
          }};
}

}  // namespace vkunroll::cli
