#include "vkunroll/host/model/backend.hpp"

#include <algorithm>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

int PlanningBackend::alloc_id(const Shape& shape, const std::string& what) {
  // As VulkanBackend: past the pool limit, released buffers are freed before the allocation.
  if (pooled_bytes_ > pool_flush_bytes_) flush();
  const uint64_t bytes = static_cast<uint64_t>(shape.count()) * 4;
  if (bytes > max_buffer_bytes_)
    throw DataError("plan: " + what + " " + shape.str() + " needs " + std::to_string(bytes >> 20) +
                " MiB, above the storage-buffer limit of " + std::to_string(max_buffer_bytes_ >> 20) + " MiB");
  if (bytes > largest_) {
    largest_ = bytes;
    largest_name_ = what + " " + shape.str();
  }
  shapes_.push_back(shape);
  names_.push_back(what);
  live_.push_back(true);
  const uint64_t before = peak_bytes();
  account_alloc(bytes);
  if (peak_bytes() > before) {
    std::vector<std::pair<uint64_t, std::string>> live;
    for (size_t i = 0; i < shapes_.size(); ++i)
      if (live_[i]) live.push_back({uint64_t(shapes_[i].count()) * 4, names_[i] + " " + shapes_[i].str()});
    std::sort(live.begin(), live.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    peak_buffers_.clear();
    for (const auto& [b, n] : live) peak_buffers_ += (peak_buffers_.empty() ? "" : ", ") + n;
  }
  // As VulkanBackend: a pooled buffer of the same size is reused.
  auto reuse = std::find_if(pooled_.begin(), pooled_.end(), [&](const Shape& p) { return p.count() == shape.count(); });
  if (reuse != pooled_.end()) {
    pooled_.erase(reuse);
    pooled_bytes_ -= bytes;
  } else {
    device_bytes_ += bytes;
    device_peak_ = std::max(device_peak_, device_bytes_);
  }
  return static_cast<int>(shapes_.size() - 1);
}

void PlanningBackend::release_id(int buf) noexcept {
  live_[size_t(buf)] = false;  // a live buffer: only its handle releases it, once
  account_release(static_cast<uint64_t>(shapes_[size_t(buf)].count()) * 4);
  pooled_.push_back(shapes_[size_t(buf)]);
  pooled_bytes_ += static_cast<uint64_t>(shapes_[size_t(buf)].count()) * 4;
}

void PlanningBackend::flush() {
  for (const auto& s : pooled_) device_bytes_ -= static_cast<uint64_t>(s.count()) * 4;
  pooled_.clear();
  pooled_bytes_ = 0;
}

int PlanningBackend::event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                      const EventTensorSpec& spec) {
  const SensorCrop c = resolve_crop(spec.crop, events.width, events.height);
  return alloc_id({3 * static_cast<int64_t>(pairs.size()), 2 * spec.bins, c.height, c.width}, "event tensors");
}

Shape PlanningBackend::shape(int buf) const { return shapes_.at(static_cast<size_t>(buf)); }

std::vector<float> Backend::download(const BufferSlice& v) {
  const Shape s = shape(v.buf);
  std::vector<float> out(static_cast<size_t>(v.n * v.c * s.h * s.w));
  download(v, out);
  flush();
  return out;
}

Shape Backend::slice_shape(const BufferSlice& v) const {
  Shape s = shape(v.buf);
  s.n = v.n, s.c = v.c;
  return s;
}

void Backend::conv_folded(int conv, const ConvDesc& desc, const std::vector<BufferSlice>& pieces, const ConvFold& fold,
                          const BufferSlice& out) {
  if (desc.transposed) throw InternalError(desc.name + ": a transposed conv is not folded");
  std::vector<Shape> shapes;
  for (const BufferSlice& v : pieces) shapes.push_back(slice_shape(v));
  const Shape is = fold.conv_input(shapes, desc.name);
  if (conv_folded_at_once(conv, pieces, is, fold, out)) return;
  // The separate ops: the input made whole (unless it is one plain piece), the conv, crop, tanh.
  Buffer x;
  BufferSlice xin = pieces.at(0);
  if (pieces.size() > 1 || fold.map != InputMap::none) {
    x = alloc(is, desc.name + ".input");
    int64_t c0 = 0;
    for (size_t i = 0; i < pieces.size(); ++i) {
      const int64_t c = fold.piece_channels(shapes[i].c);
      const BufferSlice dst{x.id(), 0, is.n, c0, c};
      if (fold.map == InputMap::reflect_pad) reflect_pad(pieces[i], dst, int(fold.top), int(fold.left));
      else if (fold.map == InputMap::space_to_depth) space_to_depth(pieces[i], dst);
      else if (fold.map == InputMap::depth_to_space) depth_to_space(pieces[i], dst);
      else copy(pieces[i], dst);
      c0 += c;
    }
    xin = x.whole();
  }
  const Shape full{is.n, desc.cout, conv_output_size(is.h, desc.k, desc.stride, desc.pad),
                   conv_output_size(is.w, desc.k, desc.stride, desc.pad)};
  const Shape os = slice_shape(out);
  const bool crops = fold.crop_top || fold.crop_left || os.h != full.h || os.w != full.w;
  if (!crops && fold.tanh_scale <= 0) {
    this->conv(conv, xin, out, nullptr);
    return;
  }
  Buffer y = alloc(full, desc.name + ".output");
  this->conv(conv, xin, y.whole(), nullptr);
  x.reset();
  if (fold.tanh_scale <= 0) {
    crop(y.whole(), out, int(fold.crop_top), int(fold.crop_left));
  } else if (!crops) {
    tanh_scale(y.whole(), out, fold.tanh_scale);
  } else {
    Buffer c = alloc(os, desc.name + ".cropped");
    crop(y.whole(), c.whole(), int(fold.crop_top), int(fold.crop_left));
    y.reset();
    tanh_scale(c.whole(), out, fold.tanh_scale);
  }
}

}  // namespace vkunroll
