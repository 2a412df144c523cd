// Safetensors (https://huggingface.co/docs/safetensors): an 8-byte little-endian header length,
// a JSON header {name: {dtype, shape, data_offsets:[begin,end]}, "__metadata__": {str: str}},
// then one byte buffer. Reading checks everything the header claims against the file (size,
// offsets inside the buffer, bytes == product(shape) * dtype size, no overlaps, no holes), so a
// truncated or lying file is a clear error naming the file and the tensor, never a crash.
#pragma once
#include <cstddef>
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <vector>

namespace vkunroll {

enum class StDType { F64, F32, F16, BF16, I64, I32, I16, I8, U64, U32, U16, U8, BOOL };

size_t st_dtype_size(StDType t);
const char* st_dtype_name(StDType t);          // "F32", ...
StDType st_dtype_from_name(const std::string& name);  // throws Error on an unknown name

int64_t st_element_count(const std::vector<int64_t>& shape);  // throws on negative/overflow

// A tensor held in memory (read from a file, or built to be written).
struct SafetensorsTensor {
  std::string name;
  StDType dtype = StDType::F32;
  std::vector<int64_t> shape;
  std::vector<uint8_t> data;  // little-endian, row-major, st_element_count(shape) * size bytes

  int64_t count() const { return st_element_count(shape); }
  // Values as float32: F32 copied, F16/BF16/F64 converted, integers converted exactly where
  // representable. Throws for BOOL.
  std::vector<float> to_f32() const;
};

// A tensor referencing the caller's memory, for writing without copies.
struct SafetensorsTensorRef {
  std::string name;
  StDType dtype = StDType::F32;
  std::vector<int64_t> shape;
  const void* data = nullptr;
  size_t bytes = 0;  // must equal count * dtype size
};

struct SafetensorsFile {
  std::map<std::string, std::string> metadata;  // "__metadata__"
  std::vector<SafetensorsTensor> tensors;                // in file (offset) order

  bool has(const std::string& name) const;
  const SafetensorsTensor& get(const std::string& name) const;  // throws Error naming the missing tensor
  std::vector<std::string> names() const;
};

// Reads and validates a whole file. `origin` names it in errors (the path for read_safetensors).
SafetensorsFile read_safetensors(const std::string& path);
SafetensorsFile parse_safetensors(std::span<const uint8_t> bytes, const std::string& origin);

// Writes tensors in the given order (names must be unique and not "__metadata__"); the header is
// padded with spaces to a multiple of 8 bytes so the data is 8-byte aligned, as the reference
// library does. Writes to a temporary file and renames, so a failed write leaves no partial file.
void write_safetensors(const std::string& path, const std::vector<SafetensorsTensorRef>& tensors,
                       const std::map<std::string, std::string>& metadata = {});
void write_safetensors(const std::string& path, const std::vector<SafetensorsTensor>& tensors,
                       const std::map<std::string, std::string>& metadata = {});
std::vector<uint8_t> serialize_safetensors(const std::vector<SafetensorsTensorRef>& tensors,
                                           const std::map<std::string, std::string>& metadata = {});

// Streaming writer for outputs larger than memory: the header (names, dtypes, shapes) is fixed
// up front; the data of each tensor is then written in pieces at byte offsets inside the
// tensor, in any order. finish() checks that every byte was written exactly once and renames
// the temporary file into place; destroying an unfinished writer removes the temporary file.
class SafetensorsStreamWriter {
 public:
  struct Spec {
    std::string name;
    StDType dtype = StDType::F32;
    std::vector<int64_t> shape;
  };
  SafetensorsStreamWriter(const std::string& path, const std::vector<Spec>& specs,
                          const std::map<std::string, std::string>& metadata = {});
  ~SafetensorsStreamWriter();
  SafetensorsStreamWriter(const SafetensorsStreamWriter&) = delete;
  SafetensorsStreamWriter& operator=(const SafetensorsStreamWriter&) = delete;

  void write(const std::string& name, size_t byte_offset, const void* data, size_t bytes);
  void finish();

 private:
  struct Slot {
    uint64_t file_offset = 0, bytes = 0, written = 0;
    std::map<uint64_t, uint64_t> pieces;  // begin -> end of the byte ranges written so far
  };
  std::string path_, tmp_path_;
  std::map<std::string, Slot> slots_;
  void* file_ = nullptr;  // FILE*
  bool finished_ = false;
};

}  // namespace vkunroll
