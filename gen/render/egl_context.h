#pragma once

#include <memory>
#include <string>

namespace stackgen {

/// The EGL platform a context runs on.
enum class EglPlatform {
  kDevice,       // EGL_EXT_platform_device: a GPU driver's device (or a software one when forced)
  kSurfaceless,  // EGL_MESA_platform_surfaceless: Mesa with no display (llvmpipe without a GPU)
};

/// A headless OpenGL 3.3 core context: the EGL platform choice behind one small class.
///
/// The platform is the EGL device platform when a non-software device is listed, Mesa's
/// surfaceless platform otherwise; the environment variable STACKGEN_EGL_PLATFORM=device or
/// STACKGEN_EGL_PLATFORM=surfaceless forces one (a forced device platform takes a software device
/// when no GPU device is listed). The context has no surface (EGL_KHR_surfaceless_context), or a
/// 1x1 pbuffer where that extension is missing; render into framebuffer objects.
///
/// A context is current on at most one thread at a time; call MakeCurrent() on the thread that
/// uses it. Not copyable or movable.
class EglContext {
 public:
  /// Chooses the platform, creates the context and makes it current on the calling thread.
  /// Throws std::runtime_error naming the failed EGL call and the error code (e.g.
  /// "eglInitialize failed: EGL_NOT_INITIALIZED"), an unknown STACKGEN_EGL_PLATFORM value, or a
  /// context older than OpenGL 3.3.
  EglContext();
  ~EglContext();
  EglContext(const EglContext&) = delete;
  EglContext& operator=(const EglContext&) = delete;

  /// Makes this context current on the calling thread; cheap when it already is. Throws
  /// std::runtime_error with the EGL error name (e.g. EGL_BAD_ACCESS when current elsewhere).
  void MakeCurrent();

  /// The platform chosen at construction.
  EglPlatform platform() const;

  /// One line naming the platform (and device), GL_RENDERER and GL_VERSION.
  std::string Description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The name of an EGL error code, e.g. "EGL_BAD_ALLOC"; "EGL error 0x3099" for unknown codes.
std::string EglErrorName(int code);

/// The name of an OpenGL error code, e.g. "GL_INVALID_OPERATION"; "GL error 0x0507" for unknown
/// codes.
std::string GlErrorName(unsigned int code);

/// Throws std::runtime_error "<what>: GL_INVALID_ENUM" (every pending error, by name) when
/// glGetError reports an error in the current context; does nothing otherwise.
void CheckGlError(const char* what);

}  // namespace stackgen
