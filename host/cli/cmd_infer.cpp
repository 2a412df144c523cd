// vkunroll infer: the network on raw input tensors (rs, ev1, ev2, ev3) from a safetensors file,
// every intermediate written under the reference's names. This is how anyone checks vkunroll
// against a PyTorch run of the same weights.
#include <chrono>
#include <iostream>
#include <memory>
#include <set>
#include <sstream>

#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

HostTensor input_array(const SafetensorsFile& f, const std::string& path, const std::string& name) {
  if (!f.has(name)) throw Error(path + ": no tensor '" + name + "' (expected rs, ev1, ev2, ev3)");
  const SafetensorsTensor& t = f.get(name);
  if (t.shape.size() != 4) {
    std::ostringstream os;
    for (size_t i = 0; i < t.shape.size(); ++i) os << (i ? "x" : "") << t.shape[i];
    throw Error(path + ": tensor '" + name + "' has shape " + os.str() + ", expected 4 dimensions (B, C, H, W)");
  }
  if (t.dtype != StDType::F32 && t.dtype != StDType::F16 && t.dtype != StDType::BF16 && t.dtype != StDType::F64)
    throw Error(path + ": tensor '" + name + "' has dtype " + st_dtype_name(t.dtype) + ", expected a float type");
  return {Shape{t.shape[0], t.shape[1], t.shape[2], t.shape[3]}, t.to_f32()};
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

}  // namespace

int cmd_infer(const Argv& argv) {
  Args args("infer", argv, {"model", "inputs", "out", "mode", "device", "precision", "backend", "outputs", "max-items"});
  if (args.help()) {
    std::cout
        << "usage: vkunroll infer --model M.safetensors --inputs IN.safetensors --out OUT.safetensors\n"
           "                      [--mode s|m] [--backend vulkan|cpu] [--device INDEX|NAME] [--precision fp32]\n"
           "                      [--outputs sys,E,flow,warped,fused,m,out] [--max-items K]\n\n"
           "Runs SelfUnroll on raw tensors: rs [B,3,H,W], ev1/ev2/ev3 [B,2N,H,W] (F32/F16/BF16), fed as given\n"
           "(images in the model's channel order, see its metadata). --mode m needs B even: items 2k and 2k+1\n"
           "are RS frames 1 and 2 toward target k (default: m when the model has MOA weights and B is even,\n"
           "else s). Writes every intermediate (sys, E, flow, warped, fused; m and out in mode m) as F32 under\n"
           "the reference's names. --backend cpu runs the CPU reference (slow); --max-items bounds the batch\n"
           "items run together. fp16 is not available yet (the kernels compute in fp32).\n";
    return 0;
  }
  const std::string model_path = args.require("model"), inputs_path = args.require("inputs"), out_path = args.require("out");
  const std::string precision = args.get_or("precision", "fp32");
  if (precision != "fp32")
    throw Error("--precision '" + precision + "': fp32 is the only precision (there are no fp16 kernels; the " +
                "kernels compute in fp32)");
  const std::string backend_name = args.get_or("backend", "vulkan");
  if (backend_name != "vulkan" && backend_name != "cpu")
    throw Error("--backend '" + backend_name + "' (expected vulkan or cpu)");

  const Weights weights = load_weights(model_path);
  for (const auto& n : weights.notes) std::cerr << "note: " << model_path << ": " << n << "\n";
  const SafetensorsFile in_file = read_safetensors(inputs_path);
  ModelInputs in{input_array(in_file, inputs_path, "rs"), input_array(in_file, inputs_path, "ev1"),
                 input_array(in_file, inputs_path, "ev2"), input_array(in_file, inputs_path, "ev3")};
  // The physics-informed variant also reads the physics estimate; other models refuse it.
  if (weights.config.physics_input) {
    if (!in_file.has("phys"))
      throw Error(inputs_path + ": tensor 'phys' [B, 3, H, W] is missing: " + model_path + " is the physics-informed variant");
    in.phys = input_array(in_file, inputs_path, "phys");
  } else if (in_file.has("phys")) {
    throw Error(inputs_path + ": tensor 'phys' is given, but " + model_path + " is not the physics-informed variant");
  }
  std::vector<std::string> ignored;
  for (const auto& n : in_file.names())
    if (n != "rs" && n != "ev1" && n != "ev2" && n != "ev3" && n != "phys") ignored.push_back(n);
  if (!ignored.empty()) {
    std::cerr << "note: " << inputs_path << ": ignoring " << ignored.size() << " other tensor(s):";
    for (const auto& n : ignored) std::cerr << " " << n;
    std::cerr << "\n";
  }

  RunOptions opt;
  const int64_t B = in.rs.shape.n;
  const std::string mode = args.get_or("mode", weights.config.moa && B % 2 == 0 ? "m" : "s");
  if (mode != "s" && mode != "m") throw Error("--mode '" + mode + "' (expected s or m)");
  opt.mode = mode == "m" ? Mode::m : Mode::s;
  if (auto o = args.get("outputs")) opt.outputs = split(*o);
  opt.max_items = static_cast<int>(args.integer("max-items", 0));

  std::unique_ptr<Context> ctx;
  std::unique_ptr<Backend> backend;
  if (backend_name == "vulkan") {
    ContextOptions co;
    co.device = args.get_or("device", "");
    ctx = std::make_unique<Context>(co);
    backend = std::make_unique<VulkanBackend>(*ctx);
  } else {
    backend = std::make_unique<CpuBackend>();
  }
  const auto t0 = std::chrono::steady_clock::now();
  Model model(*backend, weights);
  const auto t1 = std::chrono::steady_clock::now();
  const auto out = model.run(in, opt);
  const auto t2 = std::chrono::steady_clock::now();

  std::vector<SafetensorsTensorRef> views;
  for (const auto& [name, arr] : out)
    views.push_back({name, StDType::F32, {arr.shape.n, arr.shape.c, arr.shape.h, arr.shape.w}, arr.data.data(),
                     arr.data.size() * sizeof(float)});
  std::map<std::string, std::string> md{{"mode", mode},
                                        {"backend", backend->name()},
                                        {"device", ctx ? ctx->info().name : "cpu"},
                                        {"model", model_path},
                                        {"config", weights.config.summary()}};
  write_safetensors(out_path, views, md);
  std::cerr << "infer: SelfUnroll-" << (mode == "m" ? "M" : "S") << " on " << in.rs.shape.str() << " ("
            << weights.config.summary() << ") on " << backend->name() << ": weights "
            << std::chrono::duration<double>(t1 - t0).count() << " s, run " << std::chrono::duration<double>(t2 - t1).count()
            << " s, peak intermediates " << (backend->peak_bytes() >> 20) << " MiB; wrote " << out.size() << " tensors to "
            << out_path << "\n";
  return 0;
}

}  // namespace vkunroll::cli
