// The physics contrast c (and the log offset eps) from the frames and the events between them:
// see estimate_contrast in unroll_plan.hpp for what is fitted and why.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/luminance.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

namespace {

constexpr size_t kMaxPairs = 4;          // frame pairs compared (each adds every moving pixel)
constexpr int kMinEvents = 2;            // |net events| a pixel needs: one event is as likely noise
constexpr int kMinSupport = 3;           // 8-neighbours with the same net sign: noise is isolated
constexpr size_t kMinPixels = 200;       // fewer pixels: no estimate, the default and a warning
constexpr double kEncodedLow = 0.02, kEncodedHigh = 0.98;  // frame values neither black nor saturated
constexpr double kOffsets[] = {0.0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05};  // eps candidates (linear)
constexpr double kBeyondOffset = 0.1;  // tried only to tell whether the largest candidate binds
constexpr double kBeyondGain = 0.9;     // binds when the residual there is at least 10% lower
constexpr double kPlausibleLow = 0.05, kPlausibleHigh = 1.0;  // DVS thresholds outside: warned

// Linear luminance (Rec. 709 on linear BGR; a gray frame as it is) of a BGR float32 frame in [0, 1].
std::vector<double> linear_luminance(const cv::Mat& image, double gamma) {
  std::vector<double> out(size_t(image.rows) * image.cols);
  const int ch = image.channels();
  for (int y = 0; y < image.rows; ++y) {
    const float* row = image.ptr<float>(y);
    for (int x = 0; x < image.cols; ++x) {
      auto lin = [&](int c) { return std::pow(std::max(0.0, double(row[x * ch + c])), gamma); };
      out[size_t(y) * image.cols + x] = ch >= 3 ? kLumB * lin(0) + kLumG * lin(1) + kLumR * lin(2) : lin(0);
    }
  }
  return out;
}

// One pixel's evidence: the luminance of both frames and the net event count between them.
struct Sample {
  double a, b;
  int n;
};

struct PairEvidence {
  std::vector<Sample> samples;
  std::vector<double> quiet_change;  // log change of in-range pixels without an event in their 3x3
  size_t event_pixels = 0, isolated = 0;  // pixels with events; of them, none in their 8 neighbours
};

// The pixels of frames (a, b) whose net events between the rows' mid-exposures are signal:
// |N| >= kMinEvents, kMinSupport same-sign neighbours, both frames in range.
PairEvidence pair_evidence(const RowTiming& fa, const RowTiming& fb, const cv::Mat& ia, const cv::Mat& ib, double gamma,
                           int W, int H, const std::function<EventStream(double, double)>& events) {
  const std::vector<double> sa = fa.start_times_us(), ea = fa.end_times_us(), sb = fb.start_times_us(), eb = fb.end_times_us();
  std::vector<double> mid_a(H), mid_b(H);
  for (int y = 0; y < H; ++y) mid_a[y] = 0.5 * (sa[y] + ea[y]), mid_b[y] = 0.5 * (sb[y] + eb[y]);
  const EventStream ev = events(*std::min_element(mid_a.begin(), mid_a.end()), *std::max_element(mid_b.begin(), mid_b.end()));
  std::vector<int> net(size_t(W) * H, 0), count(size_t(W) * H, 0);
  for (size_t i = 0; i < ev.size(); ++i) {
    const int x = ev.x[i], y = ev.y[i];
    if (x >= W || y >= H || !(double(ev.t[i]) > mid_a[y] && double(ev.t[i]) <= mid_b[y])) continue;
    net[size_t(y) * W + x] += ev.p[i] > 0 ? 1 : -1;
    count[size_t(y) * W + x]++;
  }
  const std::vector<double> la = linear_luminance(ia, gamma), lb = linear_luminance(ib, gamma);
  const double lo = std::pow(kEncodedLow, gamma), hi = std::pow(kEncodedHigh, gamma);
  PairEvidence r;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const size_t i = size_t(y) * W + x;
      if (!(la[i] > lo && la[i] < hi && lb[i] > lo && lb[i] < hi)) continue;
      int support = 0, around = 0;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int yy = y + dy, xx = x + dx;
          if (yy < 0 || yy >= H || xx < 0 || xx >= W) continue;
          const size_t j = size_t(yy) * W + xx;
          around += count[j];
          if ((dy || dx) && net[i] != 0 && (net[j] > 0) == (net[i] > 0) && net[j] != 0) support++;
        }
      if (count[i] > 0) r.event_pixels++, r.isolated += around == count[i];
      if (around == 0) r.quiet_change.push_back(std::log(lb[i] + 0.01) - std::log(la[i] + 0.01));
      if (std::abs(net[i]) >= kMinEvents && support >= kMinSupport) r.samples.push_back({la[i], lb[i], net[i]});
    }
  return r;
}

// Weighted median: the first value whose cumulative weight reaches half (the L1 fit through 0).
double weighted_median(std::vector<std::pair<double, double>> vw) {
  std::sort(vw.begin(), vw.end());
  double total = 0;
  for (const auto& [v, w] : vw) total += w;
  double acc = 0;
  for (const auto& [v, w] : vw)
    if ((acc += w) >= 0.5 * total) return v;
  return vw.back().first;
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
  return v[v.size() / 2];
}

}  // namespace

ContrastEstimate estimate_contrast(const std::vector<RowTiming>& timings, const std::vector<int>& frames, double gamma, int width,
                                   int height, const std::function<cv::Mat(int)>& image,
                                   const std::function<EventStream(double, double)>& events) {
  std::vector<std::pair<int, int>> pairs;
  for (int k : frames)
    if (k + 1 < static_cast<int>(timings.size()) && pairs.size() < kMaxPairs) pairs.push_back({k, k + 1});
  if (pairs.empty())
    return {0.2, 0.0, "a fixed 0.2, not estimated: no pair of consecutive frames",
            "contrast c = 0.2 is a fixed default: the frames unrolled have no successor to estimate it from "
            "(give " + opt("contrast") + " C, or include the next frame)",
            true, {}, 0};
  std::vector<Sample> samples;
  std::vector<double> quiet;
  size_t event_pixels = 0, isolated = 0;
  for (auto [a, b] : pairs) {
    PairEvidence e = pair_evidence(timings[a], timings[b], image(a), image(b), gamma, width, height, events);
    samples.insert(samples.end(), e.samples.begin(), e.samples.end());
    quiet.insert(quiet.end(), e.quiet_change.begin(), e.quiet_change.end());
    event_pixels += e.event_pixels, isolated += e.isolated;
  }
  const double isolated_fraction = event_pixels ? double(isolated) / double(event_pixels) : -1.0;
  // Frame noise: the robust spread of the log change where nothing happened; a signal pixel's
  // change must exceed 3 sigma and agree with its events' sign (hot pixels fire without one).
  double sigma = 0;
  if (quiet.size() >= 100) {
    const double m = median(quiet);
    for (double& q : quiet) q = std::abs(q - m);
    sigma = 1.4826 * median(quiet);
  }
  const double frame_noise = quiet.size() >= 100 ? sigma : -1.0;
  std::vector<Sample> kept;
  for (const Sample& s : samples) {
    const double d = std::log(s.b + 0.01) - std::log(s.a + 0.01);
    if (std::abs(d) > 3 * sigma && (d > 0) == (s.n > 0)) kept.push_back(s);
  }
  std::string over;
  for (auto [a, b] : pairs) over += (over.empty() ? "" : ", ") + std::to_string(a) + "-" + std::to_string(b);
  if (kept.size() < kMinPixels)
    return {0.2, 0.0, "a fixed 0.2, not estimated: " + std::to_string(kept.size()) + " pixels of frames " + over +
                          " have events explained by a brightness change (" + std::to_string(kMinPixels) + " needed)",
            "contrast c = 0.2 is a fixed default: too few pixels of frames " + over +
                " have both events and a matching brightness change to estimate it (give " + opt("contrast") + " C)",
            true, pairs, kept.size(), frame_noise, isolated_fraction};
  // Per offset: c is the L1 fit of log change against event count; the offset whose fit leaves the
  // least residual (in events) wins.
  std::vector<double> change(kept.size());
  auto fit_at = [&](double eps) {
    std::vector<std::pair<double, double>> ratio;
    for (size_t i = 0; i < kept.size(); ++i) {
      change[i] = std::log(kept[i].b + eps) - std::log(kept[i].a + eps);
      ratio.push_back({change[i] / kept[i].n, std::abs(kept[i].n)});
    }
    const double c = weighted_median(ratio);
    double residual = 1e300;
    if (c > 0) {
      residual = 0;
      for (size_t i = 0; i < kept.size(); ++i) residual += std::abs(change[i] / c - kept[i].n);
    }
    return std::pair{c, residual};
  };
  double best_c = 0.2, best_eps = 0.0, best_residual = 1e300;
  for (double eps : kOffsets)
    if (const auto [c, residual] = fit_at(eps); residual < best_residual) best_residual = residual, best_c = c, best_eps = eps;
  // At the largest candidate the grid, not the data, may have stopped the fit: one step beyond says
  // which. Event noise alone moves the residual's minimum past the true offset by a few percent
  // (validation: 1-7% lower at 0.1 where the truth is 0.05), so only a clearly better fit counts.
  const double largest = kOffsets[std::size(kOffsets) - 1];
  const bool grid_bound = best_eps == largest && fit_at(kBeyondOffset).second < kBeyondGain * best_residual;
  char src[200];
  std::snprintf(src, sizeof src, "estimated (brightness change against event count at %zu pixels of frames %s; log offset %g)",
                kept.size(), over.c_str(), best_eps);
  ContrastEstimate r{best_c, best_eps, src, "", false, pairs, kept.size(), frame_noise, isolated_fraction};
  if (best_c < kPlausibleLow || best_c > kPlausibleHigh) {
    char text[260];
    std::snprintf(text, sizeof text,
                  "the contrast estimate c = %.3f lies outside the range of event-camera thresholds (%.2f to %.1f): "
                  "event noise or a slow sensor may dominate; give ", best_c, kPlausibleLow, kPlausibleHigh);
    r.warning = text + opt("contrast") + " C if it is known";
  }
  if (grid_bound) {
    char text[360];
    std::snprintf(text, sizeof text,
                  "the log offset fit stopped at its largest candidate (%g) and %g fits these pixels clearly better: the "
                  "contrast c = %.3f is bounded by the offset grid, not by the data (heavy event noise or a large "
                  "dark offset); give ", largest, kBeyondOffset, best_c);
    r.warning += (r.warning.empty() ? "" : "; ") + std::string(text) + opt("contrast") + " C if it is known";
  }
  return r;
}

}  // namespace vkunroll
