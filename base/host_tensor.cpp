#include "vkunroll/base/host_tensor.hpp"

#include <string>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

HostTensor::HostTensor(Shape s, float fill) : shape(s), data(static_cast<size_t>(s.count()), fill) {}

HostTensor::HostTensor(Shape s, std::vector<float> values) : shape(s), data(std::move(values)) {
  if (static_cast<int64_t>(data.size()) != s.count())
    throw UsageError("HostTensor: " + std::to_string(data.size()) + " values given for shape " + s.str() + " (" +
                std::to_string(s.count()) + " expected)");
}

}  // namespace vkunroll
