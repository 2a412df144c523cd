// Fused activations; ACT and SLOPE are specialization constants of the including shader.
// Codes match vkunroll::Activation: 0 none, 1 leaky_relu, 2 tanh, 3 sigmoid, 4 hardsigmoid.
float act_tanh(float v) {
  // exp of a non-positive argument never overflows, so large |v| gives +-1, not NaN.
  float e = exp(-2.0 * abs(v));
  return sign(v) * (1.0 - e) / (1.0 + e);
}
float act(float v) {
  if (ACT == 1u) return v >= 0.0 ? v : v * SLOPE;
  if (ACT == 2u) return act_tanh(v);
  if (ACT == 3u) return 1.0 / (1.0 + exp(-v));
  if (ACT == 4u) return clamp(v / 6.0 + 0.5, 0.0, 1.0);
  return v;
}
vec4 act4(vec4 v) { return vec4(act(v.x), act(v.y), act(v.z), act(v.w)); }
