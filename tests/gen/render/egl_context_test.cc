#include "gen/render/egl_context.h"

#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

// sets an environment variable for one scope, restoring the old value after
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    const char* old = std::getenv(name);
    had_value_ = old != nullptr;
    if (had_value_) old_value_ = old;
    setenv(name, value, 1);
  }
  ~ScopedEnv() {
    if (had_value_) {
      setenv(name_.c_str(), old_value_.c_str(), 1);
    } else {
      unsetenv(name_.c_str());
    }
  }

 private:
  std::string name_;
  std::string old_value_;
  bool had_value_ = false;
};

// a context comes up on the default platform and says what it runs on
TEST(EglContextTest, CreatesAContext) {
  EglContext context;
  context.MakeCurrent();
  const std::string description = context.Description();
  EXPECT_NE(description.find("GL_RENDERER"), std::string::npos) << description;
  EXPECT_NE(description.find("GL_VERSION"), std::string::npos) << description;
  const char* platform = context.platform() == EglPlatform::kDevice ? "device" : "surfaceless";
  EXPECT_NE(description.find(platform), std::string::npos) << description;
  std::cout << "default: " << description << "\n";
}

// STACKGEN_EGL_PLATFORM forces either platform and refuses unknown names
TEST(EglContextTest, PlatformCanBeForced) {
  {
    const ScopedEnv env("STACKGEN_EGL_PLATFORM", "surfaceless");
    const EglContext context;
    EXPECT_EQ(context.platform(), EglPlatform::kSurfaceless) << context.Description();
  }
  {
    const ScopedEnv env("STACKGEN_EGL_PLATFORM", "device");
    try {
      const EglContext context;
      EXPECT_EQ(context.platform(), EglPlatform::kDevice) << context.Description();
      std::cout << "forced device: " << context.Description() << "\n";
    } catch (const std::runtime_error& e) {
      // set-ups that list no EGL device at all must say so
      EXPECT_NE(std::string(e.what()).find("STACKGEN_EGL_PLATFORM=device"), std::string::npos)
          << e.what();
    }
  }
  const ScopedEnv env("STACKGEN_EGL_PLATFORM", "vulkan");
  try {
    const EglContext context;
    ADD_FAILURE() << "an unknown platform was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("vulkan"), std::string::npos) << e.what();
  }
}

// two contexts on one thread take turns
TEST(EglContextTest, ContextsTakeTurns) {
  EglContext first;
  EglContext second;
  first.MakeCurrent();
  second.MakeCurrent();
  first.MakeCurrent();
  SUCCEED();
}

// error codes are reported by name
TEST(EglContextTest, NamesErrors) {
  EXPECT_EQ(EglErrorName(0x3003), "EGL_BAD_ALLOC");
  EXPECT_EQ(EglErrorName(0x3008), "EGL_BAD_DISPLAY");
  EXPECT_EQ(EglErrorName(0x1234), "EGL error 0x1234");
  EXPECT_EQ(GlErrorName(0x0500), "GL_INVALID_ENUM");
  EXPECT_EQ(GlErrorName(0x0502), "GL_INVALID_OPERATION");
  EXPECT_EQ(GlErrorName(0x0505), "GL_OUT_OF_MEMORY");
  EXPECT_EQ(GlErrorName(0x0abc), "GL error 0x0ABC");
}

}  // namespace
}  // namespace stackgen
