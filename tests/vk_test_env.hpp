// Test support: one validated Vulkan context per test process, and a listener that fails any
// test during which the validation layer reported a message.
#pragma once
#include <string>

#include <span>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/shader_registry.hpp"

namespace vkunroll::vktest {

// The lavapipe context of this test process (validation on), created on first use.
Context& context();
// A second lavapipe context that enforces a 256-byte minUniformBufferOffsetAlignment (lavapipe's is
// 16), to check what a strict GPU needs; a validation message aborts. Created on first use.
Context& strict_uniform_context();
// A third lavapipe context with ContextOptions::whole_tensor_bindings: every slice binds its whole
// tensor, so the canary tests see writes outside a slice (lavapipe drops writes past a binding). A
// validation message aborts. Created on first use.
Context& whole_binding_context();
// True when a context was created in this process (the listener only checks then).
bool context_created();
// The tests' own shaders (tests/shaders/*.comp), for runtime tests that know no kernel.
const ShaderModuleBlob& test_shader(std::string_view name);
inline std::span<const uint32_t> test_shader_words(std::string_view name) {
  const ShaderModuleBlob& b = test_shader(name);
  return {b.words, b.word_count};
}
// A real recording of tests/data/real/ (its README gives sources and licenses). The checkout has
// them: a test that reads one fails, never skips, where it is missing.
std::string real_recording(const std::string& name);

}  // namespace vkunroll::vktest
