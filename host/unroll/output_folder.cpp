#include "vkunroll/host/unroll/output_folder.hpp"

#include <fcntl.h>
#include <stdio.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <climits>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <optional>
#include <set>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/unroll/sha256.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

constexpr const char* kLockName = ".lock";

std::string errno_text(int e) { return std::strerror(e); }

[[noreturn]] void io_fail(const std::string& path, const std::string& what, int e) {
  throw IoError(path + ": " + what + " (" + errno_text(e) + ")");
}

// Writes all of `bytes` to fd (short writes retried); false with errno set on failure.
bool write_all(int fd, const char* p, size_t n) {
  while (n) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    p += w, n -= static_cast<size_t>(w);
  }
  return true;
}

void fsync_path(const fs::path& p, bool directory) {
  const int fd = ::open(p.c_str(), (directory ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);  // best effort for folders (some filesystems refuse fsync on them)
  ::close(fd);
}

std::string host_name() {
  char buf[256] = {};
  if (::gethostname(buf, sizeof buf - 1) != 0) return "?";
  return buf;
}

// The list of what a committed output holds (relative paths, one a line), written at commit.
constexpr const char* kManifestName = ".vkunroll-manifest";
constexpr const char* kManifestHeader = "# vkunroll output manifest 1: the files this output holds";

// The files a folder's manifest lists; none when it has no manifest (an output from before them).
std::optional<std::set<std::string>> read_manifest(const fs::path& dir) {
  std::error_code ec;
  if (!fs::exists(dir / kManifestName, ec)) return std::nullopt;
  std::set<std::string> files;  // an unreadable manifest lists nothing: everything is refused
  std::ifstream in(dir / kManifestName);
  std::string line;
  while (std::getline(in, line))
    if (!line.empty() && line[0] != '#') files.insert(line);
  return files;
}

// A folder is listed when a listed file lies inside it.
bool listed_folder(const std::set<std::string>& listed, const std::string& dir) {
  const std::string prefix = dir + "/";
  auto it = listed.lower_bound(prefix);
  return it != listed.end() && it->compare(0, prefix.size(), prefix) == 0;
}

bool is_empty_dir(const fs::path& p) {
  std::error_code ec;
  return fs::is_directory(p, ec) && fs::directory_iterator(p, ec) == fs::directory_iterator();
}

}  // namespace

const char* existing_output_name(ExistingOutput e) {
  switch (e) {
    case ExistingOutput::refuse: return "refuse";
    case ExistingOutput::overwrite: return "overwrite";
    case ExistingOutput::resume: return "resume";
  }
  return "?";
}

const OutputLayout& unroll_output_layout() {
  static const OutputLayout layout = {
      {"frames", "gs_video.mp4", "contact_sheet.png", "metrics.csv", "summary.json", "frames.jsonl"}, {"frames"}, {"frames"}, true};
  return layout;
}

const OutputLayout& sequence_output_layout() {
  static const OutputLayout layout = {{"meta.json", "rs", "gs", "events.h5", "events.txt"}, {"rs", "gs"}, {}, false, false};
  return layout;
}

std::string enclosing_output_folder(const std::string& path) {
  std::error_code ec;
  const fs::path p = fs::absolute(path, ec).lexically_normal();
  if (ec) return {};
  for (fs::path d = p.parent_path(); !d.empty(); d = d.parent_path()) {
    if (fs::exists(d / kManifestName, ec)) return d.string();
    if (d == d.root_path()) break;
  }
  return {};
}

void check_written_sequence(const std::string& staging, const std::string& shown, const std::string& events_topic) {
  try {
    SequenceOptions so;
    so.layout = SequenceLayout::generic;
    so.events.events_topic = events_topic;
    const Sequence seq = load_sequence(staging, so);
    const RowTiming& first = seq.frames.front().timing;
    EventReadReport report;
    (void)seq.read_events(INT64_MIN, int64_t(std::ceil(first.last_end().to_double())) + 1, &report);
    if (!report.size_disagreement.empty()) throw DataError(report.size_disagreement);
  } catch (const Error& e) {
    std::string m = e.what();
    for (size_t at; (at = m.find(staging)) != std::string::npos;) m.replace(at, staging.size(), shown);
    throw DataError(shown + ": the sequence written would not load, so nothing was committed: " + m);
  }
}

std::string sha256_file(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) io_fail(path.string(), "cannot open for reading", errno);
  Sha256 h;
  char buf[1 << 16];
  while (true) {
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int e = errno;
      ::close(fd);
      io_fail(path.string(), "read failed", e);
    }
    if (n == 0) break;
    h.update(buf, static_cast<size_t>(n));
  }
  ::close(fd);
  return h.hex();
}

OutputFolder::OutputFolder(fs::path final_dir, ExistingOutput existing, const OutputPath& spec, const OutputLayout* layout)
    : field_(spec.field), existing_(existing), layout_(layout ? *layout : spec.layout ? *spec.layout() : unroll_output_layout()) {
  if (spec.shape != OutputShape::folder) throw std::logic_error(std::string("output path '") + spec.id + "' is not a folder");
  std::string text = final_dir.string();
  while (text.size() > 1 && text.back() == '/') text.pop_back();
  if (text.empty()) throw OptionError(field_, "", "empty folder name");
  final_ = fs::absolute(fs::path(text)).lexically_normal();
  const std::string name = final_.filename().string();
  if (name.empty() || name == "." || name == "..")
    throw OptionError(field_, "'" + final_dir.string() + "'", "name a folder to create (not '.', '..' or '/')");
  staging_ = final_.parent_path() / ("." + name + ".partial");
  std::error_code ec;
  // A file where a folder of the path must be is the option's fault (exit 2), not an I/O error.
  for (fs::path p = final_.parent_path(); !p.empty() && p != p.root_path(); p = p.parent_path()) {
    const auto st = fs::status(p, ec);
    if (!fs::exists(st)) continue;
    if (!fs::is_directory(st))
      throw OptionError(field_, final_dir.string(), p.string() + " exists and is not a folder");
    break;
  }
  fs::create_directories(final_.parent_path(), ec);
  if (ec) throw IoError(final_.parent_path().string() + ": cannot create the output's parent folder (" + ec.message() + ")");
  lock();
  try {
    check_final();
    if (existing_ != ExistingOutput::resume) clear_staging();
    for (const auto& dir : layout_.make) {
      fs::create_directories(staging_ / dir, ec);
      if (ec) throw IoError(staging_.string() + ": cannot create the staging folder (" + ec.message() + ")");
    }
  } catch (...) {
    // A staging folder made only for this attempt goes; a killed run's files stay for --resume.
    std::error_code ec2;
    bool only_lock = true;
    for (const auto& e : fs::directory_iterator(staging_, ec2)) only_lock = only_lock && e.path().filename() == kLockName;
    if (only_lock) fs::remove_all(staging_, ec2);
    ::close(lock_fd_);
    lock_fd_ = -1;
    throw;
  }
}

void OutputFolder::lock() {
  const fs::path lock_path = staging_ / kLockName;
  for (int attempt = 0; attempt < 100; ++attempt) {
    if (::mkdir(staging_.c_str(), 0755) != 0 && errno != EEXIST) io_fail(staging_.string(), "cannot create the staging folder", errno);
    const int fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) {
      if (errno == ENOENT) continue;  // the folder was renamed away meanwhile (a run committed)
      io_fail(lock_path.string(), "cannot open the lock file", errno);
    }
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      char who[512] = {};
      const ssize_t n = ::pread(fd, who, sizeof who - 1, 0);
      ::close(fd);
      std::string holder = n > 0 ? std::string(who, static_cast<size_t>(n)) : std::string("unknown");
      while (!holder.empty() && holder.back() == '\n') holder.pop_back();
      throw OutputBusyError(final_.string() + ": another vkunroll run is writing this output (" + holder +
                            "); wait for it to finish or choose another " + opt(field_));
    }
    // The lock file must still be the one at the path (not one a committing run just unlinked).
    struct stat a {}, b {};
    if (::fstat(fd, &a) != 0 || ::stat(lock_path.c_str(), &b) != 0 || a.st_ino != b.st_ino || a.st_dev != b.st_dev) {
      ::close(fd);
      continue;
    }
    const std::string who = "pid " + std::to_string(::getpid()) + " on " + host_name() + ", since " +
                            std::to_string(static_cast<long long>(std::time(nullptr))) + " (Unix s)\n";
    if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, who.data(), who.size(), 0) < 0) {
      const int e = errno;
      ::close(fd);
      io_fail(lock_path.string(), "cannot write the lock file", e);
    }
    lock_fd_ = fd;
    return;
  }
  throw OutputBusyError(final_.string() + ": could not take the output's lock (other runs keep committing into it)");
}

void OutputFolder::check_final() {
  std::error_code ec;
  const auto st = fs::symlink_status(final_, ec);
  if (!fs::exists(st)) return;
  if (!fs::is_directory(st))
    throw OptionError(field_, final_.string(),
                      std::string("exists and is not a folder (") +
                          (fs::is_symlink(st) ? "a symbolic link" : fs::is_regular_file(st) ? "a file" : "a device, FIFO or socket") + ")");
  if (is_empty_dir(final_)) return;
  if (existing_ == ExistingOutput::refuse)
    throw OptionError(field_, final_.string(),
                      "the folder exists and is not empty; " + opt("overwrite") + " replaces it (only what vkunroll wrote is replaced)" +
                          std::string(layout_.resumable ? ", or " + opt("resume") + " continues it (its valid GS frames are kept)" : ""));
  // Everything inside, at any depth, must be what vkunroll wrote there: listed in the folder's
  // manifest, or (an output from before manifests) one of the output's names, frames/ holding only PNGs.
  const std::optional<std::set<std::string>> listed = read_manifest(final_);
  const bool has_manifest = listed.has_value();
  if (!has_manifest && !layout_.by_names_without_manifest)
    throw OptionError(field_, final_.string(),
                      std::string("holds no ") + kManifestName + ", so vkunroll cannot tell that it wrote what is there; refusing "
                          "to replace the folder (move it away or choose another " + opt(field_) + ")");
  const auto& names = layout_.names;
  const auto& pngs = layout_.png_folders;
  for (auto it = fs::recursive_directory_iterator(final_, ec); !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const fs::path rel = it->path().lexically_relative(final_);
    const std::string r = rel.string();
    const bool dir = it->is_directory(ec) && !it->is_symlink(ec);
    bool ours;
    if (has_manifest) ours = r == kManifestName || (dir ? listed_folder(*listed, r) : listed->count(r) > 0);
    else if (rel.has_parent_path())
      ours = !dir && rel.extension() == ".png" && std::find(pngs.begin(), pngs.end(), rel.parent_path().string()) != pngs.end();
    else ours = std::find(names.begin(), names.end(), r) != names.end();
    if (!ours)
      throw OptionError(field_, final_.string(),
                        "holds '" + r + "', which vkunroll did not write there" +
                            (has_manifest ? " (not in its " + std::string(kManifestName) + ")" : "") +
                            "; refusing to replace the folder (move it away or choose another " + opt(field_) + ")");
  }
  if (ec) throw IoError(final_.string() + ": cannot list the earlier output (" + ec.message() + ")");
  replaces_ = true;
}

void OutputFolder::clear_staging() const {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(staging_, ec)) {
    if (e.path().filename() == kLockName) continue;
    fs::remove_all(e.path(), ec);
    if (ec) throw IoError(e.path().string() + ": cannot remove a stale staged file (" + ec.message() + ")");
  }
}

OutputFolder::~OutputFolder() {
  if (append_fd_ >= 0) ::close(append_fd_);
  if (!committed_ && lock_fd_ >= 0 && existing_ != ExistingOutput::resume) {
    std::error_code ec;
    fs::remove_all(staging_, ec);  // nothing of a failed run stays behind (--resume keeps it)
  }
  if (lock_fd_ >= 0) ::close(lock_fd_);
}

void OutputFolder::write(const std::string& rel, std::string_view bytes) const {
  const fs::path target = staging_ / rel;
  const fs::path tmp = target.parent_path() / ("." + target.filename().string() + ".tmp-" + std::to_string(::getpid()));
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) io_fail(shown(rel), "cannot create", errno);
  if (!write_all(fd, bytes.data(), bytes.size()) || ::fsync(fd) != 0) {
    const int e = errno;
    ::close(fd);
    ::unlink(tmp.c_str());
    io_fail(shown(rel), "cannot write " + std::to_string(bytes.size()) + " bytes", e);
  }
  if (::close(fd) != 0) {
    const int e = errno;
    ::unlink(tmp.c_str());
    io_fail(shown(rel), "cannot write (close failed)", e);
  }
  if (::rename(tmp.c_str(), target.c_str()) != 0) {
    const int e = errno;
    ::unlink(tmp.c_str());
    io_fail(shown(rel), "cannot rename the written file into place", e);
  }
}

void OutputFolder::append_line(const std::string& rel, const std::string& line) {
  if (append_fd_ < 0 || append_rel_ != rel) {
    if (append_fd_ >= 0) ::close(append_fd_);
    append_fd_ = ::open((staging_ / rel).c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (append_fd_ < 0) io_fail(shown(rel), "cannot open for appending", errno);
    append_rel_ = rel;
  }
  const std::string l = line + "\n";
  if (!write_all(append_fd_, l.data(), l.size())) io_fail(shown(rel), "cannot append", errno);
}

void OutputFolder::adopt(const fs::path& src, const std::string& rel) const {
  const fs::path target = staging_ / rel;
  std::error_code ec;
  if (fs::equivalent(src, target, ec)) return;
  fs::remove(target, ec);
  fs::create_hard_link(src, target, ec);
  if (!ec) return;
  fs::copy_file(src, target, fs::copy_options::overwrite_existing, ec);
  if (ec) throw IoError(shown(rel) + ": cannot bring in the earlier output's " + src.string() + " (" + ec.message() + ")");
}

void OutputFolder::prune(const std::vector<std::string>& keep) const {
  const std::set<std::string> wanted(keep.begin(), keep.end());
  std::error_code ec;
  std::vector<fs::path> extra;
  for (const auto& e : fs::recursive_directory_iterator(staging_, ec)) {
    const std::string rel = e.path().lexically_relative(staging_).string();
    if (rel != kLockName && !e.is_directory() && !wanted.count(rel)) extra.push_back(e.path());
  }
  for (const auto& p : extra) fs::remove(p, ec);
  for (const auto& e : fs::directory_iterator(staging_, ec))  // folders this run made no use of
    if (e.is_directory() && !wanted.count(e.path().filename().string()) && is_empty_dir(e.path())) fs::remove(e.path(), ec);
}

void OutputFolder::write_manifest() const {
  // Everything staged is this run's (the staging folder starts empty, or with a killed run's own files).
  std::string text = std::string(kManifestHeader) + "\n";
  std::vector<std::string> files;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(staging_, ec); !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const std::string rel = it->path().lexically_relative(staging_).string();
    if (rel != kLockName && rel != kManifestName && !it->is_directory(ec)) files.push_back(rel);
  }
  if (ec) throw IoError(staging_.string() + ": cannot list the staged output (" + ec.message() + ")");
  std::sort(files.begin(), files.end());
  for (const auto& f : files) text += f + "\n";
  write(kManifestName, text);
}

void OutputFolder::commit() {
  if (committed_) return;
  if (append_fd_ >= 0) {
    ::fsync(append_fd_);
    ::close(append_fd_);
    append_fd_ = -1;
  }
  write_manifest();
  for (const auto& dir : layout_.make) fsync_path(staging_ / dir, true);
  fsync_path(staging_, true);
  // The lock file stays out of the final folder; the lock itself is held until the rename is done.
  ::unlink((staging_ / kLockName).c_str());
  std::error_code ec;
  const bool final_exists = fs::exists(fs::symlink_status(final_, ec));
  if (!final_exists) {
    if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, final_.c_str(), RENAME_NOREPLACE) != 0) {
      if (errno != EINVAL && errno != ENOSYS) io_fail(final_.string(), "cannot rename the staged output into place", errno);
      if (::rename(staging_.c_str(), final_.c_str()) != 0) io_fail(final_.string(), "cannot rename the staged output into place", errno);
    }
  } else if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, final_.c_str(), RENAME_EXCHANGE) == 0) {
    fs::remove_all(staging_, ec);  // now the old output
  } else {
    // No atomic exchange on this filesystem: move the old output aside first.
    const fs::path old = final_.parent_path() / ("." + final_.filename().string() + ".old-" + std::to_string(::getpid()));
    if (::rename(final_.c_str(), old.c_str()) != 0) io_fail(final_.string(), "cannot move the old output aside", errno);
    if (::rename(staging_.c_str(), final_.c_str()) != 0) io_fail(final_.string(), "cannot rename the staged output into place", errno);
    fs::remove_all(old, ec);
  }
  fsync_path(final_.parent_path(), true);
  committed_ = true;
  ::close(lock_fd_);
  lock_fd_ = -1;
}

}  // namespace vkunroll
