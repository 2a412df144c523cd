#include "vk_test_env.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>

namespace vkunroll::vktest {

namespace {
std::unique_ptr<Context>& slot() {
  static std::unique_ptr<Context> ctx;
  return ctx;
}
std::unique_ptr<Context>& strict_slot() {
  static std::unique_ptr<Context> ctx;
  return ctx;
}

std::unique_ptr<Context>& whole_slot() {
  static std::unique_ptr<Context> ctx;
  return ctx;
}

class ValidationListener : public ::testing::EmptyTestEventListener {
  void OnTestStart(const ::testing::TestInfo&) override {
    if (context_created()) context().clear_validation_messages();
  }
  void OnTestEnd(const ::testing::TestInfo&) override {
    if (!context_created()) return;
    for (const auto& m : context().validation_messages()) ADD_FAILURE() << "Vulkan " << m;
  }
};
}  // namespace

Context& context() {
  if (!slot()) {
    ContextOptions o;
    o.validation = true;  // always in tests
    o.validation_fatal = false;  // the listener fails the test instead, with the message
    o.announce = false;
    slot() = std::make_unique<Context>(o);
  }
  return *slot();
}

Context& strict_uniform_context() {
  std::unique_ptr<Context>& strict = strict_slot();
  if (!strict) {
    ContextOptions o;
    o.validation = true;
    o.validation_fatal = true;
    o.announce = false;
    o.min_uniform_offset_alignment = 256;
    strict = std::make_unique<Context>(o);
  }
  return *strict;
}

Context& whole_binding_context() {
  std::unique_ptr<Context>& whole = whole_slot();
  if (!whole) {
    ContextOptions o;
    o.validation = true;
    o.validation_fatal = true;
    o.announce = false;
    o.whole_tensor_bindings = true;
    whole = std::make_unique<Context>(o);
  }
  return *whole;
}

bool context_created() { return slot() != nullptr; }

std::string shared_path(const std::string& rel) {
  const std::filesystem::path p = std::filesystem::path(VKUNROLL_SHARED_DIR) / rel;
  return std::filesystem::exists(p) ? p.string() : std::string();
}

}  // namespace vkunroll::vktest

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ::testing::UnitTest::GetInstance()->listeners().Append(new vkunroll::vktest::ValidationListener);
  const int rc = RUN_ALL_TESTS();
  vkunroll::vktest::strict_slot().reset();
  vkunroll::vktest::whole_slot().reset();
  vkunroll::vktest::slot().reset();
  return rc;
}
