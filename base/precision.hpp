// The arithmetic precision of a run: a setting, chosen by the user, never by accident.
// fp32 is the reference; fp16 stores weights and activations in 16 bits (docs/kernels.md says
// which ops accumulate in fp32 and where values are guarded against overflow).
#pragma once
#include <string>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

enum class Precision { fp32, fp16 };

inline const char* precision_name(Precision p) { return p == Precision::fp16 ? "fp16" : "fp32"; }
// "fp32" | "fp16"; the OptionError names the field `what`.
inline Precision parse_precision(const std::string& s, const std::string& what = "precision") {
  if (s == "fp32") return Precision::fp32;
  if (s == "fp16") return Precision::fp16;
  throw OptionError(what, "'" + s + "'", "expected fp32 or fp16");
}

}  // namespace vkunroll
