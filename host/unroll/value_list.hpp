// Lists of numbers on the command line: comma lists "-0.25,0.5,1.25" and ranges.
//   values: "start:stop:count" = count evenly spaced values, both ends included
//           (0:1:5 = 0, 0.25, 0.5, 0.75, 1; count 1 = start). Items are exact Rationals
//           ("1/3", "0.1"), and ranges and single values mix: "0:1:3,1.25".
//   frames: integers; "a:b" = a, a+1, ..., b; "a:b:n" = n evenly spaced values that must be integers.
#pragma once
#include <string>
#include <vector>

#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/kernels/event_tensor.hpp"

namespace vkunroll {

// Errors are OptionErrors of the field `what` (e.g. "times_us").
std::vector<Rational> parse_value_list(const std::string& text, const std::string& what);
std::vector<int> parse_frame_list(const std::string& text, const std::string& what);

// The rule of every list of targets or frames, whichever front end built it: each value once (a
// value twice would compute and write the same result twice). OptionError of `what` naming the
// value; `listed`: the list as the user typed it, shown in the message when given.
void refuse_repeated(const std::vector<Rational>& values, const std::string& what, bool frames,
                     const std::string& listed = {});

// A crop a user gives (`voxelize --crop`, Python's event_tensors(crop=)): x0, y0 >= 0 and a positive
// width and height, one rule for both front ends (OptionError naming `field`). The spec's width 0
// ("up to the edge") is how no crop is stored, never a value a user gives.
SensorCrop user_crop(const std::vector<long long>& x0_y0_width_height, const std::string& field);

}  // namespace vkunroll
