#include "vkunroll/host/unroll/metrics.hpp"

#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

cv::Mat to_unit_float(const cv::Mat& m) {
  cv::Mat f;
  const double scale = m.depth() == CV_8U ? 1.0 / 255 : m.depth() == CV_16U ? 1.0 / 65535 : 1.0;
  m.convertTo(f, CV_MAKETYPE(CV_32F, m.channels()), scale);
  cv::patchNaNs(f, 0.0);
  cv::min(cv::max(f, 0.0), 1.0, f);
  return f;
}

namespace {
void check_pair(const cv::Mat& a, const cv::Mat& b, const char* what) {
  if (a.empty() || b.empty()) throw UsageError(std::string(what) + ": empty image");
  if (a.size() != b.size() || a.channels() != b.channels())
    throw UsageError(std::string(what) + ": images differ in size or channels (" + std::to_string(a.cols) + "x" +
                std::to_string(a.rows) + "x" + std::to_string(a.channels()) + " vs " + std::to_string(b.cols) + "x" +
                std::to_string(b.rows) + "x" + std::to_string(b.channels()) + ")");
}
}  // namespace

double psnr(const cv::Mat& a, const cv::Mat& b) {
  check_pair(a, b, "psnr");
  cv::Mat fa = to_unit_float(a), fb = to_unit_float(b), d;
  cv::subtract(fa, fb, d, cv::noArray(), CV_64F);
  const cv::Scalar sq = cv::sum(d.mul(d));
  const double mse = sq[0] + sq[1] + sq[2] + sq[3];
  const double n = static_cast<double>(d.total()) * d.channels();
  if (mse <= 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(1.0 / (mse / n));
}

double ssim(const cv::Mat& a, const cv::Mat& b) {
  check_pair(a, b, "ssim");
  cv::Mat fa = to_unit_float(a), fb = to_unit_float(b);
  const int win = std::min({11, fa.rows, fa.cols});
  const double sigma = 1.5 * win / 11.0;
  const double C1 = 0.01 * 0.01, C2 = 0.03 * 0.03;
  cv::Mat g = cv::getGaussianKernel(win, sigma, CV_64F);
  std::vector<cv::Mat> ca, cb;
  cv::split(fa, ca);
  cv::split(fb, cb);
  double total = 0;
  const cv::Rect valid(win / 2, win / 2, fa.cols - win + 1, fa.rows - win + 1);
  for (size_t c = 0; c < ca.size(); ++c) {
    cv::Mat x, y;
    ca[c].convertTo(x, CV_64F);
    cb[c].convertTo(y, CV_64F);
    auto blur = [&](const cv::Mat& m) {
      cv::Mat r;
      cv::sepFilter2D(m, r, CV_64F, g, g, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
      return r(valid);
    };
    cv::Mat mx = blur(x), my = blur(y);
    cv::Mat sxx = blur(x.mul(x)) - mx.mul(mx), syy = blur(y.mul(y)) - my.mul(my), sxy = blur(x.mul(y)) - mx.mul(my);
    cv::Mat num = (2 * mx.mul(my) + C1).mul(2 * sxy + C2);
    cv::Mat den = (mx.mul(mx) + my.mul(my) + C1).mul(sxx + syy + C2);
    cv::Mat s;
    cv::divide(num, den, s);
    total += cv::mean(s)[0];
  }
  return total / static_cast<double>(ca.size());
}

}  // namespace vkunroll
