// SelfUnroll weights: the model configuration and the named float tensors of a weights file
// (safetensors, F32/F16/BF16, configuration in "__metadata__"; see docs/model.md).
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace vkunroll {

struct SafetensorsFile;

struct UnetConfig {
  int base = 32;   // width of the first level; level i has base * 2^i channels
  int depth = 3;   // number of down/up levels
  bool operator==(const UnetConfig&) const = default;
};

// Everything that fixes the tensor shapes and the arithmetic of one SelfUnroll model.
// The largest event gate radius a configuration may state (a (2r+1)^2 box, one conv).
constexpr int kMaxPhysicsGate = 15;

struct ModelConfig {
  int D = 10;            // residual dense blocks
  int C = 5;             // convs per block
  int G = 48;            // growth rate
  int G0 = 96;           // block width
  int N = 16;            // temporal bins; each event tensor has 2N channels
  int upnet_width = 256; // UPNet.0 output channels (depth_to_space(2) -> upnet_width / 4)
  UnetConfig flownet{32, 4}, fusion_net{32, 3}, attfusion_net{32, 3};
  float rdb_slope = 0.01f;  // LeakyReLU slope in the residual dense blocks
  float unet_slope = 0.1f;  // LeakyReLU slope in the UNets
  bool moa = true;          // attfusion_net present: SelfUnroll-M available
  // The physics-informed variant (docs/model.md): E-IC_T also reads the physics unroller's estimate
  // at t* (`phys`, last in its input) and predicts a correction to it: sys = clamp(phys, 0, 1) + E.
  bool physics_input = false;
  // The variant's contrast threshold for `phys`: "estimate" (as --mode physics) or a number.
  std::string physics_contrast = "estimate";
  // The variant's event gate radius r (-1: none): fused = clamp(phys, 0, 1) wherever no event of
  // ev1/ev2 lies within the (2r+1)^2 square around the pixel (there physics is exact but for
  // frame noise, and a small network's correction only adds error).
  int physics_gate = -1;
  // The variant's learned confidence: fusion_net predicts a 4th channel, and inside the gate
  // fused = c * fusion_net + (1 - c) * clamp(phys, 0, 1), c = hardsigmoid(channel 3), so the model
  // itself decides where physics is right (metadata physics_confidence; from fusion_net.pred's shape).
  bool physics_confidence = false;
  // The intensity encoding the model was trained in (PNG value = linear^(1/gamma)); unset: unknown.
  std::optional<double> gamma;
  std::string channel_order = "rgb";  // image channel order the weights expect ("rgb" | "bgr")
  std::string description;

  int ev_channels() const { return 2 * N; }
  int fusion_channels() const { return physics_confidence ? 4 : 3; }  // fusion_net's output
  // E-IC_T's input channels before space_to_depth: rs, ev1, ev2, ev3 (and phys in the variant).
  int synthesis_channels() const { return 3 + 3 * ev_channels() + (physics_input ? 3 : 0); }
  // Each UNet's input channels, its pieces in the order host/model/model.cpp concatenates them.
  int flownet_input_channels() const { return 2 * ev_channels() + 3; }            // ev1, ev2, rs
  int fusion_input_channels() const { return 3 + 3 + 2 + ev_channels() + 3; }     // sys, warped, flow, ev3, rs
  int attfusion_input_channels() const { return 2 * 3 + 2 * ev_channels() + 2 * 2; }  // E, ev1, flow of frames 1 and 2
  // The published models (fast.pth, gev.pth, gevreal.pth, dre.pth): 33,914,185 parameters.
  static ModelConfig published() { return {}; }
  // Strings for the safetensors metadata (keys in docs/model.md).
  std::map<std::string, std::string> to_metadata() const;
  std::string summary() const;  // one line, e.g. "D=10 C=5 G=48 G0=96 N=16 ... moa"
  // Throws Error when a value is out of range (non-positive widths, upnet_width % 4, ...).
  void validate() const;
  bool same_shapes(const ModelConfig& o) const;
};

using TensorShape = std::vector<int64_t>;

// Every tensor the configuration needs, in a fixed order, with its shape (PyTorch layout:
// Conv2d [out, in, k, k], ConvTranspose2d [in, out, k, k], bias [out]).
std::vector<std::pair<std::string, TensorShape>> expected_tensors(const ModelConfig& cfg);
int64_t parameter_count(const ModelConfig& cfg);

// The configuration from tensor shapes alone (slopes, channel order: the published values).
// Throws Error naming the tensor that is missing or has an impossible shape.
ModelConfig infer_config(const std::map<std::string, TensorShape>& shapes);

struct WeightTensor {
  TensorShape shape;
  std::vector<float> data;
};

struct Weights {
  ModelConfig config;
  std::map<std::string, WeightTensor> tensors;
  std::vector<std::string> notes;  // e.g. "no attfusion_net (MOA) weights: SelfUnroll-S only"

  const WeightTensor& get(const std::string& name) const;  // throws Error naming the key
};

// Loads and checks a weights file: configuration from the metadata (checked against the shapes)
// or inferred from the shapes; every expected name present with its exact shape, no unexpected
// name, dtype F32/F16/BF16. Errors name the file and the tensor.
Weights load_weights(const std::string& path);
Weights weights_from_safetensors(const SafetensorsFile& file, const std::string& origin);

// Deterministic random weights (fan-in scaled uniform, activations of order one) for tests and
// benches; the same seed gives the same weights on every platform.
Weights random_weights(const ModelConfig& cfg, uint64_t seed);

// Writes F32 (or F16 when `fp16`) tensors with the configuration metadata.
void save_weights(const std::string& path, const Weights& w, bool fp16 = false);

}  // namespace vkunroll
