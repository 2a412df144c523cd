// `vkunroll unroll`: a recording (sequence folder) -> GS frames at chosen instants, with the
// learned model (SelfUnroll-S/-M) or the weight-free physics unroller, streaming frame by frame
// through one UnrollSession (host/unroll/session.hpp).
#pragma once
#include <nlohmann/json.hpp>

#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

// Runs the whole job; returns summary.json's content (also written to out_dir).
nlohmann::json run_unroll(const UnrollOptions& options);


}  // namespace vkunroll
