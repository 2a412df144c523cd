#include "vkunroll/host/events/sequence.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numeric>
#include <opencv2/imgcodecs.hpp>
#include <regex>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/json_read.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/meta_schema.hpp"

namespace vkunroll {
namespace fs = std::filesystem;
namespace {

// Natural order: "2.png" < "10.png", so numbered frames without zero padding sort right.
bool natural_less(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (std::isdigit(static_cast<unsigned char>(a[i])) && std::isdigit(static_cast<unsigned char>(b[j]))) {
      size_t i2 = i, j2 = j;
      while (i2 < a.size() && std::isdigit(static_cast<unsigned char>(a[i2]))) ++i2;
      while (j2 < b.size() && std::isdigit(static_cast<unsigned char>(b[j2]))) ++j2;
      std::string na = a.substr(i, i2 - i), nb = b.substr(j, j2 - j);
      na.erase(0, std::min(na.find_first_not_of('0'), na.size()));
      nb.erase(0, std::min(nb.find_first_not_of('0'), nb.size()));
      if (na.size() != nb.size()) return na.size() < nb.size();
      if (na != nb) return na < nb;
      i = i2;
      j = j2;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// Files in `dir` whose extension (lower case, with dot) is one of `exts`, natural order.
std::vector<std::string> list_files(const fs::path& dir, const std::vector<std::string>& exts) {
  std::vector<std::string> out;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return out;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    const std::string ext = lower(e.path().extension().string());
    if (std::find(exts.begin(), exts.end(), ext) != exts.end()) out.push_back(e.path().string());
  }
  std::sort(out.begin(), out.end(), [](const std::string& a, const std::string& b) {
    return natural_less(fs::path(a).filename().string(), fs::path(b).filename().string());
  });
  return out;
}

const std::vector<std::string> kImageExts = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"};

// The first existing subfolder among `names`.
std::optional<fs::path> subdir(const fs::path& root, std::initializer_list<const char*> names) {
  std::error_code ec;
  for (const char* n : names)
    if (fs::is_directory(root / n, ec)) return root / n;
  return std::nullopt;
}

Rational json_time(const nlohmann::json& j, const std::string& where) {
  if (j.is_number_unsigned() && j.get<uint64_t>() > uint64_t(INT64_MAX))
    throw DataError(where + " = " + j.dump() + " us is beyond int64 microseconds");
  if (j.is_number()) {
    try {
      return j.is_number_integer() ? Rational(j.get<int64_t>()) : Rational::from_double(j.get<double>());
    } catch (const Error&) {
      throw DataError(where + " = " + j.dump() + " us is out of range (not representable as an exact time)");
    }
  }
  if (j.is_string()) return Rational::parse(j.get<std::string>(), where);
  throw DataError(where + " must be a number (or an exact string like \"73000/259\"), got " + std::string(j.type_name()) +
              " " + j.dump());
}

std::string resolve(const fs::path& root, const std::string& rel) {
  fs::path p(rel);
  return (p.is_absolute() ? p : root / p).lexically_normal().string();
}

std::string one_file(const fs::path& root, const std::vector<std::string>& exts, const std::string& what) {
  auto files = list_files(root, exts);
  if (files.empty()) throw DataError(root.string() + ": no " + what + " file found");
  if (files.size() > 1)
    throw DataError(root.string() + ": " + std::to_string(files.size()) + " " + what + " files found, expected one (" +
                fs::path(files[0]).filename().string() + ", " + fs::path(files[1]).filename().string() + ", ...)");
  return files[0];
}

// meta.json is validated against the schema (meta_schema.cpp) first; what follows reads it.
void load_generic(Sequence& s, const fs::path& root) {
  const std::string meta_path = (root / "meta.json").string();
  std::ifstream in(meta_path);
  if (!in) throw InputMissingError(root.string() + ": no meta.json (generic layout, see sequence-format.md)");
  nlohmann::json m = parse_json<nlohmann::json>(in, meta_path);  // invalid or a repeated key: DataError
  s.warnings = validate_meta(m, meta_path);
  s.width = m["width"].get<int>();
  s.height = m["height"].get<int>();
  const Rational delay = json_time(m["line_delay_us"], meta_path + ":line_delay_us");
  const Rational exposure = json_time(m["exposure_us"], meta_path + ":exposure_us");
  const Readout readout = m.contains("readout") ? parse_readout(m["readout"].get<std::string>()) : Readout::top_down;
  const auto& frames = m["frames"];
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = meta_path + ":frames[" + std::to_string(i) + "]";
    const auto& f = frames[i];
    SequenceFrame fr;
    fr.image = resolve(root, f["file"].get<std::string>());
    fr.timing.t0 = json_time(f["t0_us"], where + ".t0_us");
    fr.timing.line_delay = delay;
    // Extension: a frame may carry its own exposure (e.g. converted DRE recordings).
    fr.timing.exposure = f.contains("exposure_us") ? json_time(f["exposure_us"], where + ".exposure_us") : exposure;
    fr.timing.rows = s.height;
    fr.timing.readout = readout;
    s.frames.push_back(fr);
  }
  s.event_files.push_back(resolve(root, m["events"].get<std::string>()));
  // Extension: a ROS bag's event topic (vkunroll bag-sequence writes it); an --events-topic wins.
  if (m.contains("events_topic") && s.event_options.events_topic.empty())
    s.event_options.events_topic = m["events_topic"].get<std::string>();
  if (m.contains("ground_truth")) {
    const auto& g = m["ground_truth"];
    for (size_t i = 0; i < g.size(); ++i)
      s.ground_truth.push_back({resolve(root, g[i]["file"].get<std::string>()),
                                json_time(g[i]["t_us"], meta_path + ":ground_truth[" + std::to_string(i) + "].t_us")});
  }
  s.notes.push_back("generic layout: timing from meta.json");
}

void sensor_from_first_image(Sequence& s, const std::vector<std::string>& images, const std::string& folder) {
  if (images.empty()) throw DataError(folder + ": no frame images found");
  const auto [w, h] = image_size(images[0]);
  s.width = w;
  s.height = h;
}

void load_gev_rs(Sequence& s, const fs::path& root, const SequenceOptions& o) {
  const auto rs = subdir(root, {"rs", "RS"});
  if (!rs) throw DataError(root.string() + ": no rs/ folder (Gev-RS layout)");
  const auto images = list_files(*rs, kImageExts);
  sensor_from_first_image(s, images, rs->string());
  s.event_files.push_back(one_file(root, {".h5", ".hdf5"}, "HDF5 event"));
  // GS frames at 5000 fps (200 us); RS frame k starts at GS frame 100k; row step one GS period
  // and exposure 16 GS frames, or half-row steps (100 us) and 8 frames.
  const Rational gs_period(200);
  const Rational delay = o.gev_half_row ? Rational(100) : gs_period;
  const Rational exposure = gs_period * Rational(o.gev_half_row ? 8 : 16);
  for (size_t k = 0; k < images.size(); ++k)
    s.frames.push_back({images[k], {gs_period * Rational(100 * static_cast<int64_t>(k)), delay, exposure, s.height,
                                    Readout::top_down}});
  if (const auto gs = subdir(root, {"gs", "GS"})) {
    const auto g = list_files(*gs, kImageExts);
    for (size_t i = 0; i < g.size(); ++i) s.ground_truth.push_back({g[i], gs_period * Rational(static_cast<int64_t>(i))});
  }
  s.notes.push_back(std::string("Gev-RS: GS frame i at i*200 us (event time origin 0), RS frame k t0 = 20000k us, ") +
                    (o.gev_half_row ? "half-row variant: line delay 100 us, exposure 1600 us"
                                    : "line delay 200 us, exposure 3200 us"));
}

void load_gev_rs_real(Sequence& s, const fs::path& root, const SequenceOptions& o) {
  static const std::regex name_re(R"(^(.+)_(\d+)_(\d+)$)");
  const std::string name = root.filename().string();
  std::smatch mt;
  if (!std::regex_match(name, mt, name_re))
    throw DataError(root.string() + ": Gev-RS-Real folders are named <id>_<exposure_us>_<readout_us>, got '" + name + "'");
  const Rational exposure = Rational::parse(mt[2].str(), "folder exposure"),
                 readout = Rational::parse(mt[3].str(), "folder readout");
  const auto img = subdir(root, {"image", "images"});
  if (!img) throw DataError(root.string() + ": no image/ folder (Gev-RS-Real layout)");
  const auto images = list_files(*img, kImageExts);
  sensor_from_first_image(s, images, img->string());
  s.event_files.push_back(one_file(root, {".npz"}, "NumPy .npz event"));
  if (s.height < 2) throw DataError(root.string() + ": frames must have at least 2 rows");
  const Rational delay = readout / Rational(s.height - 1);
  // Frame times: the reference gives the rate (about 20.79 fps, 19.61 for two folders), not the
  // t0s. Origin: the first event; period: the option, else whichever of the two rates best fits
  // the recording's event span / frame count.
  Rational period = Rational(100000000, 2079);
  int64_t t_first = 0, t_last = 0;
  bool any = false;
  if (!o.t0s_us) {
    EventReadOptions ro = s.event_options;
    scan_events(s.event_files[0], ro, [&](const EventStream& c) {
      if (c.empty()) return;
      if (!any) t_first = c.t.front();
      t_last = c.t.back();
      any = true;
    });
  }
  if (o.frame_period_us) {
    period = *o.frame_period_us;
  } else if (any && images.size() > 1) {
    const double per = static_cast<double>(t_last - t_first) / static_cast<double>(images.size());
    const double p1 = 1e6 / 20.79, p2 = 1e6 / 19.61;
    if (std::abs(per - p2) < std::abs(per - p1)) period = Rational(100000000, 1961);
    s.notes.push_back("Gev-RS-Real: event span / frames = " + std::to_string(per) + " us per frame; using " +
                      (period == Rational(100000000, 1961) ? "19.61" : "20.79") + " fps");
  }
  for (size_t k = 0; k < images.size(); ++k)
    s.frames.push_back({images[k], {Rational(t_first) + period * Rational(static_cast<int64_t>(k)), delay, exposure,
                                    s.height, Readout::top_down}});
  s.notes.push_back("Gev-RS-Real: exposure " + exposure.str() + " us, line delay readout/(H-1) = " + delay.str() +
                    " us, frame k t0 = first event (" + std::to_string(t_first) + " us) + k * " + period.str() +
                    " us (inferred; override with t0s / frame period)");
}

void load_dre(Sequence& s, const fs::path& root) {
  const auto img = subdir(root, {"images", "image"});
  if (!img) throw DataError(root.string() + ": no images/ folder (DRE layout)");
  const auto images = list_files(*img, kImageExts);
  sensor_from_first_image(s, images, img->string());
  const std::string h5 = one_file(root, {".h5", ".hdf5"}, "HDF5 event");
  s.event_files.push_back(h5);
  const ImageTimestamps ts = read_image_timestamps(h5);
  if (ts.start_image_ts.empty() || ts.end_image_ts.empty())
    throw DataError(h5 + ": DRE needs start_image_ts and end_image_ts (exposure = end - start)");
  if (ts.start_image_ts.size() != ts.end_image_ts.size())
    throw DataError(h5 + ": start_image_ts has " + std::to_string(ts.start_image_ts.size()) + " entries, end_image_ts " +
                std::to_string(ts.end_image_ts.size()));
  if (ts.start_image_ts.size() != images.size())
    throw DataError(h5 + ": " + std::to_string(ts.start_image_ts.size()) + " frame timestamps but " +
                std::to_string(images.size()) + " images in " + img->string());
  for (size_t k = 0; k < images.size(); ++k) {
    const Rational st = Rational::from_double(ts.start_image_ts[k]), en = Rational::from_double(ts.end_image_ts[k]);
    if (en <= st)
      throw DataError(h5 + ": frame " + std::to_string(k) + " has end_image_ts " + en.str() + " <= start_image_ts " + st.str());
    s.frames.push_back({images[k], {st, Rational(70), en - st, s.height, Readout::top_down}});
  }
  s.notes.push_back("DRE: t0 = start_image_ts, exposure = end_image_ts - start_image_ts, line delay 70 us");
}

void load_fastec(Sequence& s, const fs::path& root, const SequenceOptions& o) {
  const auto rs = subdir(root, {"RS", "rs"});
  if (!rs) throw DataError(root.string() + ": no RS/ folder (Fastec-RS layout)");
  const auto images = list_files(*rs, kImageExts);
  sensor_from_first_image(s, images, rs->string());
  auto ev = list_files(root / "events", {".npz"});
  if (ev.empty()) ev = list_files(root, {".npz"});
  if (ev.empty()) throw DataError(root.string() + ": no per-frame .npz event files (Fastec-RS layout)");
  s.event_files = ev;
  // GS at 2400 fps (P = 1250/3 us); rows advance half a GS frame (625/3 us); a row's exposure is
  // one GS frame; RS frame k starts at GS frame step*k (260 by default).
  const Rational P(1250, 3);
  for (size_t k = 0; k < images.size(); ++k)
    s.frames.push_back({images[k], {P * Rational(static_cast<int64_t>(k) * o.fastec_frame_step_gs), P / Rational(2), P,
                                    s.height, Readout::top_down}});
  if (const auto gs = subdir(root, {"GS", "gs"})) {
    const auto g = list_files(*gs, kImageExts);
    for (size_t i = 0; i < g.size(); ++i) s.ground_truth.push_back({g[i], P * Rational(static_cast<int64_t>(i))});
  }
  s.notes.push_back("Fastec-RS (interpretation): GS period 1250/3 us, line delay 625/3 us (half a GS frame), "
                    "exposure 1250/3 us, frame k t0 = " + std::to_string(o.fastec_frame_step_gs) +
                    "k GS periods; override with line delay / exposure / t0s");
}

// Width, height and channels of a PNG (IHDR: colour type) or any image OpenCV reads.
ImageHeader image_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw DataError(path + ": cannot open image");
  unsigned char h[26] = {};
  in.read(reinterpret_cast<char*>(h), 26);
  static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (in.gcount() == 26 && std::equal(sig, sig + 8, h)) {
    if (std::string(reinterpret_cast<char*>(h + 12), 4) != "IHDR") throw DataError(path + ": PNG without IHDR chunk first");
    auto be32 = [&](int o) { return (uint32_t(h[o]) << 24) | (uint32_t(h[o + 1]) << 16) | (uint32_t(h[o + 2]) << 8) | h[o + 3]; };
    // Colour types 0 gray, 2 RGB, 3 palette (decoded as RGB), 4 gray + alpha, 6 RGBA.
    const int channels = h[25] == 0 ? 1 : h[25] == 4 ? 2 : h[25] == 6 ? 4 : 3;
    return {static_cast<int>(be32(16)), static_cast<int>(be32(20)), channels};
  }
  const cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (m.empty()) throw DataError(path + ": not a readable image");
  return {m.cols, m.rows, m.channels()};
}

// A frame or ground-truth image exists and (PNG) is not cut short: its last chunk is IEND. Only the
// header is decoded here; the pixels are read when the frame is used. Sizes and channels:
// rule_images_agree.
ImageHeader check_image(const Sequence& s, const std::string& image, const char* what) {
  std::error_code ec;
  if (!fs::exists(image, ec)) throw InputMissingError(s.root + ": " + what + " image '" + image + "' does not exist");
  if (fs::is_directory(image, ec)) throw DataError(image + ": " + what + " image is a folder");
  if (const std::string kind = special_file_kind(image); !kind.empty())
    throw DataError(image + ": " + what + " image is " + kind + ", expected a regular file");
  const ImageHeader header = image_header(image);
  if (const std::string problem = image_end_problem(image); !problem.empty())
    throw DataError(image + ": " + what + " image " + problem);
  return header;
}

// Where frame k's t0 came from, for messages.
std::string t0_source(const Sequence& s, size_t k, const SequenceOptions& o) {
  const std::string n = std::to_string(k);
  if (o.t0s_us) return "t0s value " + std::to_string(k + 1) + " (the " + opt("t0s_us") + " option, SequenceOptions::t0s_us)";
  switch (s.layout) {
    case SequenceLayout::generic: return (fs::path(s.root) / "meta.json").string() + ":frames[" + n + "].t0_us";
    case SequenceLayout::dre: return s.event_files.at(0) + ": start_image_ts[" + n + "]";
    default: return std::string(sequence_layout_name(s.layout)) + " frame " + n + "'s t0 (the layout's convention)";
  }
}

// Frame times must stay where int64 windows and float64 arithmetic are exact (|t| <= 2^53 us,
// about 285 years; Unix-time microseconds of today are about 1.7e15), and t0s must increase.
void check_frame_times(const Sequence& s, const SequenceOptions& o) {
  const Rational limit(int64_t(1) << 53);
  for (size_t k = 0; k < s.frames.size(); ++k) {
    const RowTiming& t = s.frames[k].timing;
    const std::string field = t0_source(s, k, o);
    Rational end;
    try {
      end = t.last_end();
    } catch (const Error&) {
      end = limit + Rational(1);  // beyond 120-bit arithmetic: certainly out of range
    }
    if (t.t0 < -limit || t.t0 > limit || end > limit || t.line_delay > limit || t.exposure > limit)
      throw DataError(field + ": frame " + std::to_string(k) + " (" + s.frames[k].image + ") has t0 " + t.t0.str() +
                  " us and ends at " + (end > limit ? std::string("more than 2^53") : end.str()) +
                  " us: frame times must lie within +-2^53 us (+-9007199254740992 us, about 285 years) so that event "
                  "windows and float64 times stay exact");
    if (k > 0 && t.t0 <= s.frames[k - 1].timing.t0)
      throw DataError(field + ": frame " + std::to_string(k) + " (" + s.frames[k].image + ") starts at t0 " + t.t0.str() +
                  " us, not after frame " + std::to_string(k - 1) + "'s t0 " + s.frames[k - 1].timing.t0.str() +
                  " us: frames must be in time order (t0s must increase; rule frames-in-time-order)");
  }
}

// The schema's cross-field rules (meta_schema.hpp). A reference dataset's timing is its own
// convention (Gev-RS rows overlap the next frame), so the timing rules hold for meta.json only.
void check_meta_rules(const Sequence& s, const SequenceOptions& o) {
  const std::string file = s.layout == SequenceLayout::generic ? (fs::path(s.root) / "meta.json").string() : s.root;
  rule_distinct_frame_files(s, file);
  if (s.layout != SequenceLayout::generic) return;
  const bool overridden = o.t0s_us || o.line_delay_us;
  try {
    rule_readout_within_frame_period(s, [&](size_t k) {
      return overridden ? opt("t0s_us") + "/" + opt("line_delay_us") + ":frame " + std::to_string(k) : t0_source(s, k, o);
    });
  } catch (const MetaSchemaError& e) {
    if (overridden) throw UsageError(e.text());  // the options' values, not meta.json's, break the rule
    throw;
  }
  // --t0s-us moves the frames, not meta.json's ground-truth instants: the rule is meta.json's own.
  if (!o.t0s_us) rule_ground_truth_inside_recording(s, file);
}

}  // namespace

std::string image_end_problem(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char sig[8] = {};
  in.read(reinterpret_cast<char*>(sig), 8);
  const bool png = in.gcount() == 8 && sig[0] == 0x89 && sig[1] == 'P' && sig[2] == 'N' && sig[3] == 'G';
  const bool jpeg = in.gcount() >= 3 && sig[0] == 0xFF && sig[1] == 0xD8 && sig[2] == 0xFF;
  if (!png && !jpeg) return "";
  std::error_code ec;
  const uint64_t size = fs::file_size(path, ec);
  if (ec) return "cannot be sized (" + ec.message() + ")";
  const uint64_t tail = std::min<uint64_t>(size, 64 << 10);
  std::string end(tail, '\0');
  in.clear();
  in.seekg(std::streamoff(size - tail));
  in.read(end.data(), std::streamsize(tail));
  if (png && end.find("IEND") == std::string::npos)
    return "is a truncated PNG (no IEND chunk at its end; " + std::to_string(size) + " bytes)";
  if (jpeg) {
    // Inside a scan every FF byte is stuffed (FF 00) or a restart marker, so FF D9 after the last
    // start of scan (FF DA) is the end of the image; an EXIF thumbnail's own EOI lies before it.
    const size_t sos = end.rfind("\xFF\xDA");
    if (end.find("\xFF\xD9", sos == std::string::npos ? 0 : sos) == std::string::npos)
      return "is a truncated JPEG (no end-of-image marker FF D9 after its last scan; " + std::to_string(size) + " bytes)";
  }
  return "";
}

ImageHeader check_sequence_image(const Sequence& s, const std::string& image, const char* what) {
  return check_image(s, image, what);
}

const char* sequence_layout_name(SequenceLayout l) {
  switch (l) {
    case SequenceLayout::automatic: return "auto";
    case SequenceLayout::generic: return "generic";
    case SequenceLayout::gev_rs: return "gev-rs";
    case SequenceLayout::gev_rs_real: return "gev-rs-real";
    case SequenceLayout::dre: return "dre";
    case SequenceLayout::fastec: return "fastec";
  }
  return "?";
}

SequenceLayout parse_sequence_layout(const std::string& s) {
  for (auto l : {SequenceLayout::automatic, SequenceLayout::generic, SequenceLayout::gev_rs, SequenceLayout::gev_rs_real,
                 SequenceLayout::dre, SequenceLayout::fastec})
    if (s == sequence_layout_name(l)) return l;
  throw UsageError("layout: '" + s + "' is not a sequence layout (expected auto, generic, gev-rs, gev-rs-real, dre, fastec)");
}

std::pair<int, int> image_size(const std::string& path) {
  const ImageHeader h = image_header(path);
  return {h.width, h.height};
}

Sequence load_sequence(const std::string& path, const SequenceOptions& o) {
  Sequence s;
  const fs::path root = fs::path(path).lexically_normal();
  s.root = root.string();
  s.layout = o.layout == SequenceLayout::automatic ? detect_sequence_layout(path) : o.layout;
  s.event_options = o.events;
  switch (s.layout) {
    case SequenceLayout::generic: load_generic(s, root); break;
    case SequenceLayout::gev_rs: load_gev_rs(s, root, o); break;
    case SequenceLayout::gev_rs_real: load_gev_rs_real(s, root, o); break;
    case SequenceLayout::dre: load_dre(s, root); break;
    case SequenceLayout::fastec: load_fastec(s, root, o); break;
    case SequenceLayout::automatic: break;
  }
  if (s.frames.empty()) throw DataError(s.root + ": the sequence has no frames");
  // Overrides.
  if (o.t0s_us && o.t0s_us->size() != s.frames.size())
    throw OptionError("t0s_us", "", std::to_string(o.t0s_us->size()) + " values given, the sequence has " +
                                        std::to_string(s.frames.size()) + " frames (one first-row start per frame)");
  for (size_t k = 0; k < s.frames.size(); ++k) {
    auto& t = s.frames[k].timing;
    if (o.line_delay_us) t.line_delay = *o.line_delay_us;
    if (o.exposure_us) t.exposure = *o.exposure_us;
    if (o.readout) t.readout = *o.readout;
    if (o.t0s_us) t.t0 = (*o.t0s_us)[k];
    t.validate(s.root + ": frame " + std::to_string(k) + " (" + s.frames[k].image + ")");
  }
  check_frame_times(s, o);
  check_meta_rules(s, o);
  if (o.line_delay_us || o.exposure_us || o.readout || o.t0s_us) s.notes.push_back("timing overridden by options");
  if (o.check_frame_sizes) {
    std::vector<ImageHeader> frames, truth;
    for (const auto& f : s.frames) frames.push_back(check_sequence_image(s, f.image, "frame"));
    for (const auto& g : s.ground_truth) truth.push_back(check_sequence_image(s, g.image, "ground-truth"));
    rule_images_agree(s, frames, truth);
  }
  if (o.events_file) {
    s.event_files = {*o.events_file};
    s.notes.push_back("events read from " + *o.events_file + " (option)");
  }
  for (const auto& e : s.event_files) {
    std::error_code ec;
    if (!fs::exists(e, ec)) throw InputMissingError(s.root + ": event file '" + e + "' does not exist");
  }
  // The reader checks every event against the sensor (error, or drop and count, per policy).
  s.event_options.width = s.width;
  s.event_options.height = s.height;
  return s;
}

const SequenceFrame& Sequence::frame(int index) const {
  if (index < 0 || static_cast<size_t>(index) >= frames.size())
    throw UsageError(root + ": frame " + std::to_string(index) + " does not exist (the sequence has " +
                std::to_string(frames.size()) + " frames, 0.." + std::to_string(frames.size() - 1) + ")");
  return frames[index];
}

}  // namespace vkunroll
