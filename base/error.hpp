// The base of every error vkunroll throws: the message always says what and where (file, record,
// option). Vulkan failures derive from it in runtime/vk_error.hpp; this header needs no Vulkan.
#pragma once
#include <stdexcept>
#include <string>

namespace vkunroll {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

}  // namespace vkunroll
