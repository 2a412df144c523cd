#include "vkunroll/host/model/weights.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <regex>
#include <set>
#include <sstream>

#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {
namespace {

std::string shape_str(const TensorShape& s) {
  std::string r = "[";
  for (size_t i = 0; i < s.size(); ++i) r += (i ? ", " : "") + std::to_string(s[i]);
  return r + "]";
}

void add_conv(std::vector<std::pair<std::string, TensorShape>>& out, const std::string& name, int64_t cin,
              int64_t cout, int64_t k) {
  out.push_back({name + ".weight", {cout, cin, k, k}});
  out.push_back({name + ".bias", {cout}});
}

void add_resblock(std::vector<std::pair<std::string, TensorShape>>& out, const std::string& p, int64_t w) {
  add_conv(out, p + ".conv.0.0", w, w, 3);
  add_conv(out, p + ".conv.1", w, w, 3);
}

void add_unet(std::vector<std::pair<std::string, TensorShape>>& out, const std::string& p, int64_t cin, int64_t cout,
              const UnetConfig& u) {
  add_conv(out, p + ".head", cin, u.base, 3);
  for (int i = 0; i < u.depth; ++i) {
    const int64_t w = int64_t(u.base) << i;
    const std::string d = p + ".down_path." + std::to_string(i);
    add_resblock(out, d + ".conv1", w);
    add_conv(out, d + ".conv2.0", w, w, 1);
    add_conv(out, d + ".down.0", w, 2 * w, 3);
  }
  add_resblock(out, p + ".bottom.0", int64_t(u.base) << u.depth);
  add_resblock(out, p + ".bottom.1", int64_t(u.base) << u.depth);
  for (int i = 0; i < u.depth; ++i) {
    const int64_t w = int64_t(u.base) << i;
    const std::string q = p + ".up_path." + std::to_string(i);
    out.push_back({q + ".deconv.0.weight", {2 * w, w, 4, 4}});  // ConvTranspose2d: [in, out, k, k]
    out.push_back({q + ".deconv.0.bias", {w}});
    add_conv(out, q + ".conv_skip.0", w, w, 1);
    add_conv(out, q + ".conv1.0", 2 * w, w, 3);
    add_resblock(out, q + ".conv2", w);
  }
  add_conv(out, p + ".pred", u.base, cout, 3);
}

int to_int(const std::map<std::string, std::string>& md, const std::string& key, int fallback,
           const std::string& origin) {
  auto it = md.find(key);
  if (it == md.end()) return fallback;
  try {
    size_t pos = 0;
    const long v = std::stol(it->second, &pos);
    if (pos != it->second.size()) throw std::invalid_argument("trailing");
    return static_cast<int>(v);
  } catch (const std::exception&) {
    throw DataError(origin + ": metadata '" + key + "' = '" + it->second + "' is not an integer");
  }
}

float to_float(const std::map<std::string, std::string>& md, const std::string& key, float fallback,
               const std::string& origin) {
  auto it = md.find(key);
  if (it == md.end()) return fallback;
  try {
    size_t pos = 0;
    const float v = std::stof(it->second, &pos);
    if (pos != it->second.size()) throw std::invalid_argument("trailing");
    return v;
  } catch (const std::exception&) {
    throw DataError(origin + ": metadata '" + key + "' = '" + it->second + "' is not a number");
  }
}

// splitmix64: a portable, seedable generator (std distributions differ between libraries).
struct SplitMix {
  uint64_t s;
  uint64_t next() {
    uint64_t z = (s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  float uniform_pm1() { return float(double(next() >> 11) * (2.0 / 9007199254740992.0) - 1.0); }
};

}  // namespace

std::map<std::string, std::string> ModelConfig::to_metadata() const {
  std::map<std::string, std::string> md{
      {"format", "vkunroll-selfunroll"}, {"D", std::to_string(D)}, {"C", std::to_string(C)},
      {"G", std::to_string(G)},          {"G0", std::to_string(G0)}, {"N", std::to_string(N)},
      {"upnet_width", std::to_string(upnet_width)}, {"moa", moa ? "true" : "false"},
      {"channel_order", channel_order},  {"description", description}};
  auto f = [](float v) {
    std::ostringstream os;
    os.precision(9);
    os << v;
    return os.str();
  };
  // Written only when set, so re-saving a published model gives the same metadata.
  if (physics_input) {
    md["physics_input"] = "true";
    md["physics_contrast"] = physics_contrast;
    if (physics_gate >= 0) md["physics_gate"] = std::to_string(physics_gate);
    if (physics_confidence) md["physics_confidence"] = "true";
  }
  if (gamma) md["gamma"] = f(static_cast<float>(*gamma));
  md["rdb_slope"] = f(rdb_slope);
  md["unet_slope"] = f(unet_slope);
  for (auto [name, u] : {std::pair{"flownet", flownet}, {"fusion_net", fusion_net}, {"attfusion_net", attfusion_net}}) {
    md[std::string(name) + ".base"] = std::to_string(u.base);
    md[std::string(name) + ".depth"] = std::to_string(u.depth);
  }
  return md;
}

std::string ModelConfig::summary() const {
  std::ostringstream os;
  os << "D=" << D << " C=" << C << " G=" << G << " G0=" << G0 << " N=" << N << " upnet_width=" << upnet_width
     << " flownet=" << flownet.base << "/" << flownet.depth << " fusion_net=" << fusion_net.base << "/"
     << fusion_net.depth;
  if (moa)
    os << " attfusion_net=" << attfusion_net.base << "/" << attfusion_net.depth;
  else
    os << " (no MOA: SelfUnroll-S only)";
  os << " slopes=" << rdb_slope << "/" << unet_slope << " " << channel_order;
  if (physics_input) os << " physics-informed (contrast " << physics_contrast << ")";
  if (physics_gate >= 0) os << " event gate r=" << physics_gate;
  if (physics_confidence) os << " learned confidence";
  if (gamma) os << " gamma=" << *gamma;
  return os.str();
}

void ModelConfig::validate() const {
  auto pos = [](const char* what, int v) {
    if (v <= 0) throw DataError(std::string("model configuration: ") + what + " = " + std::to_string(v) + " must be positive");
  };
  pos("D", D); pos("C", C); pos("G", G); pos("G0", G0); pos("N", N); pos("upnet_width", upnet_width);
  if (upnet_width % 4) throw DataError("model configuration: upnet_width = " + std::to_string(upnet_width) + " must be a multiple of 4");
  for (auto [name, u] : {std::pair{"flownet", flownet}, {"fusion_net", fusion_net}, {"attfusion_net", attfusion_net}}) {
    if (u.base <= 0 || u.depth <= 0 || u.depth > 5)
      throw DataError(std::string("model configuration: ") + name + " base " + std::to_string(u.base) + " depth " +
                  std::to_string(u.depth) + " (expected base > 0, depth 1..5: the size adapter pads to 32)");
  }
  if (channel_order != "rgb" && channel_order != "bgr")
    throw DataError("model configuration: channel_order '" + channel_order + "' (expected rgb or bgr)");
  if (gamma && !(*gamma > 0 && std::isfinite(*gamma)))
    throw DataError("model configuration: gamma = " + std::to_string(*gamma) + " (expected a positive number)");
  if (physics_gate < -1 || physics_gate > kMaxPhysicsGate)
    throw DataError("model configuration: physics_gate = " + std::to_string(physics_gate) + " (expected -1 for none, or 0.." +
                std::to_string(kMaxPhysicsGate) + ")");
  if (physics_gate >= 0 && !physics_input)
    throw DataError("model configuration: physics_gate = " + std::to_string(physics_gate) +
                " needs the physics-informed variant (physics_input)");
  if (physics_confidence && !physics_input)
    throw DataError("model configuration: physics_confidence needs the physics-informed variant (physics_input)");
  if (physics_input && physics_contrast != "estimate") {
    char* end = nullptr;
    const double c = std::strtod(physics_contrast.c_str(), &end);
    if (end == physics_contrast.c_str() || *end || !(c > 0 && std::isfinite(c)))
      throw DataError("model configuration: physics_contrast '" + physics_contrast + "' (expected 'estimate' or a positive number)");
  }
}

bool ModelConfig::same_shapes(const ModelConfig& o) const {
  return D == o.D && C == o.C && G == o.G && G0 == o.G0 && N == o.N && upnet_width == o.upnet_width &&
         physics_input == o.physics_input && physics_confidence == o.physics_confidence &&
         flownet == o.flownet && fusion_net == o.fusion_net && moa == o.moa && (!moa || attfusion_net == o.attfusion_net);
}

std::vector<std::pair<std::string, TensorShape>> expected_tensors(const ModelConfig& c) {
  std::vector<std::pair<std::string, TensorShape>> out;
  add_conv(out, "SFENet1", 4 * c.synthesis_channels(), c.G0, 5);
  add_conv(out, "SFENet2", c.G0, c.G0, 3);
  for (int d = 0; d < c.D; ++d) {
    const std::string p = "RDBs." + std::to_string(d);
    for (int k = 0; k < c.C; ++k) add_conv(out, p + ".convs." + std::to_string(k) + ".conv.0", c.G0 + k * c.G, c.G, 3);
    add_conv(out, p + ".LFF", c.G0 + c.C * c.G, c.G0, 1);
  }
  add_conv(out, "GFF.0", int64_t(c.D) * c.G0, c.G0, 1);
  add_conv(out, "GFF.1", c.G0, c.G0, 3);
  add_conv(out, "UPNet.0", c.G0, c.upnet_width, 3);
  add_conv(out, "UPNet.2", c.upnet_width / 4, 3, 3);
  add_unet(out, "flownet", c.flownet_input_channels(), 2, c.flownet);
  add_unet(out, "fusion_net", c.fusion_input_channels(), c.fusion_channels(), c.fusion_net);
  if (c.moa) add_unet(out, "attfusion_net", c.attfusion_input_channels(), 1, c.attfusion_net);
  return out;
}

int64_t parameter_count(const ModelConfig& cfg) {
  int64_t n = 0;
  for (const auto& [name, shape] : expected_tensors(cfg)) {
    int64_t k = 1;
    for (auto s : shape) k *= s;
    n += k;
  }
  return n;
}

ModelConfig infer_config(const std::map<std::string, TensorShape>& shapes) {
  auto need = [&](const std::string& key, size_t rank) -> const TensorShape& {
    auto it = shapes.find(key);
    if (it == shapes.end()) throw DataError("cannot infer the model configuration: tensor '" + key + "' is missing");
    if (it->second.size() != rank)
      throw DataError("cannot infer the model configuration: tensor '" + key + "' has shape " + shape_str(it->second) +
                  ", expected rank " + std::to_string(rank));
    return it->second;
  };
  auto count = [&](const std::regex& re) {
    std::set<std::string> ids;
    std::smatch m;
    for (const auto& [k, s] : shapes)
      if (std::regex_match(k, m, re)) ids.insert(m[1]);
    return static_cast<int>(ids.size());
  };
  ModelConfig c;
  const auto& sfe = need("SFENet1.weight", 4);
  c.G0 = static_cast<int>(sfe[0]);
  // 4 * (3 + 6N) input channels for the family (an odd multiple of 4), 4 * (6 + 6N) for the
  // physics-informed variant (an even one).
  const int64_t per = sfe[1] / 4;
  c.physics_input = per % 2 == 0;
  const int64_t fixed = c.physics_input ? 6 : 3;
  if (sfe[1] % 4 || per <= fixed || (per - fixed) % 6)
    throw DataError("cannot infer the model configuration: SFENet1.weight has " + std::to_string(sfe[1]) +
                " input channels, expected 4 * (3 + 6N) (or 4 * (6 + 6N) for the physics-informed variant)");
  c.N = static_cast<int>((per - fixed) / 6);
  c.D = count(std::regex(R"(RDBs\.(\d+)\.LFF\.weight)"));
  c.C = count(std::regex(R"(RDBs\.0\.convs\.(\d+)\.conv\.0\.weight)"));
  c.G = static_cast<int>(need("RDBs.0.convs.0.conv.0.weight", 4)[0]);
  c.upnet_width = static_cast<int>(need("UPNet.0.weight", 4)[0]);
  for (auto [name, u] : {std::pair{"flownet", &c.flownet}, {"fusion_net", &c.fusion_net}, {"attfusion_net", &c.attfusion_net}}) {
    const std::string head = std::string(name) + ".head.weight";
    if (!shapes.count(head) && std::string(name) == "attfusion_net") {
      bool any = false;
      for (const auto& [k, s] : shapes) any = any || k.rfind("attfusion_net.", 0) == 0;
      if (!any) {
        c.moa = false;
        continue;
      }
    }
    u->base = static_cast<int>(need(head, 4)[0]);
    u->depth = count(std::regex(std::string(name) + R"(\.down_path\.(\d+)\.down\.0\.weight)"));
  }
  // fusion_net.pred: 3 output channels, or 4 with the variant's learned confidence.
  const auto& pred = need("fusion_net.pred.weight", 4);
  if (pred[0] != 3 && pred[0] != 4)
    throw DataError("cannot infer the model configuration: fusion_net.pred.weight has " + std::to_string(pred[0]) +
                " output channels, expected 3 (or 4: the physics-informed variant's learned confidence)");
  c.physics_confidence = pred[0] == 4;
  c.validate();
  return c;
}

const WeightTensor& Weights::get(const std::string& name) const {
  auto it = tensors.find(name);
  if (it == tensors.end()) throw DataError("weights: no tensor '" + name + "'");
  return it->second;
}

namespace {

using Metadata = std::map<std::string, std::string>;

// The configuration the metadata states (authoritative for what shapes cannot tell), checked
// against the one the shapes imply.
ModelConfig config_from_metadata(const Metadata& md, const std::map<std::string, TensorShape>& shapes, const ModelConfig& inferred,
                                 const std::string& origin) {
  ModelConfig m;
  m.D = to_int(md, "D", m.D, origin);
  m.C = to_int(md, "C", m.C, origin);
  m.G = to_int(md, "G", m.G, origin);
  m.G0 = to_int(md, "G0", m.G0, origin);
  m.N = to_int(md, "N", m.N, origin);
  m.upnet_width = to_int(md, "upnet_width", m.upnet_width, origin);
  for (auto [name, u] : {std::pair{"flownet", &m.flownet}, {"fusion_net", &m.fusion_net}, {"attfusion_net", &m.attfusion_net}}) {
    u->base = to_int(md, std::string(name) + ".base", u->base, origin);
    u->depth = to_int(md, std::string(name) + ".depth", u->depth, origin);
  }
  m.moa = md.count("moa") ? md.at("moa") == "true" : inferred.moa;
  m.physics_input = inferred.physics_input;
  if (md.count("physics_input")) {
    const std::string& v = md.at("physics_input");
    if (v != "true" && v != "false") throw DataError(origin + ": metadata 'physics_input' = '" + v + "' (expected true or false)");
    if ((v == "true") != inferred.physics_input)
      throw DataError(origin + ": metadata says physics_input=" + v + " but SFENet1.weight has " +
                  std::to_string(shapes.at("SFENet1.weight")[1]) + " input channels (" +
                  (inferred.physics_input ? "the physics-informed variant's" : "the family's") + ")");
  }
  m.physics_confidence = inferred.physics_confidence;
  if (md.count("physics_confidence") && md.at("physics_confidence") != (inferred.physics_confidence ? "true" : "false"))
    throw DataError(origin + ": metadata 'physics_confidence' = '" + md.at("physics_confidence") + "' but fusion_net.pred.weight has " +
                std::to_string(shapes.at("fusion_net.pred.weight")[0]) + " output channels (4: confidence, 3: none)");
  if (md.count("moa") && md.at("moa") != "true" && md.at("moa") != "false")
    throw DataError(origin + ": metadata 'moa' = '" + md.at("moa") + "' (expected true or false)");
  if (!m.same_shapes(inferred)) {
    if (m.moa && !inferred.moa)
      throw DataError(origin + ": metadata says moa=true but the file has no attfusion_net tensors (missing key "
                  "'attfusion_net.head.weight')");
    throw DataError(origin + ": the metadata configuration (" + m.summary() + ") disagrees with the tensor shapes (" +
                inferred.summary() + ")");
  }
  return m;
}

// What only the metadata tells: slopes, channel order, description, the variant's gate and gamma.
void apply_metadata_settings(const Metadata& md, ModelConfig& config, const std::string& origin) {
  config.rdb_slope = to_float(md, "rdb_slope", config.rdb_slope, origin);
  config.unet_slope = to_float(md, "unet_slope", config.unet_slope, origin);
  if (md.count("channel_order")) config.channel_order = md.at("channel_order");
  if (md.count("description")) config.description = md.at("description");
  if (md.count("physics_contrast")) config.physics_contrast = md.at("physics_contrast");
  if (md.count("physics_gate")) {
    const std::string& g = md.at("physics_gate");
    char* end = nullptr;
    const long v = std::strtol(g.c_str(), &end, 10);
    if (end == g.c_str() || *end || v < -1 || v > kMaxPhysicsGate)
      throw DataError(origin + ": metadata 'physics_gate' = '" + g + "' (expected an integer radius 0.." +
                  std::to_string(kMaxPhysicsGate) + ", or -1 for no gate)");
    config.physics_gate = static_cast<int>(v);
  }
  if (md.count("gamma")) {
    const std::string& g = md.at("gamma");
    char* end = nullptr;
    const double v = std::strtod(g.c_str(), &end);
    if (end == g.c_str() || *end) throw DataError(origin + ": metadata 'gamma' = '" + g + "' (expected a positive number)");
    config.gamma = v;
  }
}

// Exactly the configuration's tensors, each of its shape, a float dtype and finite values.
void load_expected_tensors(const SafetensorsFile& file, Weights& w, const std::string& origin) {
  const auto expected = expected_tensors(w.config);
  std::set<std::string> expected_names;
  for (const auto& [name, shape] : expected) expected_names.insert(name);
  std::vector<std::string> unexpected;
  for (const auto& t : file.tensors)
    if (!expected_names.count(t.name)) unexpected.push_back(t.name);
  if (!unexpected.empty()) {
    std::string list;
    for (size_t i = 0; i < unexpected.size() && i < 8; ++i) list += (i ? ", " : "") + unexpected[i];
    throw DataError(origin + ": " + std::to_string(unexpected.size()) + " unexpected tensor(s) for configuration " +
                w.config.summary() + ": " + list + (unexpected.size() > 8 ? ", ..." : ""));
  }
  for (const auto& [name, shape] : expected) {
    if (!file.has(name))
      throw DataError(origin + ": missing tensor '" + name + "' (shape " + shape_str(shape) + ") for configuration " +
                  w.config.summary());
    const SafetensorsTensor& t = file.get(name);
    if (t.shape != shape)
      throw DataError(origin + ": tensor '" + name + "' has shape " + shape_str(t.shape) + ", expected " + shape_str(shape));
    if (t.dtype != StDType::F32 && t.dtype != StDType::F16 && t.dtype != StDType::BF16)
      throw DataError(origin + ": tensor '" + name + "' has dtype " + st_dtype_name(t.dtype) + ", expected F32, F16 or BF16");
    WeightTensor wt{t.shape, t.to_f32()};
    for (float v : wt.data)
      if (!std::isfinite(v)) throw DataError(origin + ": tensor '" + name + "' holds a non-finite value");
    w.tensors.emplace(name, std::move(wt));
  }
}

}  // namespace

Weights weights_from_safetensors(const SafetensorsFile& file, const std::string& origin) {
  std::map<std::string, TensorShape> shapes;
  for (const auto& t : file.tensors) shapes[t.name] = t.shape;
  Weights w;
  const auto& md = file.metadata;
  try {
    w.config = infer_config(shapes);
  } catch (const Error& e) {
    throw Error(origin + ": " + e.text(), e.kind());
  }
  if (md.count("D") || md.count("G0")) w.config = config_from_metadata(md, shapes, w.config, origin);
  apply_metadata_settings(md, w.config, origin);
  try {
    w.config.validate();
  } catch (const Error& e) {
    throw Error(origin + ": " + e.text(), e.kind());
  }
  load_expected_tensors(file, w, origin);
  if (!w.config.moa) w.notes.push_back("no attfusion_net (MOA) weights: SelfUnroll-S only");
  return w;
}

Weights load_weights(const std::string& path) { return weights_from_safetensors(read_safetensors(path), path); }

Weights random_weights(const ModelConfig& cfg, uint64_t seed) {
  cfg.validate();
  Weights w;
  w.config = cfg;
  SplitMix rng{seed};
  for (const auto& [name, shape] : expected_tensors(cfg)) {
    int64_t n = 1;
    for (auto s : shape) n *= s;
    WeightTensor t{shape, std::vector<float>(static_cast<size_t>(n))};
    if (shape.size() == 4) {
      double fan_in = double(shape[1]) * shape[2] * shape[3];
      if (name.find(".deconv.") != std::string::npos) fan_in = double(shape[0]) * shape[2] * shape[3] / 4;
      const float bound = static_cast<float>(std::sqrt(3.0 / fan_in));
      for (auto& v : t.data) v = rng.uniform_pm1() * bound;
    } else {
      for (auto& v : t.data) v = rng.uniform_pm1() * 0.05f;
    }
    w.tensors.emplace(name, std::move(t));
  }
  return w;
}

void save_weights(const std::string& path, const Weights& w, bool fp16) {
  std::vector<SafetensorsTensor> ts;
  for (const auto& [name, shape] : expected_tensors(w.config)) {
    const WeightTensor& src = w.get(name);
    SafetensorsTensor t;
    t.name = name;
    t.shape = src.shape;
    if (!fp16) {
      t.dtype = StDType::F32;
      t.data.resize(src.data.size() * 4);
      std::memcpy(t.data.data(), src.data.data(), t.data.size());
    } else {
      t.dtype = StDType::F16;
      t.data.resize(src.data.size() * 2);
      for (size_t i = 0; i < src.data.size(); ++i) {
        // round to nearest even via the float -> half bit manipulation on normal values
        const uint32_t b = std::bit_cast<uint32_t>(src.data[i]);
        const uint32_t sign = (b >> 16) & 0x8000u;
        const int exp = int((b >> 23) & 0xff) - 127 + 15;
        uint32_t man = b & 0x7fffffu;
        uint16_t h;
        if (exp <= 0) {
          // subnormal half: multiples of 2^-24
          h = static_cast<uint16_t>(sign | uint32_t(std::nearbyint(std::fabs(src.data[i]) * 16777216.0f)));
        } else if (exp >= 31) {
          throw DataError("save_weights: " + name + " overflows fp16");
        } else {
          uint32_t r = (uint32_t(exp) << 10) | (man >> 13);
          const uint32_t rest = man & 0x1fffu;
          if (rest > 0x1000u || (rest == 0x1000u && (r & 1u))) ++r;
          h = static_cast<uint16_t>(sign | r);
        }
        std::memcpy(t.data.data() + 2 * i, &h, 2);
      }
    }
    ts.push_back(std::move(t));
  }
  write_safetensors(path, ts, w.config.to_metadata());
}

}  // namespace vkunroll
