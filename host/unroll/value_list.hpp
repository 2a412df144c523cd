// Lists of numbers on the command line: comma lists "-0.25,0.5,1.25" and ranges.
//   values: "start:stop:count" = count evenly spaced values, both ends included
//           (0:1:5 = 0, 0.25, 0.5, 0.75, 1; count 1 = start). Items are exact Rationals
//           ("1/3", "0.1"), and ranges and single values mix: "0:1:3,1.25".
//   frames: integers; "a:b" = a, a+1, ..., b; "a:b:n" = n evenly spaced values that must be integers.
#pragma once
#include <string>
#include <vector>

#include "vkunroll/base/row_timing.hpp"

namespace vkunroll {

// Errors are OptionErrors of the field `what` (e.g. "times_us").
std::vector<Rational> parse_value_list(const std::string& text, const std::string& what);
std::vector<int> parse_frame_list(const std::string& text, const std::string& what);

}  // namespace vkunroll
