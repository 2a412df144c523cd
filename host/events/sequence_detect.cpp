// Sequence layout detection. A layout whose timing is a convention (Gev-RS's 200 us rows, DRE's
// 70 us line delay, Fastec's 2400 fps) is chosen only when the folder is unambiguously that
// dataset: its event file must hold that dataset's own layout. A generic sequence whose meta.json
// was deleted (rs/, gs/, an events/{t,x,y,p} HDF5) is refused, never read with Gev-RS timing.
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <regex>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll {
namespace fs = std::filesystem;

namespace {

const std::vector<std::string> kImages = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"};

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

size_t count_files(const fs::path& dir, const std::vector<std::string>& exts, std::vector<std::string>* names = nullptr) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return 0;
  size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (!e.is_regular_file(ec)) continue;
    if (std::find(exts.begin(), exts.end(), lower(e.path().extension().string())) == exts.end()) continue;
    ++n;
    if (names) names->push_back(e.path().string());
  }
  if (names) std::sort(names->begin(), names->end());
  return n;
}

// What a folder holds, for the rules and for the message when none applies.
struct Survey {
  fs::path root;
  size_t rs = 0, gs = 0, RS = 0, GS = 0, images = 0, image = 0;  // images in rs/, gs/, RS/, GS/, images/, image/
  std::vector<std::string> h5, npz, npz_events;                  // top-level .h5, .npz; events/*.npz
  std::vector<std::string> found;                                // "rs/ (3 images)", "events.h5 (...)"

  bool has(const char* sub) const {
    std::error_code ec;
    return fs::is_directory(root / sub, ec);
  }
};

std::string h5_layout_of(const std::string& path, std::string& described) {
  std::string kind;
  try {
    kind = hdf5_event_layout(path);
  } catch (const Error& e) {
    described = "not a readable HDF5 event file";
    return "";
  }
  if (kind == "events") described = "events/{t,x,y,p}: the project's own layout, i.e. a generic sequence";
  else if (kind == "dsec") described = "DSEC's events/{x,y,p,t} + t_offset";
  else if (kind == "gevrs") described = "Gev-RS's N x 4 'events' + 'img_to_idx'";
  else if (kind == "v2e") described = "an N x 4 'events' dataset without Gev-RS's 'img_to_idx'";
  else if (kind == "dre") described = "top-level x, y, p, t (DRE)";
  else described = "no event datasets";
  return kind;
}

Survey survey(const fs::path& root) {
  Survey s;
  s.root = root;
  // Case matters on Linux: rs/ and RS/ are different folders and the datasets differ in case.
  s.rs = count_files(root / "rs", kImages);
  s.gs = count_files(root / "gs", kImages);
  s.RS = count_files(root / "RS", kImages);
  s.GS = count_files(root / "GS", kImages);
  s.images = count_files(root / "images", kImages);
  s.image = count_files(root / "image", kImages);
  for (const auto& [n, dir] : {std::pair<size_t, const char*>{s.rs, "rs"}, {s.gs, "gs"}, {s.RS, "RS"}, {s.GS, "GS"},
                               {s.images, "images"}, {s.image, "image"}})
    if (s.has(dir)) s.found.push_back(std::string(dir) + "/ (" + std::to_string(n) + " images)");
  count_files(root, {".h5", ".hdf5"}, &s.h5);
  count_files(root, {".npz"}, &s.npz);
  count_files(root / "events", {".npz"}, &s.npz_events);
  if (!s.npz.empty()) s.found.push_back(std::to_string(s.npz.size()) + " .npz file(s)");
  if (!s.npz_events.empty()) s.found.push_back("events/ with " + std::to_string(s.npz_events.size()) + " .npz files");
  for (const char* f : {"events.txt", "summary.json"})
    if (fs::exists(root / f)) s.found.push_back(f);
  return s;
}

}  // namespace

SequenceLayout detect_sequence_layout(const std::string& path) {
  const fs::path root(path);
  std::error_code ec;
  if (!fs::is_directory(root, ec)) throw Error(path + ": not a folder (a sequence is a folder)", fs::exists(root, ec) ? ErrorKind::data : ErrorKind::input_missing);
  if (fs::exists(root / "meta.json", ec)) return SequenceLayout::generic;
  Survey s = survey(root);
  std::vector<std::string> why;  // why each dataset does not apply
  std::string h5_kind, h5_desc;
  if (s.h5.size() == 1) {
    h5_kind = h5_layout_of(s.h5[0], h5_desc);
    s.found.push_back(fs::path(s.h5[0]).filename().string() + " (" + h5_desc + ")");
  } else if (s.h5.size() > 1) {
    s.found.push_back(std::to_string(s.h5.size()) + " HDF5 files");
  }
  // Gev-RS: rs/ + gs/ + one HDF5 with Gev-RS's own event layout.
  if (s.rs && s.gs && h5_kind == "gevrs") return SequenceLayout::gev_rs;
  if (s.rs || s.gs)
    why.push_back("Gev-RS needs rs/, gs/ and one .h5 holding an N x 4 'events' dataset with 'img_to_idx'");
  // DRE: images/ + one HDF5 with top-level x, y, p, t and the frames' start/end timestamps.
  if (s.images && h5_kind == "dre") {
    try {
      const ImageTimestamps ts = read_image_timestamps(s.h5[0]);
      if (!ts.start_image_ts.empty() && !ts.end_image_ts.empty()) return SequenceLayout::dre;
    } catch (const Error&) {
    }
    why.push_back("DRE needs start_image_ts and end_image_ts in " + fs::path(s.h5[0]).filename().string());
  } else if (s.images) {
    why.push_back("DRE needs images/ and one .h5 with top-level x, y, p, t, start_image_ts, end_image_ts");
  }
  // Gev-RS-Real: <id>_<exposure_us>_<readout_us>/ with image/ and one .npz (timing from the name).
  static const std::regex real_name(R"(^.+_\d+_\d+$)");
  if (s.image && s.npz.size() + s.npz_events.size() == 1 && std::regex_match(root.filename().string(), real_name))
    return SequenceLayout::gev_rs_real;
  if (s.image)
    why.push_back("Gev-RS-Real needs a folder named <id>_<exposure_us>_<readout_us> with image/ and one .npz");
  // Fastec-RS: RS/ + one .npz of events per frame (one more or less allowed).
  const size_t frames = s.RS ? s.RS : s.rs, files = s.npz_events.empty() ? s.npz.size() : s.npz_events.size();
  if (frames && files && files + 1 >= frames && files <= frames + 1) return SequenceLayout::fastec;
  if (frames)
    why.push_back("Fastec-RS needs RS/ and one .npz of events per frame (" + std::to_string(frames) + " frames, " +
                  std::to_string(files) + " .npz files)");
  std::string msg = path + ": cannot tell the layout: there is no meta.json (the generic layout, "
                    "sequence-format.md)";
  msg += s.found.empty() ? "; the folder holds no frame folders or event files" : "; found ";
  for (size_t i = 0; i < s.found.size(); ++i) msg += (i ? ", " : "") + s.found[i];
  for (const auto& w : why) msg += "; " + w;
  if (h5_kind == "events") msg += ". This looks like a generic sequence whose meta.json is missing: restore it";
  const std::string layout = opt("layout");
  msg += ". A reference dataset's timing is a convention, so it is not guessed: choose it with " + layout + " gev-rs (200 us "
         "line delay, 3200 us exposure), " + layout + " dre, " + layout + " gev-rs-real or " + layout + " fastec "
         "(SequenceOptions::layout), or write a meta.json";
  throw DataError(msg);
}

}  // namespace vkunroll
