#include "vkunroll/kernels/conv_options.hpp"

#include <initializer_list>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {
void check_one_of(const std::string& who, const char* field, int v, std::initializer_list<int> allowed) {
  if (v == 0) return;
  std::string list;
  for (int a : allowed) {
    if (a == v) return;
    list += (list.empty() ? "" : ", ") + std::to_string(a);
  }
  throw Error(who + ": ConvOptions::" + field + " = " + std::to_string(v) + " is not allowed (0 for the default, or " +
              list + ")");
}

void check_range(const std::string& who, const char* field, int v, int lo, int hi, int multiple = 1) {
  if (v == 0 || (v >= lo && v <= hi && v % multiple == 0)) return;
  throw Error(who + ": ConvOptions::" + field + " = " + std::to_string(v) + " is not allowed (0 for the default, or " +
              (multiple > 1 ? "a multiple of " + std::to_string(multiple) + " in " : std::string()) + "[" +
              std::to_string(lo) + ", " + std::to_string(hi) + "])");
}
}  // namespace

void ConvOptions::validate(const std::string& who) const {
  if (precision != Precision::fp32 && precision != Precision::fp16)
    throw Error(who + ": ConvOptions::precision = " + std::to_string(static_cast<uint32_t>(precision)) +
                " is not allowed (fp32 or fp16)");
  check_one_of(who, "blocked_cob", blocked_cob, {4, 8, 16});
  check_range(who, "blocked_px", blocked_px, 1, 16);
  check_range(who, "direct_cob", direct_cob, 4, 64, 4);
  check_range(who, "direct_px", direct_px, 1, 16);
  check_range(who, "direct_py", direct_py, 1, 8);
  check_one_of(who, "gemm_cob", gemm_cob, {4, 8, 16});
  check_one_of(who, "gemm_tv", gemm_tv, {1, 2, 4});
  check_one_of(who, "winograd_tile", winograd_tile, {6, 8});
  check_range(who, "pointwise_cob", pointwise_cob, 1, 32);
  check_range(who, "pointwise_px", pointwise_px, 1, 8);
}

}  // namespace vkunroll
