// Rec. 709 luminance weights of linear BGR: what an event pixel integrates (the simulator renders
// its events from it; the contrast estimate compares frames with events through it).
#pragma once

namespace vkunroll {

inline constexpr double kLumB = 0.0722, kLumG = 0.7152, kLumR = 0.2126;

}  // namespace vkunroll
