#include "host/backend.hpp"

#include "runtime/error.hpp"

namespace vkunroll {

int PlanningBackend::alloc(const Shape& shape, const std::string& what) {
  const uint64_t bytes = static_cast<uint64_t>(shape.count()) * 4;
  if (bytes > max_buffer_bytes_)
    throw Error("plan: " + what + " " + shape.str() + " needs " + std::to_string(bytes >> 20) +
                " MiB, above the storage-buffer limit of " + std::to_string(max_buffer_bytes_ >> 20) + " MiB");
  if (bytes > largest_) {
    largest_ = bytes;
    largest_name_ = what + " " + shape.str();
  }
  shapes_.push_back(shape);
  live_.push_back(true);
  account_alloc(bytes);
  return static_cast<int>(shapes_.size() - 1);
}

void PlanningBackend::release(int buf) {
  if (buf < 0 || buf >= static_cast<int>(shapes_.size()) || !live_[buf]) throw Error("plan: release of a dead buffer");
  live_[buf] = false;
  account_release(static_cast<uint64_t>(shapes_[buf].count()) * 4);
}

Shape PlanningBackend::shape(int buf) const { return shapes_.at(static_cast<size_t>(buf)); }

std::vector<float> PlanningBackend::download(const View& v) {
  const Shape s = shape(v.buf);
  return std::vector<float>(static_cast<size_t>(v.n * v.c * s.h * s.w));
}

}  // namespace vkunroll
