// `vkunroll unroll`: a recording (sequence folder) -> GS frames at chosen instants, with the
// learned model (SelfUnroll-S/-M) or the weight-free physics unroller, streaming frame by frame
// through one UnrollSession (host/unroll/session.hpp).
#pragma once
#include <vector>

#include <nlohmann/json.hpp>

#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

// Runs the whole job; returns summary.json's content (also written to out_dir).
nlohmann::json run_unroll(const UnrollOptions& options);

// The contrast threshold c for the physics unroller, estimated from the sequence: for up to
// three pairs of consecutive frames, both frames are unrolled to the instant halfway between
// their mid-exposures, and c is the value on a grid (0.05 .. 0.6, step 0.025) that makes the two
// estimates agree best (least mean |log difference|) — the temporal consistency SelfUnroll
// trains on. Without a pair of consecutive frames it is no estimate: 0.2, said so in `source` and
// `warning`. A value on the grid's edge (0.05 or 0.6) comes with a warning: the true threshold may
// lie outside, or noise dominates the consistency.
ContrastEstimate estimate_contrast(const Sequence& seq, const std::vector<int>& frames, double gamma);

}  // namespace vkunroll
