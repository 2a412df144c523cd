// .npz members through libzip (raw bytes) and zlib (CRC-32, inflate with an access-point index).
#include "vkunroll/host/events/zip_member_detail.hpp"

#include <zlib.h>

#include <algorithm>
#include <cstring>

namespace vkunroll::detail {

namespace {

constexpr size_t kWindow = 32768;                 // deflate's history window
constexpr uint64_t kSpan = uint64_t(1) << 20;      // output between access points
constexpr size_t kChunk = 1 << 16;                 // compressed bytes read at a time
constexpr size_t kCachedSpans = 4;

std::string hex32(uint32_t v) {
  static const char* d = "0123456789abcdef";
  std::string s = "0x00000000";
  for (int i = 9; i >= 2; --i, v >>= 4) s[size_t(i)] = d[v & 15];
  return s;
}

// An inflate stream that frees itself.
struct Inflater {
  z_stream s{};
  bool ok = false;
  Inflater() { ok = inflateInit2(&s, -15) == Z_OK; }
  ~Inflater() {
    if (ok) inflateEnd(&s);
  }
};

}  // namespace

ZipMemberSource::ZipMemberSource(zip_t* z, zip_uint64_t index, const std::string& archive, const std::string& member)
    : ByteSource(archive + ":" + member), z_(z), index_(index), archive_(archive), member_(member) {
  zip_stat_t st;
  zip_stat_init(&st);
  const zip_uint64_t need = ZIP_STAT_SIZE | ZIP_STAT_COMP_SIZE | ZIP_STAT_COMP_METHOD | ZIP_STAT_CRC;
  if (zip_stat_index(z_, index_, 0, &st) != 0 || (st.valid & need) != need)
    throw DataError(name() + ": cannot stat the zip member (corrupt .npz directory)");
  if ((st.valid & ZIP_STAT_ENCRYPTION_METHOD) && st.encryption_method != ZIP_EM_NONE)
    throw DataError(name() + ": the zip member is encrypted; vkunroll reads plain .npz files (numpy.savez)");
  size_ = st.size;
  comp_size_ = st.comp_size;
  crc_ = st.crc;
  stored_ = st.comp_method == ZIP_CM_STORE;
  if (!stored_ && st.comp_method != ZIP_CM_DEFLATE)
    throw DataError(name() + ": the zip member uses compression method " + std::to_string(st.comp_method) +
                "; .npz members are stored or deflated (numpy.savez / savez_compressed)");
  if (stored_ && comp_size_ != size_)
    corrupt("a stored member of " + std::to_string(size_) + " bytes occupies " + std::to_string(comp_size_));
  raw_ = zip_fopen_index(z_, index_, ZIP_FL_COMPRESSED);
  if (!raw_) throw DataError(name() + ": cannot open the zip member (" + zip_strerror(z_) + ")");
  try {
    if (stored_) verify_stored();
    else index_deflated();
  } catch (...) {
    zip_fclose(raw_);  // the destructor does not run for a constructor that throws
    raw_ = nullptr;
    throw;
  }
}

ZipMemberSource::~ZipMemberSource() {
  if (raw_) zip_fclose(raw_);
}

void ZipMemberSource::corrupt(const std::string& why) const {
  throw DataError(archive_ + ": member '" + member_ + "' is corrupt: " + why +
              " (the .npz is damaged; numpy refuses it too)");
}

// Compressed bytes at `offset` of the member's raw data.
size_t ZipMemberSource::read_raw(uint64_t offset, void* dst, size_t n) {
  if (offset >= comp_size_) return 0;
  n = size_t(std::min<uint64_t>(n, comp_size_ - offset));
  if (offset != raw_pos_) {
    if (zip_fseek(raw_, zip_int64_t(offset), SEEK_SET) != 0)
      throw DataError(name() + ": cannot seek in the zip member (" + zip_file_strerror(raw_) + ")");
    raw_pos_ = offset;
  }
  size_t done = 0;
  while (done < n) {
    const zip_int64_t r = zip_fread(raw_, static_cast<uint8_t*>(dst) + done, n - done);
    if (r < 0) throw DataError(name() + ": cannot read the zip member (" + zip_file_strerror(raw_) + "; truncated .npz?)");
    if (r == 0) break;
    done += size_t(r);
  }
  raw_pos_ += done;
  if (done < n) corrupt("its data ends after " + std::to_string(raw_pos_) + " of " + std::to_string(comp_size_) + " bytes");
  return done;
}

void ZipMemberSource::verify_stored() {
  std::vector<uint8_t> buf(size_t(std::min<uint64_t>(size_, kSpan)));
  uLong crc = crc32(0L, Z_NULL, 0);
  for (uint64_t off = 0; off < size_;) {
    const size_t got = read_raw(off, buf.data(), size_t(std::min<uint64_t>(buf.size(), size_ - off)));
    crc = crc32(crc, buf.data(), uInt(got));
    off += got;
  }
  if (uint32_t(crc) != crc_)
    corrupt("its CRC-32 is " + hex32(uint32_t(crc)) + ", the zip directory says " + hex32(crc_));
}

// One pass through the deflate data: the CRC check and the access points (zlib's examples/zran.c).
void ZipMemberSource::index_deflated() {
  Inflater inf;
  if (!inf.ok) throw InternalError(name() + ": cannot start zlib's inflate");
  z_stream& s = inf.s;
  std::vector<uint8_t> in(kChunk), window(kWindow, 0);
  uint64_t in_pos = 0, total_in = 0, total_out = 0, last = 0;
  uLong crc = crc32(0L, Z_NULL, 0);
  s.avail_out = 0;
  for (;;) {
    if (s.avail_out == 0) {
      s.avail_out = uInt(kWindow);
      s.next_out = window.data();
    }
    const uInt in_before = s.avail_in, out_before = s.avail_out;
    uint8_t* out_at = s.next_out;
    const int ret = inflate(&s, Z_BLOCK);
    const uInt consumed = in_before - s.avail_in, produced = out_before - s.avail_out;
    total_in += consumed;
    crc = crc32(crc, out_at, produced);
    total_out += produced;
    if (ret == Z_NEED_DICT || ret == Z_DATA_ERROR || ret == Z_MEM_ERROR || ret == Z_STREAM_ERROR)
      corrupt(std::string("inflate fails at compressed byte ") + std::to_string(total_in) + " (" +
              (s.msg ? s.msg : "zlib error") + ")");
    if (total_out > size_) corrupt("it inflates to more than the " + std::to_string(size_) + " bytes the directory says");
    if (ret == Z_STREAM_END) break;
    if (consumed == 0 && produced == 0) {
      // No progress: inflate needs input (its bit buffer may hold the end of the data, so input is
      // read only now, not whenever avail_in is 0).
      if (s.avail_in != 0) corrupt("inflate makes no progress");
      const size_t got = read_raw(in_pos, in.data(), size_t(std::min<uint64_t>(kChunk, comp_size_ - std::min(comp_size_, in_pos))));
      if (got == 0) corrupt("its deflate data ends before the end of the stream (truncated)");
      in_pos += got;
      s.avail_in = uInt(got);
      s.next_in = in.data();
      continue;
    }
    // At a block boundary (not the last block): an access point every kSpan bytes of output.
    if (ret == Z_OK && (s.data_type & 128) && !(s.data_type & 64) &&
        (points_.empty() ? total_out == 0 : total_out - last > kSpan)) {
      AccessPoint p;
      p.out = total_out, p.in = total_in, p.bits = s.data_type & 7;
      p.window.resize(kWindow);
      const size_t left = s.avail_out;  // the window is circular: its oldest byte is at kWindow - left
      if (left) std::memcpy(p.window.data(), window.data() + kWindow - left, left);
      if (left < kWindow) std::memcpy(p.window.data() + left, window.data(), kWindow - left);
      points_.push_back(std::move(p));
      last = total_out;
    }
  }
  if (total_out != size_)
    corrupt("it inflates to " + std::to_string(total_out) + " bytes, the directory says " + std::to_string(size_));
  if (uint32_t(crc) != crc_)
    corrupt("its CRC-32 is " + hex32(uint32_t(crc)) + ", the zip directory says " + hex32(crc_));
  if (points_.empty() || points_.front().out != 0) {
    AccessPoint p;  // the stream start (an empty member, or a first block zlib did not stop at)
    points_.insert(points_.begin(), std::move(p));
  }
}

// The output between access point `k` and the next one, inflated once and cached.
const ZipMemberSource::Span& ZipMemberSource::span(size_t k) {
  for (auto it = cache_.begin(); it != cache_.end(); ++it)
    if (it->point == k) {
      cache_.splice(cache_.begin(), cache_, it);
      return cache_.front();
    }
  const AccessPoint& p = points_[k];
  const uint64_t end = k + 1 < points_.size() ? points_[k + 1].out : size_;
  Span sp;
  sp.point = k;
  sp.bytes.resize(size_t(end - p.out));
  Inflater inf;
  if (!inf.ok) throw InternalError(name() + ": cannot start zlib's inflate");
  z_stream& s = inf.s;
  std::vector<uint8_t> in(kChunk);
  uint64_t in_pos = p.in;
  if (p.bits) {
    uint8_t b = 0;
    read_raw(p.in - 1, &b, 1);
    inflatePrime(&s, p.bits, b >> (8 - p.bits));
  }
  if (p.out > 0) inflateSetDictionary(&s, p.window.data(), uInt(kWindow));
  s.next_out = sp.bytes.data();
  s.avail_out = uInt(sp.bytes.size());
  while (s.avail_out > 0) {
    const uInt in_before = s.avail_in, out_before = s.avail_out;
    const int ret = inflate(&s, Z_NO_FLUSH);
    if (ret == Z_STREAM_END) break;
    if (ret != Z_OK && ret != Z_BUF_ERROR) corrupt("inflate fails when reading back a span");
    if (s.avail_in == in_before && s.avail_out == out_before) {  // needs input
      const size_t got = read_raw(in_pos, in.data(), size_t(std::min<uint64_t>(kChunk, comp_size_ - std::min(comp_size_, in_pos))));
      if (got == 0) corrupt("its deflate data ends early");
      in_pos += got;
      s.avail_in = uInt(got);
      s.next_in = in.data();
    }
  }
  if (s.avail_out > 0) corrupt("a span inflates short");
  cache_.push_front(std::move(sp));
  if (cache_.size() > kCachedSpans) cache_.pop_back();
  return cache_.front();
}

size_t ZipMemberSource::read_at(uint64_t offset, void* dst, size_t n) {
  if (offset >= size_) return 0;
  n = size_t(std::min<uint64_t>(n, size_ - offset));
  if (stored_) return read_raw(offset, dst, n);
  size_t done = 0;
  while (done < n) {
    const uint64_t at = offset + done;
    const auto it = std::upper_bound(points_.begin(), points_.end(), at,
                                     [](uint64_t v, const AccessPoint& p) { return v < p.out; });
    const size_t k = size_t(it - points_.begin()) - 1;
    const Span& sp = span(k);
    const uint64_t begin = points_[k].out;
    const size_t take = size_t(std::min<uint64_t>(n - done, begin + sp.bytes.size() - at));
    std::memcpy(static_cast<uint8_t*>(dst) + done, sp.bytes.data() + (at - begin), take);
    done += take;
  }
  return done;
}

// ---- the archive ------------------------------------------------------------------------------

NpzArchive::NpzArchive(const std::string& path, const uint8_t* data, size_t size) : path_(path) {
  if (data) {
    zip_error_t ze;
    zip_error_init(&ze);
    zip_source_t* zs = zip_source_buffer_create(data, size, 0, &ze);
    if (!zs) throw IoError(path + ": cannot read the .npz bytes");
    z_ = zip_open_from_source(zs, ZIP_RDONLY, &ze);
    if (!z_) {
      zip_source_free(zs);
      const std::string msg = zip_error_strerror(&ze);
      zip_error_fini(&ze);
      throw DataError(path + ": not a readable .npz (zip) file: " + msg);
    }
    zip_error_fini(&ze);
  } else {
    int err = 0;
    z_ = zip_open(path.c_str(), ZIP_RDONLY, &err);
    if (!z_) {
      zip_error_t ze;
      zip_error_init_with_code(&ze, err);
      const std::string msg = zip_error_strerror(&ze);
      zip_error_fini(&ze);
      throw DataError(path + ": not a readable .npz (zip) file: " + msg);
    }
  }
  const zip_int64_t count = zip_get_num_entries(z_, 0);
  for (zip_int64_t i = 0; i < count; ++i) {
    const char* n = zip_get_name(z_, zip_uint64_t(i), 0);
    if (!n) continue;
    std::string name = n;
    if (name.size() > 4 && name.compare(name.size() - 4, 4, ".npy") == 0) name.resize(name.size() - 4);
    members_.emplace_back(name, zip_uint64_t(i));
  }
}

NpzArchive::~NpzArchive() {
  open_.clear();  // member files before the archive
  if (z_) zip_discard(z_);
}

ZipMemberSource& NpzArchive::member(const std::string& key) {
  for (auto& [k, src] : open_)
    if (k == key) return *src;
  for (const auto& [name, index] : members_)
    if (name == key) {
      open_.emplace_back(key, std::make_unique<ZipMemberSource>(z_, index, path_, key));
      return *open_.back().second;
    }
  throw DataError(path_ + ": no array '" + key + "'");
}

}  // namespace vkunroll::detail
