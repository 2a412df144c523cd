// The environment variables: one parse each (base/env.hpp), a bad value refused by name.
#include <gtest/gtest.h>

#include <cstdlib>
#include <optional>
#include <string>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/runtime/context.hpp"

using namespace vkunroll;

namespace {
// Sets a variable for the scope of a test and puts the old value back.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    if (value) ::setenv(name, value, 1);
    else ::unsetenv(name);
  }
  ~ScopedEnv() {
    if (old_) ::setenv(name_, old_->c_str(), 1);
    else ::unsetenv(name_);
  }

 private:
  const char* name_;
  std::optional<std::string> old_;
};

// The UsageError's message for the variable set to `value`, or "" when it parses.
template <class Parse>
std::string refusal(const char* name, const char* value, Parse parse) {
  ScopedEnv set(name, value);
  try {
    parse();
  } catch (const UsageError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(Environment, FlagTakesOneAndZeroTrueAndFalseAndRefusesTheRest) {
  const char* name = "VKUNROLL_TEST_FLAG";
  for (const char* on : {"1", "true"}) {
    ScopedEnv set(name, on);
    EXPECT_TRUE(env::flag(name)) << on;
  }
  for (const char* off : {"0", "false", ""}) {
    ScopedEnv set(name, off);
    EXPECT_FALSE(env::flag(name)) << off;
  }
  ScopedEnv unset(name, nullptr);
  EXPECT_FALSE(env::flag(name));
  // Was read as on (anything but 0 and false) in one place and as off (anything but 1) in another.
  for (const char* bad : {"yes", "2", "on", " 1", "TRUE"}) {
    const std::string m = refusal(name, bad, [&] { env::flag(name); });
    EXPECT_EQ(m, std::string(name) + "='" + bad + "': expected 1 or true (on), 0 or false (off), or unset") << bad;
  }
}

TEST(Environment, SecondsAreAWholeNumberInRange) {
  const char* name = "VKUNROLL_TEST_SECONDS";
  {
    ScopedEnv set(name, "2.5");
    EXPECT_EQ(env::seconds(name, 600, 1e6), 2.5);
  }
  {
    ScopedEnv set(name, "");
    EXPECT_EQ(env::seconds(name, 600, 1e6), 600);
  }
  for (const char* bad : {"abc", "0", "-1", "10s", "2e6", "nan", "inf"}) {
    const std::string m = refusal(name, bad, [&] { env::seconds(name, 600, 1e6); });
    EXPECT_EQ(m, std::string(name) + "='" + bad + "': expected seconds in (0, 1000000] (default 600)") << bad;
  }
}

TEST(Environment, TextIsUnsetWhenEmpty) {
  const char* name = "VKUNROLL_TEST_TEXT";
  {
    ScopedEnv set(name, "");
    EXPECT_FALSE(env::text(name).has_value());
  }
  ScopedEnv set(name, "llvmpipe");
  EXPECT_EQ(env::text(name).value_or(""), "llvmpipe");
}

// Where a Context reads them: a bad value of a switch stops it with a usage error naming the
// variable (VKUNROLL_VALIDATION_FATAL was read as on for anything but 0 and false here, and as on
// only for 1 by the Python log forwarder).
TEST(Environment, ContextRefusesABadSwitchByName) {
  for (const char* var : {"VKUNROLL_VALIDATION_FATAL", "VKUNROLL_VALIDATION", "VKUNROLL_NO_PIPELINE_CACHE"}) {
    ContextOptions o;
    o.announce = false;
    const std::string m = refusal(var, "yes", [&] { Context ctx(o); });
    EXPECT_EQ(m, std::string(var) + "='yes': expected 1 or true (on), 0 or false (off), or unset");
  }
  ScopedEnv off("VKUNROLL_VALIDATION_FATAL", "0");
  ContextOptions o;
  o.announce = false;
  EXPECT_NO_THROW(Context ctx(o));
}
