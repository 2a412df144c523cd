// A .npz member as random-access bytes. Stored members are read in place; deflated members get an
// inflate index (zlib's zran method: the decoder's 32 KiB window saved every ~1 MiB of output), so a
// windowed read inflates only the spans it touches. Opening a member reads it once, front to back,
// and checks its CRC-32 against the zip directory (numpy refuses a corrupt member; so do we).
#pragma once
#include <zip.h>

#include <cstdint>
#include <list>
#include <memory>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

class ZipMemberSource final : public ByteSource {
 public:
  // `archive` and `member` name the file and the array in messages.
  ZipMemberSource(zip_t* z, zip_uint64_t index, const std::string& archive, const std::string& member);
  ~ZipMemberSource() override;
  uint64_t size() const override { return size_; }
  size_t read_at(uint64_t offset, void* dst, size_t n) override;
  bool stored() const { return stored_; }
  size_t access_points() const { return points_.size(); }

 private:
  struct AccessPoint {
    uint64_t out = 0, in = 0;  // uncompressed and compressed offsets of a deflate block start
    int bits = 0;              // bits of the byte before `in` that belong to the block
    std::vector<uint8_t> window;  // the last 32 KiB of output before `out`
  };
  struct Span {
    size_t point = 0;
    std::vector<uint8_t> bytes;  // output from points_[point].out to the next point (or the end)
  };
  void verify_stored();
  void index_deflated();
  const Span& span(size_t point);
  size_t read_raw(uint64_t offset, void* dst, size_t n);
  [[noreturn]] void corrupt(const std::string& why) const;

  zip_t* z_;
  zip_uint64_t index_;
  std::string archive_, member_;
  zip_file_t* raw_ = nullptr;  // the member's bytes as stored in the archive
  uint64_t size_ = 0, comp_size_ = 0, raw_pos_ = 0;
  uint32_t crc_ = 0;
  bool stored_ = false;
  std::vector<AccessPoint> points_;
  std::list<Span> cache_;  // most recently used first
};

// The members of an .npz, opened once (CRC checked, inflate index built) and kept for later reads.
class NpzArchive {
 public:
  // From a file path, or from memory when `data` is non-null (fuzzing).
  NpzArchive(const std::string& path, const uint8_t* data, size_t size);
  ~NpzArchive();
  NpzArchive(const NpzArchive&) = delete;
  NpzArchive& operator=(const NpzArchive&) = delete;
  // Reads the event array(s) (the window and policy in the sink's options) into the sink
  // (reader_numpy.cpp).
  void read(EventSink& sink);

 private:
  ZipMemberSource& member(const std::string& key);  // opened on first use, then kept
  std::string path_;
  zip_t* z_ = nullptr;
  std::vector<std::pair<std::string, zip_uint64_t>> members_;  // name without ".npy", index
  std::vector<std::pair<std::string, std::unique_ptr<ZipMemberSource>>> open_;
};

}  // namespace vkunroll::detail
