// The weights loader: configuration from metadata or shapes, and a clear error for every kind of
// broken file (missing / unexpected key, wrong shape, bad dtype, truncated file, lying header).
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>

#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/base/error.hpp"

using namespace vkunroll;

namespace {

std::string fixture(const std::string& name) { return std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/" + name; }

ModelConfig tiny() {
  ModelConfig c;
  c.D = 2; c.C = 2; c.G = 8; c.G0 = 16; c.N = 4; c.upnet_width = 32;
  c.flownet = {4, 4}; c.fusion_net = {4, 3}; c.attfusion_net = {8, 2};
  return c;
}

// The tensors of `w` as views, with metadata, serialized in memory.
std::vector<uint8_t> serialize(const Weights& w, std::map<std::string, std::string> md,
                               const std::function<bool(const std::string&)>& keep = nullptr,
                               std::vector<SafetensorsTensorRef> extra = {}) {
  std::vector<SafetensorsTensorRef> views;
  for (const auto& [name, t] : w.tensors) {
    if (keep && !keep(name)) continue;
    views.push_back({name, StDType::F32, t.shape, t.data.data(), t.data.size() * 4});
  }
  for (auto& e : extra) views.push_back(e);
  return serialize_safetensors(views, md);
}

std::string error_of(const std::vector<uint8_t>& bytes) {
  try {
    weights_from_safetensors(parse_safetensors(bytes, "w.safetensors"), "w.safetensors");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Weights, PublishedConfigurationHasThePaperParameterCount) {
  EXPECT_EQ(parameter_count(ModelConfig::published()), 33914185);
  ModelConfig s = ModelConfig::published();
  s.moa = false;
  EXPECT_LT(parameter_count(s), 33914185);
}

TEST(Weights, LoadsTheGoldenFixtureWithItsMetadata) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  EXPECT_TRUE(w.config.same_shapes(tiny())) << w.config.summary();
  EXPECT_FLOAT_EQ(w.config.rdb_slope, 0.01f);
  EXPECT_FLOAT_EQ(w.config.unet_slope, 0.1f);
  EXPECT_EQ(w.config.channel_order, "rgb");
  EXPECT_EQ(w.tensors.size(), expected_tensors(tiny()).size());
  EXPECT_EQ(w.get("flownet.up_path.3.deconv.0.weight").shape, (TensorShape{64, 32, 4, 4}));
  EXPECT_TRUE(w.notes.empty());
}

TEST(Weights, InfersTheConfigurationWithoutMetadata) {
  const Weights r = random_weights(tiny(), 5);
  const Weights w = weights_from_safetensors(parse_safetensors(serialize(r, {}), "x"), "x");
  EXPECT_TRUE(w.config.same_shapes(tiny())) << w.config.summary();
  EXPECT_EQ(w.get("GFF.1.bias").data, r.get("GFF.1.bias").data);
}

TEST(Weights, WithoutMoaRunsSOnlyAndSaysSo) {
  const Weights r = random_weights(tiny(), 5);
  const auto bytes = serialize(r, {}, [](const std::string& n) { return n.rfind("attfusion_net.", 0) != 0; });
  const Weights w = weights_from_safetensors(parse_safetensors(bytes, "x"), "x");
  EXPECT_FALSE(w.config.moa);
  ASSERT_EQ(w.notes.size(), 1u);
  EXPECT_NE(w.notes[0].find("SelfUnroll-S only"), std::string::npos);
  // metadata claiming MOA without its tensors is an error
  auto md = tiny().to_metadata();
  EXPECT_NE(error_of(serialize(r, md, [](const std::string& n) { return n.rfind("attfusion_net.", 0) != 0; }))
                .find("attfusion_net.head.weight"),
            std::string::npos);
}

TEST(Weights, MissingKeyIsNamed) {
  const Weights r = random_weights(tiny(), 5);
  const std::string e = error_of(serialize(r, tiny().to_metadata(), [](const std::string& n) {
    return n != "fusion_net.up_path.1.conv_skip.0.bias";
  }));
  EXPECT_NE(e.find("missing tensor 'fusion_net.up_path.1.conv_skip.0.bias'"), std::string::npos) << e;
  EXPECT_NE(e.find("w.safetensors"), std::string::npos) << e;
}

TEST(Weights, UnexpectedKeyIsNamed) {
  const Weights r = random_weights(tiny(), 5);
  const float v[2] = {1, 2};
  const std::string e = error_of(serialize(r, tiny().to_metadata(), nullptr, {{"RDBs.0.extra", StDType::F32, {2}, v, 8}}));
  EXPECT_NE(e.find("unexpected"), std::string::npos) << e;
  EXPECT_NE(e.find("RDBs.0.extra"), std::string::npos) << e;
}

TEST(Weights, WrongShapeIsNamed) {
  Weights r = random_weights(tiny(), 5);
  r.tensors["UPNet.2.weight"].shape = {3, 8, 3, 2};
  r.tensors["UPNet.2.weight"].data.resize(3 * 8 * 3 * 2);
  const std::string e = error_of(serialize(r, tiny().to_metadata()));
  EXPECT_NE(e.find("'UPNet.2.weight' has shape [3, 8, 3, 2], expected [3, 8, 3, 3]"), std::string::npos) << e;
}

TEST(Weights, WrongDtypeIsNamed) {
  Weights r = random_weights(tiny(), 5);
  std::vector<SafetensorsTensorRef> views;
  std::vector<int32_t> ints(16, 1);
  for (const auto& [name, t] : r.tensors) {
    if (name == "SFENet2.bias")
      views.push_back({name, StDType::I32, t.shape, ints.data(), 64});
    else
      views.push_back({name, StDType::F32, t.shape, t.data.data(), t.data.size() * 4});
  }
  const std::string e = error_of(serialize_safetensors(views, tiny().to_metadata()));
  EXPECT_NE(e.find("'SFENet2.bias' has dtype I32"), std::string::npos) << e;
}

TEST(Weights, MetadataDisagreeingWithShapesIsAnError) {
  const Weights r = random_weights(tiny(), 5);
  auto md = tiny().to_metadata();
  md["G"] = "12";
  const std::string e = error_of(serialize(r, md));
  EXPECT_NE(e.find("disagrees with the tensor shapes"), std::string::npos) << e;
  md = tiny().to_metadata();
  md["N"] = "four";
  EXPECT_NE(error_of(serialize(r, md)).find("'N' = 'four' is not an integer"), std::string::npos);
}

TEST(Weights, TruncatedAndLyingFilesFailClearly) {
  const Weights r = random_weights(tiny(), 5);
  auto bytes = serialize(r, tiny().to_metadata());
  const auto dir = std::filesystem::temp_directory_path() / "vkunroll_test_weights";
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "trunc.safetensors").string();
  {
    std::ofstream f(path, std::ios::binary);
    f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size() - 100));
  }
  try {
    load_weights(path);
    FAIL() << "a truncated file loaded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("trunc.safetensors"), std::string::npos) << e.what();
  }
  // a header whose length field points past the end of the file
  auto lying = bytes;
  const uint64_t big = bytes.size() * 2;
  std::memcpy(lying.data(), &big, 8);
  EXPECT_FALSE(error_of(lying).empty());
  // a header whose data offsets run past the buffer: edit the first "data_offsets":[a,b] end value
  uint64_t hlen = 0;
  std::memcpy(&hlen, bytes.data(), 8);
  std::string header(reinterpret_cast<const char*>(bytes.data() + 8), hlen);
  const size_t at = header.find("\"data_offsets\":[");
  ASSERT_NE(at, std::string::npos);
  const size_t comma = header.find(',', at);
  const size_t close = header.find(']', comma);
  std::string replaced = header.substr(0, comma + 1) + "999999999" + header.substr(close);
  replaced.resize(hlen, ' ');
  if (replaced.size() == hlen) {
    auto edited = bytes;
    std::memcpy(edited.data() + 8, replaced.data(), hlen);
    EXPECT_FALSE(error_of(edited).empty());
  }
  std::filesystem::remove_all(dir);
}

TEST(Weights, SaveAndLoadRoundTripF32AndF16) {
  const Weights r = random_weights(tiny(), 7);
  const auto dir = std::filesystem::temp_directory_path() / "vkunroll_test_weights_rt";
  std::filesystem::create_directories(dir);
  save_weights((dir / "a.safetensors").string(), r, false);
  save_weights((dir / "b.safetensors").string(), r, true);
  const Weights a = load_weights((dir / "a.safetensors").string());
  const Weights b = load_weights((dir / "b.safetensors").string());
  EXPECT_TRUE(a.config.same_shapes(tiny()));
  for (const auto& [name, t] : r.tensors) {
    EXPECT_EQ(a.get(name).data, t.data) << name;
    for (size_t i = 0; i < t.data.size(); ++i)
      ASSERT_NEAR(b.get(name).data[i], t.data[i], std::abs(t.data[i]) * 1e-3f + 1e-7f) << name;
  }
  std::filesystem::remove_all(dir);
}

TEST(Weights, Bf16TensorsLoadAsFloat) {
  const Weights r = random_weights(tiny(), 9);
  std::vector<std::vector<uint16_t>> storage;
  std::vector<SafetensorsTensorRef> views;
  for (const auto& [name, t] : r.tensors) {
    std::vector<uint16_t> h(t.data.size());
    for (size_t i = 0; i < h.size(); ++i) {
      uint32_t bits;
      std::memcpy(&bits, &t.data[i], 4);
      h[i] = static_cast<uint16_t>(bits >> 16);  // truncation: within 2^-7 relative
    }
    storage.push_back(std::move(h));
    views.push_back({name, StDType::BF16, t.shape, storage.back().data(), storage.back().size() * 2});
  }
  const auto bytes = serialize_safetensors(views, tiny().to_metadata());
  const Weights w = weights_from_safetensors(parse_safetensors(bytes, "bf16"), "bf16");
  for (const auto& [name, t] : r.tensors)
    for (size_t i = 0; i < t.data.size(); ++i)
      ASSERT_NEAR(w.get(name).data[i], t.data[i], std::abs(t.data[i]) / 128.f + 1e-30f) << name;
}

// The variant's event gate (metadata physics_gate = r): read, written back, and checked by name.
TEST(Weights, PhysicsGateIsReadAndChecked) {
  ModelConfig v = tiny();
  v.physics_input = true;
  const Weights r = random_weights(v, 5);
  auto md = v.to_metadata();
  EXPECT_EQ(md.count("physics_gate"), 0u);  // no gate: not written
  md["physics_gate"] = "2";
  const Weights w = weights_from_safetensors(parse_safetensors(serialize(r, md), "g"), "g");
  EXPECT_EQ(w.config.physics_gate, 2);
  EXPECT_EQ(w.config.to_metadata().at("physics_gate"), "2");
  EXPECT_NE(w.config.summary().find("event gate r=2"), std::string::npos) << w.config.summary();
  for (const char* bad : {"x", "2.5", "-2", "16"}) {
    md["physics_gate"] = bad;
    const std::string e = error_of(serialize(r, md));
    EXPECT_NE(e.find("'physics_gate' = '" + std::string(bad) + "'"), std::string::npos) << e;
  }
  md["physics_gate"] = "-1";  // what the mirror writes for "no gate" is accepted
  EXPECT_EQ(error_of(serialize(r, md)), "");
  // a gate needs the variant's physics input
  const Weights plain = random_weights(tiny(), 5);
  auto pmd = tiny().to_metadata();
  pmd["physics_gate"] = "1";
  EXPECT_NE(error_of(serialize(plain, pmd)).find("needs the physics-informed variant"), std::string::npos);
  ModelConfig c = tiny();
  c.physics_gate = 1;
  EXPECT_THROW(c.validate(), Error);
}

// The learned confidence: fusion_net.pred has 4 output channels; shapes and metadata must agree.
TEST(Weights, LearnedConfidenceFollowsFusionNetsShapeAndIsChecked) {
  ModelConfig v = tiny();
  v.physics_input = true;
  v.physics_confidence = true;
  const Weights r = random_weights(v, 5);
  EXPECT_EQ(r.get("fusion_net.pred.weight").shape[0], 4);
  auto md = v.to_metadata();
  EXPECT_EQ(md.at("physics_confidence"), "true");
  const Weights w = weights_from_safetensors(parse_safetensors(serialize(r, md), "c"), "c");
  EXPECT_TRUE(w.config.physics_confidence);
  EXPECT_NE(w.config.summary().find("learned confidence"), std::string::npos) << w.config.summary();
  md.erase("physics_confidence");  // the shapes alone tell it
  EXPECT_TRUE(weights_from_safetensors(parse_safetensors(serialize(r, md), "c"), "c").config.physics_confidence);
  md["physics_confidence"] = "false";
  EXPECT_NE(error_of(serialize(r, md)).find("'physics_confidence' = 'false' but fusion_net.pred.weight has 4"),
            std::string::npos) << error_of(serialize(r, md));
  // a 3-channel model claiming a confidence
  ModelConfig plain_variant = tiny();
  plain_variant.physics_input = true;
  auto pmd = plain_variant.to_metadata();
  pmd["physics_confidence"] = "true";
  EXPECT_NE(error_of(serialize(random_weights(plain_variant, 5), pmd)).find("physics_confidence"), std::string::npos);
  ModelConfig c = tiny();
  c.physics_confidence = true;  // without the physics input
  EXPECT_THROW(c.validate(), Error);
}
