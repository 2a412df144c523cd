#include "vkunroll/host/sim/scene.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/host/sim/random.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll::sim {

namespace {

constexpr double kTwoPi = 6.283185307179586;

// Display-space values are kept away from 0 and 1 so that the log response stays finite and
// highlights do not clip.
constexpr double kDisplayLo = 0.12, kDisplayHi = 0.92;

cv::Mat linearize(const cv::Mat& display01, double gamma) {
  cv::Mat lin;
  cv::pow(cv::max(display01, 0.0), gamma, lin);
  return lin;
}

// Rescales each image to [lo, hi] over all channels.
void normalize_range(cv::Mat& m, double lo, double hi) {
  double mn = 0, mx = 0;
  cv::minMaxLoc(m.reshape(1), &mn, &mx);
  if (mx - mn < 1e-12) {
    m.setTo(cv::Scalar::all(0.5 * (lo + hi)));
    return;
  }
  m.convertTo(m, CV_32F, (hi - lo) / (mx - mn), lo - mn * (hi - lo) / (mx - mn));
}

cv::Vec3f random_color(Rng& rng, double lo, double hi) {
  // A random brightness with a moderate random tint, in display space.
  const double v = rng.uniform(lo, hi);
  cv::Vec3f c;
  for (int k = 0; k < 3; ++k) c[k] = static_cast<float>(std::clamp(v * rng.uniform(0.7, 1.3), kDisplayLo, kDisplayHi));
  return c;
}

// Smooth value noise: random grids upsampled with cubic interpolation, summed over octaves.
cv::Mat value_noise(cv::Size size, double feature_px, Rng& rng, int octaves, bool color) {
  cv::Mat acc(size, CV_32FC3, cv::Scalar::all(0));
  double amp = 1.0;
  for (int o = 0; o < octaves; ++o) {
    const double cell = std::max(2.0, feature_px / std::pow(2.0, o));
    const int gw = std::max(2, static_cast<int>(std::ceil(size.width / cell)) + 1);
    const int gh = std::max(2, static_cast<int>(std::ceil(size.height / cell)) + 1);
    cv::Mat grid(gh, gw, CV_32FC3);
    for (int y = 0; y < gh; ++y)
      for (int x = 0; x < gw; ++x) {
        const float g = static_cast<float>(rng.uniform(-1.0, 1.0));
        cv::Vec3f v(g, g, g);
        if (color)
          for (int k = 0; k < 3; ++k) v[k] += static_cast<float>(0.35 * rng.uniform(-1.0, 1.0));
        grid.at<cv::Vec3f>(y, x) = v;
      }
    cv::Mat up;
    cv::resize(grid, up, cv::Size(static_cast<int>(gw * cell), static_cast<int>(gh * cell)), 0, 0, cv::INTER_CUBIC);
    acc += up(cv::Rect(0, 0, size.width, size.height)) * amp;
    amp *= 0.55;
  }
  return acc;
}

cv::Mat checkerboard(cv::Size size, double cell, Rng& rng) {
  cv::Mat m(size, CV_32FC3);
  const cv::Vec3f light = random_color(rng, 0.7, 0.9), dark = random_color(rng, 0.1, 0.3);
  const int c = std::max(1, static_cast<int>(std::lround(cell)));
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) m.at<cv::Vec3f>(y, x) = (((x / c) + (y / c)) & 1) ? light : dark;
  return m;
}

cv::Mat bars(cv::Size size, double feature, Rng& rng) {
  cv::Mat m(size, CV_32FC3);
  // Vertical bars of random width and color ...
  int x = 0;
  while (x < size.width) {
    const int w = std::max(1, static_cast<int>(feature * rng.uniform(0.3, 1.6)));
    const cv::Vec3f c = random_color(rng, 0.1, 0.9);
    m(cv::Rect(x, 0, std::min(w, size.width - x), size.height)).setTo(cv::Scalar(c[0], c[1], c[2]));
    x += w;
  }
  // ... crossed by a few translucent horizontal bars, so vertical motion makes events as well.
  int y = static_cast<int>(feature * rng.uniform(0.5, 3.0));
  while (y < size.height) {
    const int h = std::max(1, static_cast<int>(feature * rng.uniform(0.3, 1.2)));
    const cv::Vec3f c = random_color(rng, 0.1, 0.9);
    cv::Mat roi = m(cv::Rect(0, y, size.width, std::min(h, size.height - y)));
    roi = roi * 0.5 + cv::Scalar(c[0], c[1], c[2]) * 0.5;
    y += h + static_cast<int>(feature * rng.uniform(1.5, 6.0));
  }
  return m;
}

const char* const kWords[] = {"ROLLING", "SHUTTER", "EVENTS", "vkunroll", "DAVIS346", "unroll", "0123456789",
                              "global", "SelfUnroll", "motion", "Vulkan", "row-by-row", "346x260", "skew"};

void draw_text(cv::Mat& m, double feature, Rng& rng, double coverage) {
  const int fonts[] = {cv::FONT_HERSHEY_SIMPLEX, cv::FONT_HERSHEY_DUPLEX, cv::FONT_HERSHEY_COMPLEX,
                       cv::FONT_HERSHEY_TRIPLEX, cv::FONT_HERSHEY_PLAIN};
  const int count = std::max(1, static_cast<int>(coverage * m.total() / (feature * feature * 8)));
  for (int i = 0; i < count; ++i) {
    const std::string word = kWords[rng.integer(0, static_cast<int>(std::size(kWords)) - 1)];
    const int font = fonts[rng.integer(0, 4)];
    const double scale = feature * rng.uniform(0.6, 1.8) / 22.0;
    const int thickness = std::max(1, static_cast<int>(scale * rng.uniform(1.0, 3.0)));
    const cv::Point org(rng.integer(-static_cast<int>(feature), m.cols), rng.integer(0, m.rows + static_cast<int>(feature)));
    const cv::Vec3f c = random_color(rng, rng.chance(0.5) ? 0.1 : 0.75, rng.chance(0.5) ? 0.3 : 0.9);
    cv::putText(m, word, org, font, scale, cv::Scalar(c[0], c[1], c[2]), thickness, cv::LINE_AA);
  }
}

cv::Mat text_texture(cv::Size size, double feature, Rng& rng) {
  const cv::Vec3f bg = random_color(rng, 0.35, 0.65);
  cv::Mat m(size, CV_32FC3, cv::Scalar(bg[0], bg[1], bg[2]));
  draw_text(m, feature, rng, 1.0);
  return m;
}

cv::Mat noise_texture(cv::Size size, double feature, Rng& rng) {
  cv::Mat m = value_noise(size, feature * 4.0, rng, 5, true);
  normalize_range(m, kDisplayLo, kDisplayHi);
  return m;
}

cv::Mat mixed_texture(cv::Size size, double feature, Rng& rng) {
  cv::Mat base = noise_texture(size, feature, rng);
  const cv::Mat check = checkerboard(size, feature, rng);
  const cv::Mat bar = bars(size, feature, rng);
  // Large smooth blobs choose where the checkerboard and the bars show through.
  cv::Mat sel_a = value_noise(size, feature * 12.0, rng, 1, false), sel_b = value_noise(size, feature * 12.0, rng, 1, false);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      if (sel_a.at<cv::Vec3f>(y, x)[0] > 0.45f) base.at<cv::Vec3f>(y, x) = check.at<cv::Vec3f>(y, x);
      else if (sel_b.at<cv::Vec3f>(y, x)[0] > 0.45f) base.at<cv::Vec3f>(y, x) = bar.at<cv::Vec3f>(y, x);
    }
  draw_text(base, feature, rng, 0.25);
  return base;
}

glm::dmat3 translate(glm::dvec2 d) {
  glm::dmat3 m(1.0);
  m[2] = glm::dvec3(d, 1.0);
  return m;
}
glm::dmat3 rotate(double a) {
  glm::dmat3 m(1.0);
  m[0] = glm::dvec3(std::cos(a), std::sin(a), 0.0);
  m[1] = glm::dvec3(-std::sin(a), std::cos(a), 0.0);
  return m;
}
glm::dmat3 scale(double sx, double sy) {
  glm::dmat3 m(1.0);
  m[0][0] = sx;
  m[1][1] = sy;
  return m;
}

cv::Mat luminance_of(const cv::Mat& bgr) {
  cv::Mat lum;
  cv::transform(bgr, lum, cv::Matx13f(static_cast<float>(kLumB), static_cast<float>(kLumG), static_cast<float>(kLumR)));
  return lum;
}

}  // namespace

// ---- names -------------------------------------------------------------------------------------

TextureKind parse_texture_kind(const std::string& name) {
  if (name == "checkerboard") return TextureKind::Checkerboard;
  if (name == "bars") return TextureKind::Bars;
  if (name == "noise") return TextureKind::Noise;
  if (name == "text") return TextureKind::Text;
  if (name == "mixed") return TextureKind::Mixed;
  throw UsageError("unknown texture '" + name + "': expected checkerboard, bars, noise, text, mixed or an image file");
}
const char* texture_kind_name(TextureKind kind) {
  switch (kind) {
    case TextureKind::Checkerboard: return "checkerboard";
    case TextureKind::Bars: return "bars";
    case TextureKind::Noise: return "noise";
    case TextureKind::Text: return "text";
    case TextureKind::Mixed: return "mixed";
  }
  return "?";
}

MotionKind parse_motion_kind(const std::string& name) {
  if (name == "static") return MotionKind::Static;
  if (name == "pan") return MotionKind::Pan;
  if (name == "accelerate") return MotionKind::Accelerate;
  if (name == "rotate") return MotionKind::Rotate;
  if (name == "zoom") return MotionKind::Zoom;
  if (name == "shake") return MotionKind::Shake;
  if (name == "mixed") return MotionKind::Mixed;
  throw UsageError("unknown motion '" + name + "': expected static, pan, accelerate, rotate, zoom, shake or mixed");
}
const char* motion_kind_name(MotionKind kind) {
  switch (kind) {
    case MotionKind::Static: return "static";
    case MotionKind::Pan: return "pan";
    case MotionKind::Accelerate: return "accelerate";
    case MotionKind::Rotate: return "rotate";
    case MotionKind::Zoom: return "zoom";
    case MotionKind::Shake: return "shake";
    case MotionKind::Mixed: return "mixed";
  }
  return "?";
}
const char* sprite_shape_name(SpriteShape shape) {
  switch (shape) {
    case SpriteShape::Rectangle: return "rectangle";
    case SpriteShape::Ellipse: return "ellipse";
    case SpriteShape::Star: return "star";
  }
  return "?";
}

// ---- textures ----------------------------------------------------------------------------------

cv::Mat make_texture(TextureKind kind, cv::Size size, uint64_t seed, double feature_px, double gamma) {
  if (size.width < 1 || size.height < 1) throw UsageError("make_texture: empty size");
  if (!(feature_px >= 1.0)) throw UsageError("make_texture: feature size must be >= 1 pixel");
  Rng rng(seed, 0x7E47);
  cv::Mat display;
  switch (kind) {
    case TextureKind::Checkerboard: display = checkerboard(size, feature_px, rng); break;
    case TextureKind::Bars: display = bars(size, feature_px, rng); break;
    case TextureKind::Noise: display = noise_texture(size, feature_px, rng); break;
    case TextureKind::Text: display = text_texture(size, feature_px, rng); break;
    case TextureKind::Mixed: display = mixed_texture(size, feature_px, rng); break;
  }
  return linearize(display, gamma);
}

cv::Mat load_texture(const std::string& path, double gamma) {
  cv::Mat img = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  if (img.empty()) throw DataError("texture file '" + path + "': cannot be read as an image (expected PNG, JPEG, ...)");
  double scale = 1.0;
  switch (img.depth()) {
    case CV_8U: scale = 1.0 / 255.0; break;
    case CV_16U: scale = 1.0 / 65535.0; break;
    case CV_32F: scale = 1.0; break;
    default: throw DataError("texture file '" + path + "': unsupported pixel depth (expected 8- or 16-bit)");
  }
  if (img.channels() == 1) cv::cvtColor(img, img, cv::COLOR_GRAY2BGR);
  else if (img.channels() == 4) cv::cvtColor(img, img, cv::COLOR_BGRA2BGR);
  cv::Mat f;
  img.convertTo(f, CV_32FC3, scale);
  // Same display range as procedural textures: keeps the log response finite, avoids clipping.
  f = f * (kDisplayHi - kDisplayLo) + cv::Scalar::all(kDisplayLo);
  return linearize(f, gamma);
}

// ---- motion presets ----------------------------------------------------------------------------

CameraMotion camera_motion_preset(MotionKind kind, double k, uint64_t seed) {
  CameraMotion m;
  Rng rng(seed, 0x5AE);
  m.shake_phase = glm::dvec4(rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi));
  const double sx = rng.chance(0.5) ? 1.0 : -1.0, sy = rng.chance(0.5) ? 1.0 : -1.0;
  switch (kind) {
    case MotionKind::Static: break;
    case MotionKind::Pan:  // a steady sideways pan: ~9 px of skew over a 260-row readout
      m.velocity = glm::dvec2(sx * 350.0, sy * 60.0) * k;
      break;
    case MotionKind::Accelerate:  // speeds up from 100 to ~1000 px/s over half a second, turning
      m.velocity = glm::dvec2(sx * 100.0, 0.0) * k;
      m.acceleration = glm::dvec2(sx * 1800.0, sy * 400.0) * k;
      m.angular_acceleration = sy * 1.5;
      break;
    case MotionKind::Rotate:  // in-plane rotation about the view center
      m.angular_velocity = sx * 0.9;
      m.angular_acceleration = sy * 1.0;
      break;
    case MotionKind::Zoom:  // moving toward the scene
      m.zoom_rate = 0.9;
      m.velocity = glm::dvec2(sx * 40.0, sy * 30.0) * k;
      break;
    case MotionKind::Shake:  // hand tremor on a slow drift
      m.velocity = glm::dvec2(sx * 60.0, sy * 20.0) * k;
      m.shake_amplitude_px = 6.0 * k;
      m.shake_hz = 7.0;
      m.shake_rotation_rad = 0.012;
      break;
    case MotionKind::Mixed:  // everything at once, moderate: the default
      m.velocity = glm::dvec2(sx * 200.0, sy * 40.0) * k;
      m.acceleration = glm::dvec2(sx * 400.0, -sy * 150.0) * k;
      m.angular_velocity = sy * 0.15;
      m.angular_acceleration = sx * 0.4;
      m.zoom_rate = 0.2;
      m.shake_amplitude_px = 2.0 * k;
      m.shake_hz = 9.0;
      m.shake_rotation_rad = 0.004;
      break;
  }
  return m;
}

// ---- scene -------------------------------------------------------------------------------------

Scene::Scene(SceneSpec spec) : spec_(std::move(spec)) {
  if (spec_.width < 1 || spec_.height < 1 || spec_.width > 8192 || spec_.height > 8192)
    throw UsageError("scene: size " + std::to_string(spec_.width) + "x" + std::to_string(spec_.height) +
                " out of range (1..8192)");
  if (spec_.supersample < 1 || spec_.supersample > 8)
    throw UsageError("scene: supersample " + std::to_string(spec_.supersample) + " out of range (1..8)");
  if (!(spec_.background_scale > 0)) throw UsageError("scene: background_scale must be > 0");
  if (spec_.background.empty()) {
    background_color_ = cv::Mat(4, 4, CV_32FC3, spec_.background_color);
  } else {
    if (spec_.background.type() != CV_32FC3) throw InternalError("scene: background must be CV_32FC3 linear intensity");
    background_color_ = spec_.background;
  }
  background_lum_ = luminance_of(background_color_);

  const int ss = spec_.supersample;
  for (size_t i = 0; i < spec_.sprites.size(); ++i) {
    const SpriteSpec& s = spec_.sprites[i];
    if (!(s.size.x >= 1 && s.size.y >= 1))
      throw UsageError("scene: sprite " + std::to_string(i) + " is smaller than one pixel");
    // Sprite textures are resampled to S samples per sensor pixel so edges stay sharp at render time.
    const cv::Size ts(std::max(2, static_cast<int>(std::ceil(s.size.x * ss))), std::max(2, static_cast<int>(std::ceil(s.size.y * ss))));
    cv::Mat color;
    if (s.texture.empty()) {
      color = cv::Mat(ts, CV_32FC3, s.color);
    } else {
      if (s.texture.type() != CV_32FC3) throw InternalError("scene: sprite " + std::to_string(i) + " texture must be CV_32FC3");
      cv::resize(s.texture, color, ts, 0, 0, cv::INTER_AREA);
    }
    // Alpha mask drawn 4x finer, then area-averaged: anti-aliased shape edges.
    const int f = 4;
    cv::Mat mask_hi(ts.height * f, ts.width * f, CV_8UC1, cv::Scalar(0));
    const double w = mask_hi.cols, h = mask_hi.rows;
    switch (s.shape) {
      case SpriteShape::Rectangle: mask_hi.setTo(255); break;
      case SpriteShape::Ellipse:
        cv::ellipse(mask_hi, cv::Point2d(w / 2, h / 2), cv::Size2d(w / 2, h / 2), 0, 0, 360, cv::Scalar(255), cv::FILLED);
        break;
      case SpriteShape::Star: {
        std::vector<cv::Point> pts;
        for (int k = 0; k < 10; ++k) {
          const double r = (k & 1) ? 0.45 : 1.0, a = -kTwoPi / 4 + k * kTwoPi / 10;
          pts.emplace_back(static_cast<int>(w / 2 + r * w / 2 * std::cos(a)), static_cast<int>(h / 2 + r * h / 2 * std::sin(a)));
        }
        cv::fillPoly(mask_hi, std::vector<std::vector<cv::Point>>{pts}, cv::Scalar(255));
        break;
      }
    }
    cv::Mat alpha;
    mask_hi.convertTo(alpha, CV_32F, 1.0 / 255.0);
    cv::resize(alpha, alpha, ts, 0, 0, cv::INTER_AREA);
    std::vector<cv::Mat> ch;
    cv::split(color, ch);
    for (auto& c : ch) c = c.mul(alpha);  // premultiplied: resampling then blends correctly
    cv::Mat rgba, la;
    cv::merge(std::vector<cv::Mat>{ch[0], ch[1], ch[2], alpha}, rgba);
    cv::Mat lum = ch[0] * kLumB + ch[1] * kLumG + ch[2] * kLumR;
    cv::merge(std::vector<cv::Mat>{lum, alpha}, la);
    sprite_rgba_.push_back(rgba);
    sprite_lum_alpha_.push_back(la);
  }
}

glm::dmat3 Scene::world_from_sensor(double t_us) const {
  const CameraMotion& m = spec_.camera;
  const double t = t_us * 1e-6;
  glm::dvec2 c = spec_.world_center + m.velocity * t + 0.5 * m.acceleration * t * t;
  double theta = m.angular_velocity * t + 0.5 * m.angular_acceleration * t * t;
  if (m.shake_amplitude_px != 0.0 || m.shake_rotation_rad != 0.0) {
    const double w = kTwoPi * m.shake_hz;
    const glm::dvec4& ph = m.shake_phase;
    c.x += m.shake_amplitude_px * (std::sin(w * t + ph.x) + 0.5 * std::sin(1.73 * w * t + ph.y));
    c.y += m.shake_amplitude_px * (0.8 * std::sin(1.31 * w * t + ph.z) + 0.4 * std::sin(2.27 * w * t + ph.w));
    theta += m.shake_rotation_rad * std::sin(0.89 * w * t + ph.y + ph.z);
  }
  const double zoom = std::exp(m.zoom_rate * t);
  const glm::dvec2 center(0.5 * (spec_.width - 1), 0.5 * (spec_.height - 1));
  return translate(c) * rotate(theta) * scale(1.0 / zoom, 1.0 / zoom) * translate(-center);
}

glm::dmat3 Scene::sensor_from_sprite(size_t index, double t_us) const {
  const SpriteSpec& s = spec_.sprites.at(index);
  const double t = t_us * 1e-6;
  const glm::dvec2 pos = s.position + s.velocity * t + 0.5 * s.acceleration * t * t;
  const double angle = s.angle + s.angular_velocity * t;
  return translate(pos) * rotate(angle) * translate(-0.5 * s.size);
}

double Scene::gain(double t_us) const {
  const double t = t_us * 1e-6;
  double g = spec_.gain * std::exp(spec_.log_gain_rate * t);
  if (spec_.flicker_amplitude != 0.0) g *= 1.0 + spec_.flicker_amplitude * std::sin(kTwoPi * spec_.flicker_hz * t);
  return g;
}

void Scene::render(double t_us, cv::Mat& color) { render_impl(t_us, true, color); }
void Scene::render_luminance(double t_us, cv::Mat& luminance) { render_impl(t_us, false, luminance); }

namespace {

// Mirror an index into [0, n) the way BORDER_REFLECT_101 does (period 2n - 2).
inline int reflect101(int i, int n) {
  if (n == 1) return 0;
  const int period = 2 * n - 2;
  i %= period;
  if (i < 0) i += period;
  return i < n ? i : period - i;
}

// Exact bilinear sample of an NC-channel float texture (texel centers at integers), reflecting
// at the border. Unlike cv::warpAffine (which quantizes positions to 1/32 texel), the result is
// continuous in (u, v): a moving scene changes intensity smoothly, as the event model assumes.
template <int NC>
inline void sample_reflect(const cv::Mat& tex, double u, double v, float* out) {
  const double fu = std::floor(u), fv = std::floor(v);
  const int u0 = static_cast<int>(fu), v0 = static_cast<int>(fv);
  const float au = static_cast<float>(u - fu), av = static_cast<float>(v - fv);
  int ua = u0, ub = u0 + 1, va = v0, vb = v0 + 1;
  if (u0 < 0 || u0 + 1 >= tex.cols) ua = reflect101(u0, tex.cols), ub = reflect101(u0 + 1, tex.cols);
  if (v0 < 0 || v0 + 1 >= tex.rows) va = reflect101(v0, tex.rows), vb = reflect101(v0 + 1, tex.rows);
  const float* ra = tex.ptr<float>(va);
  const float* rb = tex.ptr<float>(vb);
  for (int c = 0; c < NC; ++c) {
    const float top = ra[ua * NC + c] + au * (ra[ub * NC + c] - ra[ua * NC + c]);
    const float bot = rb[ua * NC + c] + au * (rb[ub * NC + c] - rb[ua * NC + c]);
    out[c] = top + av * (bot - top);
  }
}

// Bilinear sample with zero outside the texture (sprites: transparent beyond their box).
template <int NC>
inline void sample_zero(const cv::Mat& tex, double u, double v, float* out) {
  const double fu = std::floor(u), fv = std::floor(v);
  const int u0 = static_cast<int>(fu), v0 = static_cast<int>(fv);
  const float au = static_cast<float>(u - fu), av = static_cast<float>(v - fv);
  const float w[4] = {(1 - au) * (1 - av), au * (1 - av), (1 - au) * av, au * av};
  const int us[4] = {u0, u0 + 1, u0, u0 + 1}, vs[4] = {v0, v0, v0 + 1, v0 + 1};
  for (int c = 0; c < NC; ++c) out[c] = 0.0f;
  for (int k = 0; k < 4; ++k) {
    if (us[k] < 0 || vs[k] < 0 || us[k] >= tex.cols || vs[k] >= tex.rows) continue;
    const float* p = tex.ptr<float>(vs[k]) + us[k] * NC;
    for (int c = 0; c < NC; ++c) out[c] += w[k] * p[c];
  }
}

struct SpriteDraw {
  const cv::Mat* tex;         // premultiplied channels + alpha
  double m[6];                // sensor (x, y) -> texture (u, v): u = m0 x + m1 y + m2, v = m3 x + m4 y + m5
  double x0, y0, x1, y1;      // sensor-space bounding box
};

template <int NC>
void render_rows(const cv::Range& rows, int width, int ss, const cv::Mat& bg, const double* mb,
                 const std::vector<SpriteDraw>& sprites, float gain, cv::Mat& out) {
  const float norm = gain / static_cast<float>(ss * ss);
  std::vector<const SpriteDraw*> active;
  for (int y = rows.start; y < rows.end; ++y) {
    active.clear();
    for (const SpriteDraw& s : sprites)
      if (s.y0 <= y + 0.5 && s.y1 >= y - 0.5) active.push_back(&s);
    float* dst = out.ptr<float>(y);
    if (ss == 1) {
      // One sample per pixel: background along the row with incremental coordinates, then each
      // sprite "over" it across its bounding-box span only.
      double u = mb[1] * y + mb[2], v = mb[4] * y + mb[5];
      for (int x = 0; x < width; ++x, u += mb[0], v += mb[3]) sample_reflect<NC>(bg, u, v, dst + x * NC);
      for (const SpriteDraw* s : active) {
        const int xa = std::max(0, static_cast<int>(std::ceil(s->x0))), xb = std::min(width - 1, static_cast<int>(std::floor(s->x1)));
        double su = s->m[0] * xa + s->m[1] * y + s->m[2], sv = s->m[3] * xa + s->m[4] * y + s->m[5];
        for (int x = xa; x <= xb; ++x, su += s->m[0], sv += s->m[3]) {
          float pre[NC + 1];
          sample_zero<NC + 1>(*s->tex, su, sv, pre);
          const float a = pre[NC];
          if (a <= 0.0f) continue;
          for (int c = 0; c < NC; ++c) dst[x * NC + c] = pre[c] + dst[x * NC + c] * (1.0f - a);
        }
      }
      if (gain != 1.0f)
        for (int i = 0; i < width * NC; ++i) dst[i] *= gain;
      continue;
    }
    for (int x = 0; x < width; ++x) {
      float acc[NC] = {};
      bool sprite_here = false;
      for (const SpriteDraw* s : active) sprite_here |= (s->x0 <= x + 0.5 && s->x1 >= x - 0.5);
      for (int j = 0; j < ss; ++j) {
        const double ys = y + (j + 0.5) / ss - 0.5;
        for (int i = 0; i < ss; ++i) {
          const double xs = x + (i + 0.5) / ss - 0.5;
          float col[NC];
          sample_reflect<NC>(bg, mb[0] * xs + mb[1] * ys + mb[2], mb[3] * xs + mb[4] * ys + mb[5], col);
          if (sprite_here) {
            for (const SpriteDraw* s : active) {
              if (xs < s->x0 || xs > s->x1 || ys < s->y0 || ys > s->y1) continue;
              float pre[NC + 1];
              sample_zero<NC + 1>(*s->tex, s->m[0] * xs + s->m[1] * ys + s->m[2], s->m[3] * xs + s->m[4] * ys + s->m[5], pre);
              const float a = pre[NC];
              if (a <= 0.0f) continue;
              for (int c = 0; c < NC; ++c) col[c] = pre[c] + col[c] * (1.0f - a);  // premultiplied "over"
            }
          }
          for (int c = 0; c < NC; ++c) acc[c] += col[c];
        }
      }
      for (int c = 0; c < NC; ++c) dst[x * NC + c] = acc[c] * norm;
    }
  }
}

}  // namespace

void Scene::render_impl(double t_us, bool color, cv::Mat& out) {
  const int ss = spec_.supersample;
  const double bs = spec_.background_scale;
  // Texture pixel u has its center at world coordinate (u + 0.5) / bs.
  const glm::dmat3 tex_from_world = translate(glm::dvec2(-0.5)) * scale(bs, bs);
  const glm::dmat3 mb3 = tex_from_world * world_from_sensor(t_us);
  const double mb[6] = {mb3[0][0], mb3[1][0], mb3[2][0], mb3[0][1], mb3[1][1], mb3[2][1]};

  std::vector<SpriteDraw> draws;
  for (size_t i = 0; i < spec_.sprites.size(); ++i) {
    const cv::Mat& tex = color ? sprite_rgba_[i] : sprite_lum_alpha_[i];
    const SpriteSpec& s = spec_.sprites[i];
    // Sprite texture pixel u sits at local coordinate (u + 0.5) * size / texture_size.
    const glm::dmat3 local_from_tex = scale(s.size.x / tex.cols, s.size.y / tex.rows) * translate(glm::dvec2(0.5));
    const glm::dmat3 sensor_from_tex = sensor_from_sprite(i, t_us) * local_from_tex;
    SpriteDraw d;
    d.tex = &tex;
    d.x0 = d.y0 = 1e300;
    d.x1 = d.y1 = -1e300;
    for (glm::dvec2 c : {glm::dvec2(-1, -1), glm::dvec2(tex.cols, -1), glm::dvec2(-1, tex.rows), glm::dvec2(tex.cols, tex.rows)}) {
      const glm::dvec3 p = sensor_from_tex * glm::dvec3(c, 1.0);
      d.x0 = std::min(d.x0, p.x); d.y0 = std::min(d.y0, p.y); d.x1 = std::max(d.x1, p.x); d.y1 = std::max(d.y1, p.y);
    }
    if (d.x1 < -1 || d.y1 < -1 || d.x0 > spec_.width || d.y0 > spec_.height) continue;  // off screen
    const glm::dmat3 inv = glm::inverse(sensor_from_tex);
    const double m[6] = {inv[0][0], inv[1][0], inv[2][0], inv[0][1], inv[1][1], inv[2][1]};
    std::copy(m, m + 6, d.m);
    draws.push_back(d);
  }
  const float g = static_cast<float>(gain(t_us));
  out.create(spec_.height, spec_.width, color ? CV_32FC3 : CV_32FC1);
  const cv::Mat& bg = color ? background_color_ : background_lum_;
  // Rows are independent: deterministic under any thread count.
  cv::parallel_for_(cv::Range(0, spec_.height), [&](const cv::Range& rows) {
    if (color) render_rows<3>(rows, spec_.width, ss, bg, mb, draws, g, out);
    else render_rows<1>(rows, spec_.width, ss, bg, mb, draws, g, out);
  });
}

nlohmann::json Scene::describe() const {
  using nlohmann::json;
  const CameraMotion& m = spec_.camera;
  json cam = {{"world_center_px", {spec_.world_center.x, spec_.world_center.y}},
              {"velocity_px_s", {m.velocity.x, m.velocity.y}},
              {"acceleration_px_s2", {m.acceleration.x, m.acceleration.y}},
              {"angular_velocity_rad_s", m.angular_velocity},
              {"angular_acceleration_rad_s2", m.angular_acceleration},
              {"zoom_rate_per_s", m.zoom_rate},
              {"shake_amplitude_px", m.shake_amplitude_px},
              {"shake_hz", m.shake_hz},
              {"shake_rotation_rad", m.shake_rotation_rad},
              {"shake_phase_rad", {m.shake_phase.x, m.shake_phase.y, m.shake_phase.z, m.shake_phase.w}}};
  json sprites = json::array();
  for (const SpriteSpec& s : spec_.sprites)
    sprites.push_back({{"shape", sprite_shape_name(s.shape)},
                       {"size_px", {s.size.x, s.size.y}},
                       {"position_px", {s.position.x, s.position.y}},
                       {"velocity_px_s", {s.velocity.x, s.velocity.y}},
                       {"acceleration_px_s2", {s.acceleration.x, s.acceleration.y}},
                       {"angle_rad", s.angle},
                       {"angular_velocity_rad_s", s.angular_velocity},
                       {"textured", !s.texture.empty()}});
  return {{"camera", cam},
          {"sprites", sprites},
          {"supersample", spec_.supersample},
          {"background_scale", spec_.background_scale},
          {"background_size", {background_color_.cols, background_color_.rows}},
          {"flicker_amplitude", spec_.flicker_amplitude},
          {"flicker_hz", spec_.flicker_hz},
          {"log_gain_rate_per_s", spec_.log_gain_rate},
          {"gain", spec_.gain}};
}

// ---- scene builder -----------------------------------------------------------------------------

SceneSpec build_scene(const SceneOptions& o) {
  if (o.width < 2 || o.height < 2) throw UsageError("scene: size must be at least 2x2");
  if (!(o.duration_us > 0)) throw UsageError("scene: duration must be > 0");
  SceneSpec spec;
  spec.width = o.width;
  spec.height = o.height;
  spec.supersample = o.supersample;
  // Preset speeds are for a 346-pixel-wide view; smaller views move proportionally slower so the
  // motion looks the same in pixels per frame width.
  const double k = o.speed_scale * o.width / 346.0;
  spec.camera = camera_motion_preset(o.motion, k, o.seed);
  spec.flicker_amplitude = o.flicker_amplitude;
  spec.flicker_hz = o.flicker_hz;

  // World extent seen over the whole duration (sampled every ms): the background must cover it.
  SceneSpec probe = spec;
  probe.world_center = glm::dvec2(0.0);
  const Scene probe_scene(probe);
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  const int samples = std::max(2, static_cast<int>(o.duration_us / 1000.0) + 1);
  for (int i = 0; i <= samples; ++i) {
    const glm::dmat3 m = probe_scene.world_from_sensor(o.duration_us * i / samples);
    for (glm::dvec2 c : {glm::dvec2(-1, -1), glm::dvec2(o.width, -1), glm::dvec2(-1, o.height), glm::dvec2(o.width, o.height)}) {
      const glm::dvec3 p = m * glm::dvec3(c, 1.0);
      x0 = std::min(x0, p.x); y0 = std::min(y0, p.y); x1 = std::max(x1, p.x); y1 = std::max(y1, p.y);
    }
  }
  const double margin = 8.0;
  // Texture resolution matches the render supersampling at zoom 1; capped in size (beyond the cap
  // the texture repeats by reflection, and zoomed-in views get slightly softer).
  const double world_w = x1 - x0 + 2 * margin, world_h = y1 - y0 + 2 * margin;
  double bs = o.supersample;
  const double cap = 6144.0;
  bs = std::min(bs, cap / std::max(world_w, world_h));
  bs = std::max(bs, 0.25);
  const cv::Size tex_size(static_cast<int>(std::ceil(world_w * bs)), static_cast<int>(std::ceil(world_h * bs)));
  spec.background_scale = bs;
  spec.world_center = glm::dvec2(margin - x0, margin - y0);

  if (!o.texture_file.empty()) {
    cv::Mat t = load_texture(o.texture_file, o.gamma);
    // Scale to cover the needed extent, keeping the aspect ratio; crop the centered part.
    const double f = std::max(static_cast<double>(tex_size.width) / t.cols, static_cast<double>(tex_size.height) / t.rows);
    cv::Mat r;
    cv::resize(t, r, cv::Size(std::max(tex_size.width, static_cast<int>(std::ceil(t.cols * f))),
                              std::max(tex_size.height, static_cast<int>(std::ceil(t.rows * f)))),
               0, 0, f < 1 ? cv::INTER_AREA : cv::INTER_CUBIC);
    spec.background = r(cv::Rect((r.cols - tex_size.width) / 2, (r.rows - tex_size.height) / 2, tex_size.width, tex_size.height)).clone();
    spec.background = cv::max(spec.background, 0.0);
  } else {
    // Features of ~7% of the view height (at least 4 px): detailed, yet resolvable.
    // Drawn at >= 2 texels per pixel, then area-averaged to the render resolution: the texture
    // is box-prefiltered, so even one sample per pixel is anti-aliased.
    const int up = bs < 2 ? 2 : 1;
    const double feature = std::max(4.0, 0.07 * o.height) * bs * up;
    cv::Mat tex = make_texture(o.texture, cv::Size(tex_size.width * up, tex_size.height * up), o.seed, feature, o.gamma);
    if (up > 1) cv::resize(tex, tex, tex_size, 0, 0, cv::INTER_AREA);
    spec.background = tex;
  }

  Rng rng(o.seed, 0x5971);
  const double kspr = o.width / 346.0;
  for (int i = 0; i < o.sprites; ++i) {
    SpriteSpec s;
    s.shape = static_cast<SpriteShape>(rng.integer(0, 2));
    const double base = o.height * rng.uniform(0.15, 0.32);
    // At least one pixel: on a tiny sensor (2x2) a sprite is a pixel, not an error.
    s.size = glm::max(glm::dvec2(base * rng.uniform(0.7, 1.5), base * rng.uniform(0.7, 1.5)), glm::dvec2(1.0));
    s.position = glm::dvec2(rng.uniform(0.15, 0.85) * o.width, rng.uniform(0.15, 0.85) * o.height);
    const double speed = rng.uniform(100.0, 280.0) * kspr * o.speed_scale, dir = rng.uniform(0, kTwoPi);
    s.velocity = speed * glm::dvec2(std::cos(dir), std::sin(dir));
    // Pull back toward the view center so sprites stay visible over the sequence.
    const double accel = rng.uniform(200.0, 900.0) * kspr * o.speed_scale;
    s.acceleration = -accel * glm::normalize(s.velocity + glm::dvec2(1e-9));
    s.angle = rng.uniform(0, kTwoPi);
    s.angular_velocity = rng.uniform(-1.5, 1.5) * o.speed_scale;
    const cv::Size ts(std::max(8, static_cast<int>(s.size.x * o.supersample)), std::max(8, static_cast<int>(s.size.y * o.supersample)));
    const TextureKind kinds[] = {TextureKind::Checkerboard, TextureKind::Noise, TextureKind::Bars};
    s.texture = make_texture(kinds[rng.integer(0, 2)], ts, o.seed * 1000 + 17 + i, std::max(3.0, ts.height / 4.0), o.gamma);
    spec.sprites.push_back(s);
  }
  return spec;
}

}  // namespace vkunroll::sim
