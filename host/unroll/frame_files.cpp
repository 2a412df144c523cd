#include "vkunroll/host/unroll/frame_files.hpp"

#include <cstring>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/unroll/metrics.hpp"

namespace vkunroll {

namespace {

// The .npy header of a float32 [H, W, 3] array (format version 1.0, padded to 64 bytes).
std::string npy_header(int h, int w) {
  std::string dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (" + std::to_string(h) + ", " +
                     std::to_string(w) + ", 3), }";
  const size_t total = (10 + dict.size() + 1 + 63) / 64 * 64;
  dict.resize(total - 10 - 1, ' ');
  dict += '\n';
  std::string out = "\x93NUMPY";
  out += char(1), out += char(0);
  const uint16_t n = static_cast<uint16_t>(dict.size());
  out += char(n & 0xff), out += char(n >> 8);
  return out + dict;
}

}  // namespace

FrameFormat parse_frame_format(const std::string& s, const std::string& what) {
  if (s == "png8") return FrameFormat::png8;
  if (s == "png16") return FrameFormat::png16;
  if (s == "npy") return FrameFormat::npy;
  throw OptionError(what, "'" + s + "'", "expected png8, png16 or npy");
}

const char* frame_format_name(FrameFormat f) {
  switch (f) {
    case FrameFormat::png8: return "png8";
    case FrameFormat::png16: return "png16";
    case FrameFormat::npy: return "npy";
  }
  return "?";
}

const char* frame_format_extension(FrameFormat f) { return f == FrameFormat::npy ? ".npy" : ".png"; }

std::string encode_frame(const cv::Mat& image, FrameFormat format) {
  if (format == FrameFormat::npy) {
    cv::Mat f;
    image.convertTo(f, CV_MAKETYPE(CV_32F, image.channels()));
    if (f.channels() == 1) cv::cvtColor(f, f, cv::COLOR_GRAY2BGR);
    cv::cvtColor(f, f, cv::COLOR_BGR2RGB);
    if (!f.isContinuous()) f = f.clone();
    std::string out = npy_header(f.rows, f.cols);
    const size_t bytes = f.total() * 3 * sizeof(float);
    const size_t at = out.size();
    out.resize(at + bytes);
    std::memcpy(out.data() + at, f.data, bytes);  // x86/ARM hosts are little-endian, as '<f4' says
    return out;
  }
  cv::Mat unit = to_unit_float(image), png;
  unit.convertTo(png, format == FrameFormat::png16 ? CV_16U : CV_8U, format == FrameFormat::png16 ? 65535.0 : 255.0);
  std::vector<uchar> buf;
  if (!cv::imencode(".png", png, buf)) throw InternalError("OpenCV could not encode a PNG");
  return std::string(buf.begin(), buf.end());
}

cv::Mat decode_frame(std::string_view bytes, FrameFormat format, const std::string& what) {
  if (format == FrameFormat::npy) {
    if (bytes.size() < 10 || bytes.substr(0, 6) != "\x93NUMPY") throw DataError(what + ": not a .npy file");
    const size_t header = 10 + (uint8_t(bytes[8]) | uint8_t(bytes[9]) << 8);
    const std::string_view dict = bytes.substr(10, header > bytes.size() ? 0 : header - 10);
    const size_t s = dict.find("'shape': (");
    int h = 0, w = 0, c = 0;
    if (dict.find("'<f4'") == std::string_view::npos || s == std::string_view::npos ||
        std::sscanf(std::string(dict.substr(s + 10)).c_str(), "%d, %d, %d", &h, &w, &c) != 3 || c != 3 || h <= 0 || w <= 0 ||
        bytes.size() != header + size_t(h) * w * 3 * sizeof(float))
      throw DataError(what + ": not a float32 [H, W, 3] .npy written by vkunroll");
    cv::Mat rgb(h, w, CV_32FC3), bgr;
    std::memcpy(rgb.data, bytes.data() + header, size_t(h) * w * 3 * sizeof(float));
    cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
    return to_unit_float(bgr);
  }
  const std::vector<uchar> buf(bytes.begin(), bytes.end());
  cv::Mat m = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
  if (m.empty()) throw DataError(what + ": not a readable PNG");
  if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
  return to_unit_float(m);
}

}  // namespace vkunroll
