// The file formats of the GS frames: 8- or 16-bit PNG, or float32 NumPy arrays for research.
//   png8, png16: BGR images clamped to [0, 1], rounded to 255 / 65535 steps.
//   npy: float32 [H, W, 3] in RGB order, C order, little-endian (NumPy's '<f4'), the values as
//        computed (not clamped: 1.0 is the RS input's white; results may leave [0, 1] slightly).
#pragma once
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

namespace vkunroll {

enum class FrameFormat { png8, png16, npy };
FrameFormat parse_frame_format(const std::string& s, const std::string& what);  // "png8" | "png16" | "npy"
const char* frame_format_name(FrameFormat f);
const char* frame_format_extension(FrameFormat f);  // ".png" or ".npy"

// `image`: float32 BGR (or gray) in [0, 1]. Returns the file's bytes.
std::string encode_frame(const cv::Mat& image, FrameFormat format);
// The bytes of encode_frame back as float32 BGR in [0, 1] (clamped; for the video and contact
// sheet of resumed frames). Throws DataError naming `what` when they do not decode.
cv::Mat decode_frame(std::string_view bytes, FrameFormat format, const std::string& what);

}  // namespace vkunroll
