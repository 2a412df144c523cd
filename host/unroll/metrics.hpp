// Image quality metrics, computed the way the reference evaluates: images clamped to [0, 1].
#pragma once
#include <vector>

#include <opencv2/core.hpp>

namespace vkunroll {

// PSNR in dB of two images of equal size and channel count (any depth; values taken as float
// in [0, 1] after clamping). Identical images give +infinity.
double psnr(const cv::Mat& a, const cv::Mat& b);

// SSIM of Wang et al. (2004): 11x11 Gaussian window, sigma 1.5, K1 = 0.01, K2 = 0.03, L = 1,
// averaged over the 'valid' window positions (no padding) and over the channels.
// Images smaller than the window fall back to a window of their own size.
double ssim(const cv::Mat& a, const cv::Mat& b);

// Converts an 8-bit, 16-bit or float image to float32 in [0, 1] (clamped).
cv::Mat to_unit_float(const cv::Mat& m);

}  // namespace vkunroll
