#include "vkunroll/host/unroll/image_planes.hpp"

#include <utility>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

std::vector<float> image_planes(const cv::Mat& bgr, bool rgb) {
  if (bgr.type() != CV_32FC3) throw InternalError("image_planes: a 3-channel float32 image is expected");
  std::vector<cv::Mat> ch;
  cv::split(bgr, ch);
  if (rgb) std::swap(ch[0], ch[2]);
  std::vector<float> dst;
  dst.reserve(bgr.total() * 3);
  for (const auto& c : ch) {
    const cv::Mat cont = c.isContinuous() ? c : c.clone();
    dst.insert(dst.end(), cont.ptr<float>(), cont.ptr<float>() + cont.total());
  }
  return dst;
}

cv::Mat planes_image(const float* p, int h, int w, bool rgb) {
  std::vector<cv::Mat> ch;
  for (int c = 0; c < 3; ++c) ch.push_back(cv::Mat(h, w, CV_32F, const_cast<float*>(p + static_cast<size_t>(c) * h * w)).clone());
  if (rgb) std::swap(ch[0], ch[2]);
  cv::Mat out;
  cv::merge(ch, out);
  return out;
}

}  // namespace vkunroll
