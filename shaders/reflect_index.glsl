// The source index of padded index i along an axis of n: PyTorch's reflection where the pad is
// below n, larger pads keep reflecting (period 2(n-1)), and a size-1 axis repeats its one value.
// One reflection (the size adapter's case) takes no division. The folding is even (index -i maps
// like i), so the remainder is taken of |i|: Vulkan leaves OpSMod/OpSRem of a negative operand
// undefined (NVIDIA returned wrong indices; lavapipe did not).
// REFLECT_ONCE (specialization constant 0, set by the host where every pad is below its axis and
// no axis has size 1) keeps only the one-reflection selects: llvmpipe runs every branch under a
// mask, so the general path's division would otherwise be paid on every pixel.
// VKU_REFLECT_GENERAL_ONLY (the GPU convs' folded pads, whose spec constant 0 is the kernel) leaves it out.
#ifdef VKU_REFLECT_GENERAL_ONLY
const bool REFLECT_ONCE = false;
#else
layout(constant_id = 0) const bool REFLECT_ONCE = false;
#endif
uint reflect_index(int i, int n) {
  if (REFLECT_ONCE) return uint(i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i));
  if (i >= 0 && i < n) return uint(i);
  if (n == 1) return 0u;
  if (i < 0 && -i < n) return uint(-i);
  if (i >= n && i < 2 * n - 1) return uint(2 * n - 2 - i);
  uint period = 2u * uint(n - 1);
  uint r = uint(abs(i)) % period;
  return r >= uint(n) ? period - r : r;
}
