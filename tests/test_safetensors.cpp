// Safetensors: round trips of every dtype, the exact byte layout, and every way a file can lie.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/base/error.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

std::vector<uint8_t> file_bytes(const std::string& header) {
  std::vector<uint8_t> b(8 + header.size());
  const uint64_t n = header.size();
  std::memcpy(b.data(), &n, 8);
  if (!header.empty()) std::memcpy(b.data() + 8, header.data(), header.size());
  return b;
}

std::string error_of(const std::vector<uint8_t>& bytes) {
  try {
    parse_safetensors(bytes, "x.safetensors");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

fs::path temp_file(const std::string& name) {
  auto dir = fs::temp_directory_path() / ("vkunroll_st_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()));
  fs::create_directories(dir);
  return dir / name;
}

}  // namespace

TEST(Safetensors, RoundTripEveryDtypeWithMetadata) {
  std::vector<SafetensorsTensor> ts;
  uint8_t fill = 1;
  for (StDType dt : {StDType::F32, StDType::F16, StDType::BF16, StDType::I32, StDType::I64, StDType::U8, StDType::F64}) {
    SafetensorsTensor t;
    t.name = std::string("t_") + st_dtype_name(dt);
    t.dtype = dt;
    t.shape = {2, 3, 1};
    t.data.resize(6 * st_dtype_size(dt));
    for (auto& b : t.data) b = fill++;
    ts.push_back(t);
  }
  SafetensorsTensor empty;
  empty.name = "empty";
  empty.shape = {0, 4};
  ts.push_back(empty);
  const auto path = temp_file("rt.safetensors");
  write_safetensors(path.string(), ts, {{"format", "pt"}, {"note", "ünïcode ok"}});
  const auto f = read_safetensors(path.string());
  ASSERT_EQ(f.tensors.size(), ts.size());
  for (size_t i = 0; i < ts.size(); ++i) {
    const auto& r = f.get(ts[i].name);
    EXPECT_EQ(r.dtype, ts[i].dtype);
    EXPECT_EQ(r.shape, ts[i].shape);
    EXPECT_EQ(r.data, ts[i].data) << ts[i].name;
  }
  EXPECT_EQ(f.metadata.at("format"), "pt");
  EXPECT_EQ(f.metadata.at("note"), "ünïcode ok");
  EXPECT_FALSE(f.has("nope"));
  EXPECT_THROW(f.get("nope"), Error);
  // Data is 8-byte aligned: the header is padded.
  std::ifstream in(path, std::ios::binary);
  uint64_t hlen = 0;
  in.read(reinterpret_cast<char*>(&hlen), 8);
  EXPECT_EQ(hlen % 8, 0u);
  fs::remove(path);
}

TEST(Safetensors, ExactByteLayout) {
  const float v[2] = {1.5f, -2.f};
  const auto bytes = serialize_safetensors({{"a", StDType::F32, {2}, v, 8}});
  const std::string h = R"({"a":{"dtype":"F32","shape":[2],"data_offsets":[0,8]}})";
  std::string padded = h;
  while (padded.size() % 8) padded.push_back(' ');
  auto expect = file_bytes(padded);
  const auto* vb = reinterpret_cast<const uint8_t*>(v);
  expect.insert(expect.end(), vb, vb + 8);
  EXPECT_EQ(bytes, expect);
}

TEST(Safetensors, ToF32ConvertsHalfAndBfloat) {
  SafetensorsTensor h{"h", StDType::F16, {4}, {}};
  for (uint16_t x : {0x3c00, 0xc000, 0x0001, 0x7c00}) {  // 1, -2, smallest subnormal, +inf
    h.data.push_back(x & 0xff);
    h.data.push_back(x >> 8);
  }
  const auto f = h.to_f32();
  EXPECT_EQ(f[0], 1.f);
  EXPECT_EQ(f[1], -2.f);
  EXPECT_EQ(f[2], std::ldexp(1.f, -24));
  EXPECT_TRUE(std::isinf(f[3]));
  SafetensorsTensor b{"b", StDType::BF16, {1}, {0x80, 0x3f}};  // 1.0
  EXPECT_EQ(b.to_f32()[0], 1.f);
}

TEST(Safetensors, RejectsLyingAndTruncatedFiles) {
  EXPECT_NE(error_of({1, 2, 3}).find("truncated"), std::string::npos);
  {  // header length beyond the file
    auto b = file_bytes("{}");
    uint64_t n = 1000;
    std::memcpy(b.data(), &n, 8);
    EXPECT_NE(error_of(b).find("truncated"), std::string::npos);
  }
  {  // absurd header length
    auto b = file_bytes("{}");
    uint64_t n = ~0ull;
    std::memcpy(b.data(), &n, 8);
    EXPECT_NE(error_of(b).find("100 MB"), std::string::npos);
  }
  EXPECT_NE(error_of(file_bytes("{not json")).find("not valid JSON"), std::string::npos);
  EXPECT_NE(error_of(file_bytes("[1]")).find("expected an object"), std::string::npos);
  {  // data beyond the buffer (truncated data)
    auto b = file_bytes(R"({"a":{"dtype":"F32","shape":[2],"data_offsets":[0,8]}})");
    b.resize(b.size() + 4);
    const auto e = error_of(b);
    EXPECT_NE(e.find("'a'"), std::string::npos) << e;
    EXPECT_NE(e.find("beyond"), std::string::npos) << e;
  }
  {  // size disagrees with shape
    auto b = file_bytes(R"({"a":{"dtype":"F32","shape":[3],"data_offsets":[0,8]}})");
    b.resize(b.size() + 8);
    EXPECT_NE(error_of(b).find("needs 12"), std::string::npos);
  }
  {  // overlap
    auto b = file_bytes(R"({"a":{"dtype":"U8","shape":[4],"data_offsets":[0,4]},"b":{"dtype":"U8","shape":[4],"data_offsets":[2,6]}})");
    b.resize(b.size() + 6);
    EXPECT_NE(error_of(b).find("overlaps"), std::string::npos);
  }
  {  // hole
    auto b = file_bytes(R"({"a":{"dtype":"U8","shape":[4],"data_offsets":[2,6]}})");
    b.resize(b.size() + 6);
    EXPECT_NE(error_of(b).find("hole"), std::string::npos);
  }
  {  // trailing bytes
    auto b = file_bytes(R"({"a":{"dtype":"U8","shape":[4],"data_offsets":[0,4]}})");
    b.resize(b.size() + 5);
    EXPECT_NE(error_of(b).find("trailing"), std::string::npos);
  }
  {  // end before begin, negative shape, unknown dtype, bad metadata
    auto b = file_bytes(R"({"a":{"dtype":"U8","shape":[0],"data_offsets":[4,0]}})");
    EXPECT_NE(error_of(b).find("end before begin"), std::string::npos);
    EXPECT_NE(error_of(file_bytes(R"({"a":{"dtype":"U8","shape":[-1],"data_offsets":[0,0]}})")).find("non-negative"),
              std::string::npos);
    EXPECT_NE(error_of(file_bytes(R"({"a":{"dtype":"Q7","shape":[0],"data_offsets":[0,0]}})")).find("Q7"),
              std::string::npos);
    EXPECT_NE(error_of(file_bytes(R"({"__metadata__":{"k":1}})")).find("'k'"), std::string::npos);
    EXPECT_NE(error_of(file_bytes(R"({"a":{"shape":[0],"data_offsets":[0,0]}})")).find("dtype"), std::string::npos);
  }
  {  // shape product overflowing 64 bits
    auto b = file_bytes(
        R"({"a":{"dtype":"F32","shape":[4294967296,4294967296,16],"data_offsets":[0,0]}})");
    EXPECT_NE(error_of(b).find("overflow"), std::string::npos);
  }
  EXPECT_THROW(read_safetensors("/nonexistent/dir/x.safetensors"), Error);
}

TEST(Safetensors, StreamWriterPiecesAndChecks) {
  const auto path = temp_file("stream.safetensors").string();
  std::vector<float> a(10);
  for (int i = 0; i < 10; ++i) a[i] = static_cast<float>(i);
  {
    SafetensorsStreamWriter w(path, {{"a", StDType::F32, {2, 5}}, {"b", StDType::I32, {1}}}, {{"k", "v"}});
    w.write("a", 20, a.data() + 5, 20);  // second half first
    w.write("a", 0, a.data(), 20);
    EXPECT_THROW(w.write("a", 16, a.data(), 8), Error);   // overlaps
    EXPECT_THROW(w.write("a", 36, a.data(), 8), Error);   // past the end
    EXPECT_THROW(w.write("zz", 0, a.data(), 4), Error);   // undeclared
    EXPECT_THROW(w.finish(), Error);                      // "b" missing
    const int32_t b = -7;
    w.write("b", 0, &b, 4);
    w.finish();
  }
  const auto f = read_safetensors(path);
  EXPECT_EQ(f.get("a").to_f32(), a);
  EXPECT_EQ(f.get("b").to_f32()[0], -7.f);
  EXPECT_EQ(f.metadata.at("k"), "v");
  fs::remove(path);
  {  // an unfinished writer leaves nothing behind
    SafetensorsStreamWriter w(path, {{"a", StDType::F32, {2}}});
  }
  EXPECT_FALSE(fs::exists(path));
  EXPECT_THROW(write_safetensors(path, std::vector<SafetensorsTensorRef>{{"a", StDType::F32, {3}, a.data(), 8}}), Error);
  EXPECT_THROW(write_safetensors(path, std::vector<SafetensorsTensorRef>{{"a", StDType::F32, {1}, a.data(), 4},
                                                                 {"a", StDType::F32, {1}, a.data(), 4}}),
               Error);
}
