// OpenCV images <-> the [3, H, W] planes the model and the physics unroller read.
#pragma once
#include <vector>

#include <opencv2/core.hpp>

namespace vkunroll {

// The planes of a 3-channel float BGR image, in RGB order when `rgb`.
std::vector<float> image_planes(const cv::Mat& bgr, bool rgb);
// A float BGR image from [3, H, W] planes in RGB order when `rgb`.
cv::Mat planes_image(const float* planes, int height, int width, bool rgb);

}  // namespace vkunroll
