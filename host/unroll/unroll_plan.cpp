#include "vkunroll/host/unroll/unroll_plan.hpp"

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/json_read.hpp"
#include "vkunroll/host/events/meta_schema.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

double timing_mid(const RowTiming& t) { return 0.5 * (t.first_start().to_double() + t.last_end().to_double()); }

// Microseconds for messages: integers as such (1700000000000000, not 1.7e+15), else shortest.
std::string us_text(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, std::abs(v) < 1e18 && v == std::floor(v) ? "%.0f" : "%.17g", v);
  return buf;
}

}  // namespace

cv::Mat read_frame_image(const std::string& path, int width, int height) {
  // An image that does not end whole is refused before decoding: the decoder would fill what is
  // missing with gray and only warn on stderr ("Premature end of JPEG file").
  if (const std::string problem = image_end_problem(path); !problem.empty()) throw DataError(path + ": the image " + problem);
  cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (m.empty()) {
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputMissingError(path + ": no such image");
    throw DataError(path + ": cannot read the image (not a PNG, JPEG, TIFF or other format OpenCV reads)");
  }
  if (m.cols != width || m.rows != height)
    throw DataError(path + ": image is " + std::to_string(m.cols) + "x" + std::to_string(m.rows) + ", the sensor is " +
                std::to_string(width) + "x" + std::to_string(height));
  if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
  if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
  if (!cv::checkRange(m, true, nullptr)) throw DataError(path + ": image holds NaN or Inf values");
  return to_unit_float(m);  // [0,1] float, BGR
}

double frame_mid(const SequenceFrame& f) { return timing_mid(f.timing); }

namespace {

// The chosen frame whose span holds t (else the one with the nearest middle).
int frame_for_time(const Sequence& seq, const std::vector<int>& frames, double t) {
  int best = frames.front();
  double best_d = 1e300;
  for (int k : frames) {
    const auto& f = seq.frames[k];
    const double s = f.timing.first_start().to_double(), e = f.timing.last_end().to_double();
    const double d = (t >= s && t <= e) ? std::abs(t - frame_mid(f)) - 1e12 : std::abs(t - frame_mid(f));
    if (d < best_d) best_d = d, best = k;
  }
  return best;
}

}  // namespace

double read_meta_gamma(const Sequence& seq) {
  const fs::path meta = fs::path(seq.root) / "meta.json";
  if (seq.layout != SequenceLayout::generic || !fs::exists(meta)) return 1.0;
  std::ifstream in(meta);
  const nlohmann::json j = parse_json<nlohmann::json>(in, meta.string());
  // The simulator records its output encoding under source.settings.gamma; a value that is there
  // must be a plausible number (a string "2.2" was read as gamma 1 before).
  for (const auto& [pointer, name] : {std::pair{"/source/settings/gamma", "source.settings.gamma"}, std::pair{"/source/gamma", "source.gamma"}}) {
    const nlohmann::json::json_pointer at(pointer);
    if (!j.contains(at)) continue;
    const nlohmann::json& g = j.at(at);
    if (!g.is_number() || !(g.get<double>() >= 0.1 && g.get<double>() <= 10))
      throw DataError(meta.string() + ": " + name + " is " + g.dump() +
                      ": expected a number in [0.1, 10] (the frames' encoding gamma; " + opt("gamma") + " overrides it)");
    return g.get<double>();
  }
  return 1.0;
}

EventStream read_window(const Sequence& seq, double lo, double hi, EventReadReport* report) {
  return seq.read_events(static_cast<int64_t>(std::floor(lo)), static_cast<int64_t>(std::ceil(hi)) + 1, report);
}

std::vector<int> chosen_frames(const Sequence& seq, const std::vector<int>& requested) {
  std::vector<int> frames = requested;
  if (frames.empty())
    for (int k = 0; k < static_cast<int>(seq.frames.size()); ++k) frames.push_back(k);
  try {
    for (int k : frames) seq.frame(k);  // throws naming the index and the count
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::usage) throw;  // an index out of range: the option's fault, named
    throw OptionError("frames", "", e.text(), opt("frames") + ": " + e.text());
  }
  return frames;
}

std::map<int, std::vector<UnrollTarget>> plan_targets(const Sequence& seq, const std::vector<int>& frames,
                                                      const TargetTimes& times, const std::string& where,
                                                      std::vector<std::string>* notes) {
  std::map<int, std::vector<UnrollTarget>> targets;
  auto gt_at = [&](const Rational& t) {
    for (size_t g = 0; g < seq.ground_truth.size(); ++g)
      if (std::abs((seq.ground_truth[g].t_us - t).to_double()) < 0.5) return static_cast<int>(g);
    return -1;
  };
  // An absolute instant belongs to the frame whose span holds it, among all the sequence's frames
  // (else the nearest middle); --frames bounds the targets: one whose frame is not chosen is not
  // extrapolated from another frame (docs/usage.md, "Which frames").
  std::vector<int> all(seq.frames.size());
  for (size_t k = 0; k < all.size(); ++k) all[k] = static_cast<int>(k);
  auto chosen = [&](int k) { return std::find(frames.begin(), frames.end(), k) != frames.end(); };
  size_t gt_outside = 0;
  switch (times.kind) {
    case TargetTimes::Kind::ground_truth:
      if (seq.ground_truth.empty()) throw OptionError("times", "gt", where + " has no ground-truth frames");
      for (size_t g = 0; g < seq.ground_truth.size(); ++g) {
        const auto& gt = seq.ground_truth[g];
        const int k = frame_for_time(seq, all, gt.t_us.to_double());
        if (!chosen(k)) {
          ++gt_outside;
          continue;
        }
        targets[k].push_back({gt.t_us, seq.frames[k].timing.tau_of(gt.t_us).to_double(),
                              fs::path(gt.image).filename().string(), static_cast<int>(g)});
      }
      if (targets.empty())
        throw OptionError("frames", "", "frames holding ground-truth instants",
                          opt("times") + " gt: none of the " + std::to_string(seq.ground_truth.size()) +
                              " ground-truth instants lies in the frames " + opt("frames") + " chose (each instant goes to "
                              "the frame that spans it): choose those frames, or leave " + opt("frames") + " out");
      if (gt_outside && notes)
        notes->push_back(std::to_string(gt_outside) + " ground-truth instant(s) lie in frames outside " + opt("frames") +
                         ": not unrolled");
      break;
    case TargetTimes::Kind::absolute_us:
      for (const Rational& t : times.values) {
        const int k = frame_for_time(seq, all, t.to_double());
        if (!chosen(k))
          throw OptionError("times_us", t.str(), "an instant in a chosen frame",
                            opt("times_us") + " " + t.str() + ": the instant belongs to frame " + std::to_string(k) +
                                " (the frame that spans it, else the nearest), which " + opt("frames") +
                                " leaves out: add frame " + std::to_string(k) + " to " + opt("frames") + " or leave it out");
        targets[k].push_back({t, seq.frames[k].timing.tau_of(t).to_double(), "", gt_at(t)});
      }
      break;
    case TargetTimes::Kind::normalized:
      for (int k : frames)
        for (const Rational& tau : times.values) {
          const Rational t = seq.frames[k].timing.target_time(tau);
          targets[k].push_back({t, tau.to_double(), "", gt_at(t)});
        }
      break;
  }
  const std::string field = times.kind == TargetTimes::Kind::absolute_us ? "times_us" : "times";
  for (const auto& [k, ts] : targets)
    for (const auto& t : ts) check_target_in_recording(seq, t.t_us.to_double(), field);
  return targets;
}

void check_target_in_recording(const Sequence& seq, double t_us, const std::string& field) {
  // Over all frames: a sequence whose frames are out of time order still names its true span.
  double rec_lo = seq.frames.front().timing.first_start().to_double(), rec_hi = seq.frames.front().timing.last_end().to_double();
  for (const auto& f : seq.frames)
    rec_lo = std::min(rec_lo, f.timing.first_start().to_double()), rec_hi = std::max(rec_hi, f.timing.last_end().to_double());
  const double margin = seq.frames.size() > 1 ? frame_mid(seq.frames[1]) - frame_mid(seq.frames[0])
                                              : seq.frames[0].timing.last_end().to_double() - rec_lo;
  if (t_us < rec_lo - margin || t_us > rec_hi + margin)
    throw OptionError(field, us_text(t_us), "within a frame period of the recording",
                      opt(field) + ": target t* = " + us_text(t_us) + " us is outside the recording [" + us_text(rec_lo) + ", " +
                          us_text(rec_hi) + "] us by more than a frame period");
}

FrameTarget::Method target_method(UnrollMode mode, bool moa, bool has_next, bool inside, int frame,
                                  std::map<std::string, int>& notes) {
  using M = FrameTarget::Method;
  switch (mode) {
    case UnrollMode::physics: return M::physics;
    case UnrollMode::s: return M::s;
    case UnrollMode::automatic: return moa && has_next ? M::m : M::s;
    case UnrollMode::m:
      if (!has_next) notes["frame " + std::to_string(frame) + " is the last: SelfUnroll-S used (M needs the next frame)"]++;
      return has_next ? M::m : M::s;
    case UnrollMode::choose:
      if (inside) return M::s;
      if (moa && has_next) return M::m;
      notes[std::string("target outside its frame's exposure span: SelfUnroll-S used (") +
            (moa ? "M needs the next frame" : "the model has no MOA weights") + ")"]++;
      return M::s;
  }
  return M::s;
}

std::pair<double, double> frame_window(const SequenceFrame& f1, const SequenceFrame* f2, const std::vector<UnrollTarget>& ts,
                                       const std::vector<FrameTarget>& methods) {
  double lo = f1.timing.first_start().to_double(), hi = f1.timing.last_end().to_double();
  for (size_t j = 0; j < ts.size(); ++j) {
    const double t = ts[j].t_us.to_double();
    lo = std::min(lo, t);
    hi = std::max(hi, t + (methods[j].method == FrameTarget::Method::physics ? 0.0 : f1.timing.exposure.to_double()));
    if (methods[j].method == FrameTarget::Method::m && f2) {
      lo = std::min(lo, f2->timing.first_start().to_double());
      hi = std::max({hi, f2->timing.last_end().to_double(), t + f2->timing.exposure.to_double()});
    }
  }
  for (int y = 0; y < f1.timing.rows; ++y) lo = std::min(lo, f1.timing.start(y).to_double()), hi = std::max(hi, f1.timing.end(y).to_double());
  return {lo, hi};
}

PhysicsPlan plan_physics(UnrollMode mode, const UnrollSession& session, double seq_gamma, std::optional<double> contrast,
                         const std::function<ContrastEstimate(double)>& estimate) {
  PhysicsPlan p;
  p.seq_gamma = seq_gamma;
  const std::optional<double> model_gamma = session.has_model() ? session.model_config().gamma : std::nullopt;
  p.to_model = model_gamma ? seq_gamma / *model_gamma : 1.0;
  p.variant = session.has_model() && session.model_config().physics_input;
  p.uses_physics = mode == UnrollMode::physics || p.variant;
  if (!p.uses_physics) return p;
  p.params.gamma = static_cast<float>(mode == UnrollMode::physics ? seq_gamma : model_gamma.value_or(1.0));
  const std::string& from_model = p.variant ? session.model_config().physics_contrast : std::string("estimate");
  if (contrast) {
    p.params.contrast = static_cast<float>(*contrast);
  } else if (from_model != "estimate") {
    p.params.contrast = std::stof(from_model);  // validated when the weights were loaded
    p.contrast_source = "the model's metadata";
    p.contrast_method = "model_metadata";
  } else {
    const ContrastEstimate e = estimate(seq_gamma);
    p.params.contrast = static_cast<float>(e.contrast);
    // The variant's physics input stays plain log (offset 0): the network was trained on that.
    if (!p.variant) p.params.log_offset = static_cast<float>(e.log_offset);
    p.contrast_source = e.source;
    p.contrast_warning = e.warning;
    p.contrast_method = e.is_default ? "default" : "event_count_fit";
    p.contrast_pairs = e.pairs;
    p.contrast_pixels = e.pixels;
    p.frame_noise = e.frame_noise;
    p.isolated_event_fraction = e.isolated_event_fraction;
  }
  return p;
}

GateChoice choose_gate_radius(const GateRadiusOption& o, int model_radius, const PhysicsPlan& physics) {
  if (model_radius < 0) {
    if (o.kind == GateRadiusOption::Kind::fixed)
      throw OptionError("gate_radius", std::to_string(o.radius),
                        "this run has no model with an event gate (metadata physics_gate: the physics-informed variant)");
    return {-1, "the model has no event gate"};
  }
  if (o.kind == GateRadiusOption::Kind::fixed) return {o.radius, opt("gate_radius")};
  const std::string own = "the model's metadata (physics_gate " + std::to_string(model_radius) + ")";
  if (o.kind == GateRadiusOption::Kind::model) return {model_radius, own};
  if (physics.frame_noise < 0 || physics.isolated_event_fraction < 0)
    return {model_radius, own + ": the recording's noise was not measured (no contrast estimate)"};
  const bool clean = physics.frame_noise < kCleanFrameNoise && physics.isolated_event_fraction < kCleanIsolatedEvents;
  // frame_noise measures change where no event fired: sensor noise, and motion below the event
  // threshold too (a noise-free moving scene reads 0.01-0.1); the rule was chosen on that measure.
  char text[240];
  std::snprintf(text, sizeof text,
                "auto: a %s recording (frame noise %.4f: noise or motion below the event threshold; isolated events "
                "%.1f%%; clean below %g and %g%%)",
                clean ? "clean" : "noisy", physics.frame_noise, 100 * physics.isolated_event_fraction, kCleanFrameNoise,
                100 * kCleanIsolatedEvents);
  return {clean ? model_radius : std::max(model_radius, kNoisyGateRadius), text};
}

cv::Mat encode_for_model(const cv::Mat& image, double exponent) {
  if (std::abs(exponent - 1.0) < 1e-12) return image;
  cv::Mat v = cv::max(image, 0.0), out;
  cv::pow(v, exponent, out);
  return out;
}

void decode_model_results(std::vector<cv::Mat>& results, const std::vector<FrameTarget>& methods, double to_model) {
  for (size_t j = 0; j < results.size(); ++j)
    if (methods[j].method != FrameTarget::Method::physics) results[j] = encode_for_model(results[j], 1.0 / to_model);
}

}  // namespace vkunroll
