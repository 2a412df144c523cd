// Random model inputs for the benches (fixed seed): rs and phys uniform in [0, 1), event channels
// with a quarter of the values 0-3 events and the rest none.
#pragma once
#include <cstdint>
#include <random>
#include <vector>

#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"

inline vkunroll::HostTensor random_array(std::mt19937& rng, int64_t b, int64_t c, int64_t h, int64_t w, bool events) {
  std::uniform_real_distribution<float> u(0.f, 1.f);
  vkunroll::HostTensor a{{b, c, h, w}, std::vector<float>(size_t(b * c * h * w))};
  for (auto& v : a.data) v = events ? (u(rng) < 0.25f ? float(int(u(rng) * 4)) : 0.f) : u(rng);
  return a;
}

// B items of H x W for the configuration (phys only where the model takes it), from seed 7.
inline vkunroll::ModelInputs random_model_inputs(const vkunroll::ModelConfig& cfg, int64_t B, int64_t H, int64_t W) {
  std::mt19937 rng(7);
  vkunroll::ModelInputs in;
  in.rs = random_array(rng, B, 3, H, W, false);
  in.ev1 = random_array(rng, B, cfg.ev_channels(), H, W, true);
  in.ev2 = random_array(rng, B, cfg.ev_channels(), H, W, true);
  in.ev3 = random_array(rng, B, cfg.ev_channels(), H, W, true);
  if (cfg.physics_input) in.phys = random_array(rng, B, 3, H, W, false);
  return in;
}
