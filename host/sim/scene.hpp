// Simulated scenes: a background texture seen by a moving camera, textured foreground sprites
// with their own motion, and a global illumination gain (flicker, ramps). Rendering returns the
// sharp global-shutter image in LINEAR intensity at any instant, anti-aliased by supersampling.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "vkunroll/base/luminance.hpp"  // kLumB, kLumG, kLumR

namespace vkunroll::sim {

// ---- textures ----------------------------------------------------------------------------------
enum class TextureKind { Checkerboard, Bars, Noise, Text, Mixed };
TextureKind parse_texture_kind(const std::string& name);  // throws Error naming the valid kinds
const char* texture_kind_name(TextureKind kind);

// A procedural color texture in LINEAR intensity (CV_32FC3, BGR). Values are drawn in display
// (gamma-encoded) space in [0.12, 0.92] and linearized with `gamma`, so dark areas are realistic.
// `feature_px` is the typical feature size (checker cell, bar width, letter height) in texture pixels.
cv::Mat make_texture(TextureKind kind, cv::Size size, uint64_t seed, double feature_px, double gamma);
// Loads an image file (8/16-bit, gray or color) and converts it to linear intensity with `gamma`.
cv::Mat load_texture(const std::string& path, double gamma);

// ---- motion ------------------------------------------------------------------------------------
// Camera pose over time. World units are sensor pixels at zoom 1; t is in seconds from t = 0.
// world(p) = c(t) + R(theta(t)) * (p - sensor_center) / zoom(t), with
//   c(t) = c0 + v t + a t^2 / 2 + shake(t),  theta(t) = w t + alpha t^2 / 2 + shake_rot(t),
//   zoom(t) = exp(zoom_rate t).
// Shake is a sum of incommensurate sinusoids (hand tremor), so motion is never linear.
struct CameraMotion {
  glm::dvec2 velocity{0.0};            // px/s
  glm::dvec2 acceleration{0.0};        // px/s^2
  double angular_velocity = 0.0;       // rad/s
  double angular_acceleration = 0.0;   // rad/s^2
  double zoom_rate = 0.0;              // d(log zoom)/dt in 1/s (> 0 zooms in)
  double shake_amplitude_px = 0.0;     // peak of the main shake term
  double shake_hz = 0.0;               // main shake frequency
  double shake_rotation_rad = 0.0;     // peak rotational shake
  glm::dvec4 shake_phase{0.0};         // phases of the shake terms (radians), from the seed
};

enum class MotionKind { Static, Pan, Accelerate, Rotate, Zoom, Shake, Mixed };
MotionKind parse_motion_kind(const std::string& name);  // throws Error naming the valid kinds
const char* motion_kind_name(MotionKind kind);
// The camera motion of a preset; speeds are multiplied by `speed_scale` (1 = DAVIS346-sized view).
CameraMotion camera_motion_preset(MotionKind kind, double speed_scale, uint64_t seed);

// ---- sprites -----------------------------------------------------------------------------------
enum class SpriteShape { Rectangle, Ellipse, Star };
const char* sprite_shape_name(SpriteShape shape);

// A foreground object moving in SENSOR coordinates (its motion is relative to the camera; it
// occludes the background). Its texture is stretched over its size x/y box.
struct SpriteSpec {
  SpriteShape shape = SpriteShape::Rectangle;
  glm::dvec2 size{20.0, 20.0};          // px
  glm::dvec2 position{0.0};             // center at t = 0, sensor px
  glm::dvec2 velocity{0.0};             // px/s
  glm::dvec2 acceleration{0.0};         // px/s^2
  double angle = 0.0;                   // rad at t = 0
  double angular_velocity = 0.0;        // rad/s
  cv::Mat texture;                      // CV_32FC3 linear; empty = uniform `color`
  cv::Scalar color{0.8, 0.8, 0.8};      // linear BGR when texture is empty
};

// ---- the scene ---------------------------------------------------------------------------------
struct SceneSpec {
  int width = 346, height = 260;
  int supersample = 1;                  // S x S samples per pixel, box-filtered (textures are prefiltered)
  cv::Mat background;                   // CV_32FC3 linear; empty = uniform `background_color`
  cv::Scalar background_color{0.2, 0.2, 0.2};
  double background_scale = 1.0;        // background texture pixels per world pixel
  glm::dvec2 world_center{0.0};         // world point at the sensor center at t = 0
  CameraMotion camera;
  std::vector<SpriteSpec> sprites;
  double flicker_amplitude = 0.0;       // gain *= 1 + A sin(2 pi f t)
  double flicker_hz = 0.0;
  double log_gain_rate = 0.0;           // gain *= exp(rate * t_s): illumination ramps
  double gain = 1.0;                    // overall intensity scale
};

class Scene {
 public:
  explicit Scene(SceneSpec spec);  // validates; precomputes sprite and luminance textures

  const SceneSpec& spec() const { return spec_; }
  int width() const { return spec_.width; }
  int height() const { return spec_.height; }

  // Maps homogeneous sensor pixel coordinates (pixel centers at integers) to world coordinates.
  glm::dmat3 world_from_sensor(double t_us) const;
  // Maps sprite-local coordinates ([0,size.x] x [0,size.y]) to sensor pixel coordinates.
  glm::dmat3 sensor_from_sprite(size_t index, double t_us) const;
  double gain(double t_us) const;

  // The sharp global-shutter image at t: CV_32FC3 (BGR) linear intensity, width x height.
  void render(double t_us, cv::Mat& color);
  // Its luminance (Rec. 709 weights on linear BGR), CV_32FC1; cheaper than render + convert.
  void render_luminance(double t_us, cv::Mat& luminance);

  nlohmann::json describe() const;  // every number that defines the motion, for meta.json

 private:
  void render_impl(double t_us, bool color, cv::Mat& out);

  SceneSpec spec_;
  cv::Mat background_color_, background_lum_;             // C3 / C1
  std::vector<cv::Mat> sprite_rgba_, sprite_lum_alpha_;   // premultiplied C4 / C2
};

// Builds a complete scene from a few choices (what `vkunroll simulate` exposes).
struct SceneOptions {
  int width = 346, height = 260;
  int supersample = 1;
  TextureKind texture = TextureKind::Mixed;
  std::string texture_file;        // non-empty: use this image instead of a procedural texture
  MotionKind motion = MotionKind::Mixed;
  double speed_scale = 1.0;        // multiplies preset speeds (on top of the width/346 scaling)
  int sprites = 2;
  double flicker_amplitude = 0.0, flicker_hz = 0.0;
  double duration_us = 1e6;        // the background is made large enough for this long
  double gamma = 2.2;
  uint64_t seed = 1;
};
SceneSpec build_scene(const SceneOptions& options);

}  // namespace vkunroll::sim
