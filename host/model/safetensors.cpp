#include "vkunroll/host/model/safetensors.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <unistd.h>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/json_read.hpp"

namespace vkunroll {
namespace {

// The reference implementation refuses headers above 100 MB; so do we (a lying length field
// must not make us allocate gigabytes).
constexpr uint64_t kMaxHeaderBytes = 100ull << 20;

struct DTypeInfo {
  StDType t;
  const char* name;
  size_t size;
};
constexpr DTypeInfo kDTypes[] = {
    {StDType::F64, "F64", 8}, {StDType::F32, "F32", 4}, {StDType::F16, "F16", 2},  {StDType::BF16, "BF16", 2},
    {StDType::I64, "I64", 8}, {StDType::I32, "I32", 4}, {StDType::I16, "I16", 2},  {StDType::I8, "I8", 1},
    {StDType::U64, "U64", 8}, {StDType::U32, "U32", 4}, {StDType::U16, "U16", 2},  {StDType::U8, "U8", 1},
    {StDType::BOOL, "BOOL", 1},
};

float half_to_float(uint16_t h) {
  const uint32_t sign = (h & 0x8000u) << 16;
  uint32_t exp = (h >> 10) & 0x1f, man = h & 0x3ff;
  uint32_t bits;
  if (exp == 0) {
    if (man == 0) {
      bits = sign;
    } else {  // subnormal: normalize
      int e = -1;
      do {
        ++e;
        man <<= 1;
      } while (!(man & 0x400));
      bits = sign | ((127 - 15 - e) << 23) | ((man & 0x3ff) << 13);
    }
  } else if (exp == 31) {
    bits = sign | 0x7f800000u | (man << 13);
  } else {
    bits = sign | ((exp + 127 - 15) << 23) | (man << 13);
  }
  return std::bit_cast<float>(bits);
}

template <class T>
T load_le(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));  // the build targets little-endian hosts (x86-64, aarch64)
  return v;
}

std::string json_type(const nlohmann::json& j) { return j.type_name(); }

uint64_t checked_mul(uint64_t a, uint64_t b, const std::string& what) {
  if (a != 0 && b > std::numeric_limits<uint64_t>::max() / a) throw DataError(what + ": size overflows 64 bits");
  return a * b;
}

std::string build_header(const std::vector<SafetensorsTensorRef>& tensors, const std::map<std::string, std::string>& metadata,
                         std::vector<uint64_t>* begins) {
  // nlohmann::ordered_json keeps tensor order so the header reads in data order.
  nlohmann::ordered_json h = nlohmann::ordered_json::object();
  if (!metadata.empty()) {
    nlohmann::ordered_json m = nlohmann::ordered_json::object();
    for (const auto& [k, v] : metadata) m[k] = v;
    h["__metadata__"] = m;
  }
  std::set<std::string> seen;
  uint64_t offset = 0;
  for (const auto& t : tensors) {
    if (t.name.empty() || t.name == "__metadata__")
      throw UsageError("safetensors write: invalid tensor name '" + t.name + "'");
    if (!seen.insert(t.name).second) throw UsageError("safetensors write: duplicate tensor name '" + t.name + "'");
    const uint64_t need = checked_mul(static_cast<uint64_t>(st_element_count(t.shape)), st_dtype_size(t.dtype),
                                      "safetensors write: tensor '" + t.name + "'");
    if (need != t.bytes)
      throw UsageError("safetensors write: tensor '" + t.name + "' has " + std::to_string(t.bytes) + " bytes, its shape and " +
                  st_dtype_name(t.dtype) + " need " + std::to_string(need));
    if (need && !t.data) throw UsageError("safetensors write: tensor '" + t.name + "' has no data pointer");
    if (begins) begins->push_back(offset);
    h[t.name] = {{"dtype", st_dtype_name(t.dtype)}, {"shape", t.shape}, {"data_offsets", {offset, offset + need}}};
    offset += need;
  }
  std::string s = h.dump();
  while ((8 + s.size()) % 8) s.push_back(' ');
  return s;
}

void write_u64_le(std::string& out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

std::vector<SafetensorsTensorRef> views_of(const std::vector<SafetensorsTensor>& tensors) {
  std::vector<SafetensorsTensorRef> v;
  v.reserve(tensors.size());
  for (const auto& t : tensors) v.push_back({t.name, t.dtype, t.shape, t.data.data(), t.data.size()});
  return v;
}

std::string temp_path_for(const std::string& path) { return path + ".tmp" + std::to_string(::getpid()); }

}  // namespace

size_t st_dtype_size(StDType t) {
  for (const auto& d : kDTypes)
    if (d.t == t) return d.size;
  throw InternalError("safetensors: invalid dtype enum");
}

const char* st_dtype_name(StDType t) {
  for (const auto& d : kDTypes)
    if (d.t == t) return d.name;
  return "?";
}

StDType st_dtype_from_name(const std::string& name) {
  for (const auto& d : kDTypes)
    if (name == d.name) return d.t;
  throw DataError("safetensors: unsupported dtype '" + name +
              "' (expected one of F64 F32 F16 BF16 I64 I32 I16 I8 U64 U32 U16 U8 BOOL)");
}

int64_t st_element_count(const std::vector<int64_t>& shape) {
  uint64_t n = 1;
  for (int64_t d : shape) {
    if (d < 0) throw DataError("safetensors: negative dimension " + std::to_string(d));
    n = checked_mul(n, static_cast<uint64_t>(d), "safetensors: shape");
  }
  if (n > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) throw DataError("safetensors: shape too large");
  return static_cast<int64_t>(n);
}

std::vector<float> SafetensorsTensor::to_f32() const {
  const size_t n = static_cast<size_t>(count());
  std::vector<float> out(n);
  const uint8_t* p = data.data();
  switch (dtype) {
    case StDType::F32: std::memcpy(out.data(), p, n * 4); break;
    case StDType::F64: for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(load_le<double>(p + 8 * i)); break;
    case StDType::F16: for (size_t i = 0; i < n; ++i) out[i] = half_to_float(load_le<uint16_t>(p + 2 * i)); break;
    case StDType::BF16:
      for (size_t i = 0; i < n; ++i) out[i] = std::bit_cast<float>(static_cast<uint32_t>(load_le<uint16_t>(p + 2 * i)) << 16);
      break;
    case StDType::I64: for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(load_le<int64_t>(p + 8 * i)); break;
    case StDType::I32: for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(load_le<int32_t>(p + 4 * i)); break;
    case StDType::I16: for (size_t i = 0; i < n; ++i) out[i] = load_le<int16_t>(p + 2 * i); break;
    case StDType::I8: for (size_t i = 0; i < n; ++i) out[i] = static_cast<int8_t>(p[i]); break;
    case StDType::U64: for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(load_le<uint64_t>(p + 8 * i)); break;
    case StDType::U32: for (size_t i = 0; i < n; ++i) out[i] = static_cast<float>(load_le<uint32_t>(p + 4 * i)); break;
    case StDType::U16: for (size_t i = 0; i < n; ++i) out[i] = load_le<uint16_t>(p + 2 * i); break;
    case StDType::U8: for (size_t i = 0; i < n; ++i) out[i] = p[i]; break;
    case StDType::BOOL: throw DataError("safetensors: tensor '" + name + "' is BOOL, not convertible to float");
  }
  return out;
}

bool SafetensorsFile::has(const std::string& name) const {
  return std::any_of(tensors.begin(), tensors.end(), [&](const SafetensorsTensor& t) { return t.name == name; });
}

const SafetensorsTensor& SafetensorsFile::get(const std::string& name) const {
  for (const auto& t : tensors)
    if (t.name == name) return t;
  throw DataError("safetensors: no tensor named '" + name + "'");
}

std::vector<std::string> SafetensorsFile::names() const {
  std::vector<std::string> n;
  for (const auto& t : tensors) n.push_back(t.name);
  return n;
}

namespace {

// One tensor's header entry, checked against the data buffer's size.
struct HeaderEntry {
  std::string name;
  StDType dtype;
  std::vector<int64_t> shape;
  uint64_t begin, end;
};

void parse_metadata(const std::string& where, const nlohmann::json& v, SafetensorsFile& file) {
  if (!v.is_object()) throw DataError(where + ": __metadata__ is a JSON " + json_type(v) + ", expected an object");
  for (auto m = v.begin(); m != v.end(); ++m) {
    if (!m.value().is_string())
      throw DataError(where + ": __metadata__ field '" + m.key() + "' is a JSON " + json_type(m.value()) + ", expected a string");
    file.metadata[m.key()] = m.value().get<std::string>();
  }
}

HeaderEntry parse_entry(const std::string& where, const std::string& name, const nlohmann::json& v, uint64_t buffer_size) {
  const std::string tw = where + ": tensor '" + name + "'";
  if (!v.is_object()) throw DataError(tw + ": entry is a JSON " + json_type(v) + ", expected an object");
  if (!v.contains("dtype") || !v["dtype"].is_string()) throw DataError(tw + ": missing or non-string field 'dtype'");
  if (!v.contains("shape") || !v["shape"].is_array()) throw DataError(tw + ": missing or non-array field 'shape'");
  if (!v.contains("data_offsets") || !v["data_offsets"].is_array() || v["data_offsets"].size() != 2)
    throw DataError(tw + ": field 'data_offsets' must be an array [begin, end]");
  HeaderEntry e;
  e.name = name;
  try {
    e.dtype = st_dtype_from_name(v["dtype"].get<std::string>());
  } catch (const Error& err) {
    throw Error(tw + ": " + err.text(), err.kind());
  }
  for (const auto& d : v["shape"]) {
    if (!d.is_number_unsigned()) throw DataError(tw + ": shape entries must be non-negative integers, got " + d.dump());
    const uint64_t dv = d.get<uint64_t>();
    if (dv > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) throw DataError(tw + ": dimension too large");
    e.shape.push_back(static_cast<int64_t>(dv));
  }
  for (int k = 0; k < 2; ++k)
    if (!v["data_offsets"][k].is_number_unsigned())
      throw DataError(tw + ": data_offsets must be non-negative integers, got " + v["data_offsets"].dump());
  e.begin = v["data_offsets"][0].get<uint64_t>();
  e.end = v["data_offsets"][1].get<uint64_t>();
  if (e.end < e.begin)
    throw DataError(tw + ": data_offsets [" + std::to_string(e.begin) + ", " + std::to_string(e.end) + "] end before begin");
  if (e.end > buffer_size)
    throw DataError(tw + ": data_offsets end " + std::to_string(e.end) + " is beyond the data buffer of " +
                std::to_string(buffer_size) + " bytes (truncated file or lying header)");
  uint64_t need;
  try {
    need = checked_mul(static_cast<uint64_t>(st_element_count(e.shape)), st_dtype_size(e.dtype), tw);
  } catch (const Error& err) {
    throw Error(tw + ": " + err.text(), err.kind());
  }
  if (e.end - e.begin != need)
    throw DataError(tw + ": data_offsets span " + std::to_string(e.end - e.begin) + " bytes, shape " +
                nlohmann::json(e.shape).dump() + " of " + st_dtype_name(e.dtype) + " needs " + std::to_string(need));
  return e;
}

// The tensors must tile the buffer: sorted by begin, each starts where the previous ended.
void check_tiling(const std::string& where, std::vector<HeaderEntry>& entries, uint64_t buffer_size) {
  std::sort(entries.begin(), entries.end(), [](const HeaderEntry& a, const HeaderEntry& b) {
    return a.begin != b.begin ? a.begin < b.begin : a.end < b.end;
  });
  uint64_t cursor = 0;
  for (size_t i = 0; i < entries.size(); ++i) {
    const auto& e = entries[i];
    if (e.begin < cursor)
      throw DataError(where + ": tensor '" + e.name + "' data [" + std::to_string(e.begin) + ", " + std::to_string(e.end) +
                  ") overlaps tensor '" + entries[i - 1].name + "' (ends at " + std::to_string(cursor) + ")");
    if (e.begin > cursor)
      throw DataError(where + ": " + std::to_string(e.begin - cursor) + " unclaimed bytes at offset " + std::to_string(cursor) +
                  " before tensor '" + e.name + "' (hole in the data buffer)");
    cursor = e.end;
  }
  if (cursor != buffer_size)
    throw DataError(where + ": data buffer has " + std::to_string(buffer_size) + " bytes but the tensors cover " +
                std::to_string(cursor) + " (trailing bytes: corrupt or lying header)");
}

}  // namespace

SafetensorsFile parse_safetensors(std::span<const uint8_t> bytes, const std::string& origin) {
  const std::string where = "safetensors '" + origin + "'";
  if (bytes.size() < 8)
    throw DataError(where + ": truncated: " + std::to_string(bytes.size()) + " bytes, expected at least 8 (header length)");
  const uint64_t hlen = load_le<uint64_t>(bytes.data());
  if (hlen > kMaxHeaderBytes)
    throw DataError(where + ": header length " + std::to_string(hlen) + " exceeds the 100 MB limit (corrupt file?)");
  if (hlen > bytes.size() - 8)
    throw DataError(where + ": truncated: header length says " + std::to_string(hlen) + " bytes, the file has only " +
                std::to_string(bytes.size() - 8) + " after the length field");
  const std::string_view htext(reinterpret_cast<const char*>(bytes.data() + 8), hlen);
  // A tensor named twice (a repeated key) is refused, as any invalid header.
  nlohmann::json h = parse_json<nlohmann::json>(htext, where + ": header");
  if (!h.is_object()) throw DataError(where + ": header is a JSON " + json_type(h) + ", expected an object");
  const uint8_t* buffer = bytes.data() + 8 + hlen;
  const uint64_t buffer_size = bytes.size() - 8 - hlen;

  SafetensorsFile file;
  std::vector<HeaderEntry> entries;
  for (auto it = h.begin(); it != h.end(); ++it) {
    if (it.key() == "__metadata__") parse_metadata(where, it.value(), file);
    else entries.push_back(parse_entry(where, it.key(), it.value(), buffer_size));
  }
  check_tiling(where, entries, buffer_size);
  for (auto& e : entries) {
    SafetensorsTensor t;
    t.name = e.name;
    t.dtype = e.dtype;
    t.shape = e.shape;
    t.data.assign(buffer + e.begin, buffer + e.end);
    file.tensors.push_back(std::move(t));
  }
  return file;
}

SafetensorsFile read_safetensors(const std::string& path) {
  std::error_code ec;
  const auto st = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(st)) throw InputMissingError("safetensors '" + path + "': no such file");
  if (!std::filesystem::is_regular_file(st))  // a folder "opens" on Linux and reads as a huge size
    throw DataError("safetensors '" + path + "': is " + (std::filesystem::is_directory(st) ? "a folder" : "not a regular file") +
                    ", expected a .safetensors file");
  std::ifstream f(path, std::ios::binary);
  if (!f) throw IoError("safetensors '" + path + "': cannot open for reading");
  f.seekg(0, std::ios::end);
  const auto size = static_cast<size_t>(f.tellg());
  f.seekg(0);
  std::vector<uint8_t> bytes(size);
  if (size && !f.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(size)))
    throw IoError("safetensors '" + path + "': read failed");
  return parse_safetensors(bytes, path);
}

std::vector<uint8_t> serialize_safetensors(const std::vector<SafetensorsTensorRef>& tensors,
                                           const std::map<std::string, std::string>& metadata) {
  const std::string header = build_header(tensors, metadata, nullptr);
  std::string prefix;
  write_u64_le(prefix, header.size());
  std::vector<uint8_t> out(prefix.begin(), prefix.end());
  out.insert(out.end(), header.begin(), header.end());
  for (const auto& t : tensors) {
    const auto* p = static_cast<const uint8_t*>(t.data);
    out.insert(out.end(), p, p + t.bytes);
  }
  return out;
}

void write_safetensors(const std::string& path, const std::vector<SafetensorsTensorRef>& tensors,
                       const std::map<std::string, std::string>& metadata) {
  std::vector<SafetensorsStreamWriter::Spec> specs;
  for (const auto& t : tensors) specs.push_back({t.name, t.dtype, t.shape});
  // build_header also validates byte counts against shapes before anything is written
  (void)build_header(tensors, metadata, nullptr);
  SafetensorsStreamWriter w(path, specs, metadata);
  for (const auto& t : tensors) w.write(t.name, 0, t.data, t.bytes);
  w.finish();
}

void write_safetensors(const std::string& path, const std::vector<SafetensorsTensor>& tensors,
                       const std::map<std::string, std::string>& metadata) {
  write_safetensors(path, views_of(tensors), metadata);
}

SafetensorsStreamWriter::SafetensorsStreamWriter(const std::string& path, const std::vector<Spec>& specs,
                                                 const std::map<std::string, std::string>& metadata)
    : path_(path), tmp_path_(temp_path_for(path)) {
  std::vector<SafetensorsTensorRef> views;
  for (const auto& s : specs) {
    const uint64_t bytes = checked_mul(static_cast<uint64_t>(st_element_count(s.shape)), st_dtype_size(s.dtype),
                                       "safetensors write: tensor '" + s.name + "'");
    // Non-null placeholder pointer: the header builder only checks sizes here.
    views.push_back({s.name, s.dtype, s.shape, this, static_cast<size_t>(bytes)});
  }
  std::vector<uint64_t> begins;
  const std::string header = build_header(views, metadata, &begins);
  std::string prefix;
  write_u64_le(prefix, header.size());
  const uint64_t data_start = 8 + header.size();
  uint64_t total = data_start;
  for (size_t i = 0; i < specs.size(); ++i) {
    slots_[specs[i].name] = {data_start + begins[i], views[i].bytes, 0};
    total += views[i].bytes;
  }
  FILE* f = std::fopen(tmp_path_.c_str(), "wb");
  if (!f) throw IoError("safetensors '" + path_ + "': cannot open '" + tmp_path_ + "' for writing: " + std::strerror(errno));
  file_ = f;
  if (std::fwrite(prefix.data(), 1, prefix.size(), f) != prefix.size() ||
      std::fwrite(header.data(), 1, header.size(), f) != header.size())
    throw IoError("safetensors '" + path_ + "': write failed: " + std::strerror(errno));
  (void)total;
}

SafetensorsStreamWriter::~SafetensorsStreamWriter() {
  if (file_) std::fclose(static_cast<FILE*>(file_));
  if (!finished_) {
    std::error_code ec;
    std::filesystem::remove(tmp_path_, ec);
  }
}

void SafetensorsStreamWriter::write(const std::string& name, size_t byte_offset, const void* data, size_t bytes) {
  if (finished_) throw InternalError("safetensors '" + path_ + "': write after finish");
  auto it = slots_.find(name);
  if (it == slots_.end()) throw InternalError("safetensors '" + path_ + "': write to undeclared tensor '" + name + "'");
  Slot& s = it->second;
  if (byte_offset > s.bytes || bytes > s.bytes - byte_offset)
    throw InternalError("safetensors '" + path_ + "': write of " + std::to_string(bytes) + " bytes at " +
                std::to_string(byte_offset) + " exceeds tensor '" + name + "' (" + std::to_string(s.bytes) + " bytes)");
  if (bytes) {
    // Each byte exactly once: the new piece must not overlap its neighbours.
    const uint64_t b = byte_offset, e = byte_offset + bytes;
    auto next = s.pieces.lower_bound(b);
    if ((next != s.pieces.end() && next->first < e) ||
        (next != s.pieces.begin() && std::prev(next)->second > b))
      throw InternalError("safetensors '" + path_ + "': tensor '" + name + "' bytes [" + std::to_string(b) + ", " +
                  std::to_string(e) + ") overlap a piece written before");
    s.pieces[b] = e;
  }
  FILE* f = static_cast<FILE*>(file_);
  if (std::fseek(f, static_cast<long>(s.file_offset + byte_offset), SEEK_SET) != 0 ||
      (bytes && std::fwrite(data, 1, bytes, f) != bytes))
    throw IoError("safetensors '" + path_ + "': write failed: " + std::strerror(errno));
  s.written += bytes;
}

void SafetensorsStreamWriter::finish() {
  if (finished_) return;
  for (const auto& [name, s] : slots_)
    if (s.written != s.bytes)
      throw InternalError("safetensors '" + path_ + "': tensor '" + name + "' got " + std::to_string(s.written) + " of " +
                  std::to_string(s.bytes) + " bytes before finish()");
  FILE* f = static_cast<FILE*>(file_);
  file_ = nullptr;
  if (std::fflush(f) != 0 || std::fclose(f) != 0)
    throw IoError("safetensors '" + path_ + "': write failed: " + std::strerror(errno));
  std::error_code ec;
  std::filesystem::rename(tmp_path_, path_, ec);
  if (ec) throw IoError("safetensors '" + path_ + "': cannot rename temporary file: " + ec.message());
  finished_ = true;
}

}  // namespace vkunroll
