// Deterministic random numbers for the simulator: counter-based hashing (so results do not depend
// on thread scheduling or library versions) and a small seeded generator for scene construction.
#pragma once
#include <cmath>
#include <cstdint>

namespace vkunroll::sim {

// SplitMix64 finalizer: a fast, well-mixed 64-bit hash.
inline uint64_t mix64(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// Hash of a (seed, stream, counter) triple: the i-th draw of stream `s` under `seed`.
inline uint64_t hash3(uint64_t seed, uint64_t stream, uint64_t counter) {
  return mix64(mix64(mix64(seed) ^ stream) ^ counter);
}

// Uniform in [0, 1) from the top 53 bits.
inline double to_unit(uint64_t bits) { return static_cast<double>(bits >> 11) * 0x1.0p-53; }
// Uniform in (0, 1]: safe for log().
inline double to_unit_open0(uint64_t bits) { return (static_cast<double>(bits >> 11) + 1.0) * 0x1.0p-53; }

// Standard normal from two hashed uniforms (Box-Muller).
inline double normal_from(uint64_t a, uint64_t b) {
  const double u1 = to_unit_open0(a), u2 = to_unit(b);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

// Sequential seeded generator for building scenes (textures, sprites); identical on every platform.
class Rng {
 public:
  explicit Rng(uint64_t seed, uint64_t stream = 0) : state_(mix64(seed) ^ mix64(stream + 0x51ED)) {}
  uint64_t next() { return mix64(state_++); }
  double uniform() { return to_unit(next()); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  int integer(int lo, int hi_inclusive) {
    return lo + static_cast<int>(next() % static_cast<uint64_t>(hi_inclusive - lo + 1));
  }
  double normal() { return normal_from(next(), next()); }
  bool chance(double p) { return uniform() < p; }

 private:
  uint64_t state_;
};

}  // namespace vkunroll::sim
