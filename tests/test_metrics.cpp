// PSNR and SSIM against values known in closed form.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/base/error.hpp"

using namespace vkunroll;

TEST(Metrics, PsnrOfAConstantOffset) {
  // Values exact in float: the difference is 0.125, MSE 1/64.
  cv::Mat a(20, 30, CV_32FC3, cv::Scalar(0.5, 0.5, 0.5)), b(20, 30, CV_32FC3, cv::Scalar(0.625, 0.625, 0.625));
  EXPECT_NEAR(psnr(a, b), 10.0 * std::log10(64.0), 1e-9);
  EXPECT_TRUE(std::isinf(psnr(a, a)));
  cv::Mat a8(20, 30, CV_8UC1, cv::Scalar(0)), b8(20, 30, CV_8UC1, cv::Scalar(255));
  EXPECT_NEAR(psnr(a8, b8), 0.0, 1e-9);
}

TEST(Metrics, PsnrClampsToUnitRange) {
  cv::Mat a(4, 4, CV_32FC1, cv::Scalar(1.7)), b(4, 4, CV_32FC1, cv::Scalar(1.0));
  EXPECT_TRUE(std::isinf(psnr(a, b)));  // both clamp to 1
}

TEST(Metrics, SsimOfConstantImagesIsClosedForm) {
  const double x = 0.25, y = 0.75, C1 = 1e-4;  // exact in float
  cv::Mat a(32, 32, CV_32FC1, cv::Scalar(x)), b(32, 32, CV_32FC1, cv::Scalar(y));
  EXPECT_NEAR(ssim(a, b), (2 * x * y + C1) / (x * x + y * y + C1), 1e-9);
  EXPECT_NEAR(ssim(a, a), 1.0, 1e-12);
}

TEST(Metrics, SsimDropsWithNoiseAndIsSymmetric) {
  cv::Mat a(48, 64, CV_32FC3), n(48, 64, CV_32FC3);
  cv::randu(a, 0.2, 0.8);
  cv::randn(n, 0, 0.05);
  cv::Mat b = a + n;
  const double s1 = ssim(a, b), s2 = ssim(b, a);
  EXPECT_LT(s1, 0.99);
  EXPECT_GT(s1, 0.3);
  EXPECT_NEAR(s1, s2, 1e-12);
  cv::Mat c = a + 2 * n;
  EXPECT_LT(ssim(a, c), s1);
}

TEST(Metrics, MismatchedSizesAreAnError) {
  cv::Mat a(4, 4, CV_32FC1), b(4, 5, CV_32FC1);
  EXPECT_THROW(psnr(a, b), Error);
  EXPECT_THROW(ssim(a, b), Error);
}
