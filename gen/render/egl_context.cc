#include "gen/render/egl_context.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include <EGL/egl.h>
#include <EGL/eglext.h>
#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

namespace stackgen {
namespace {

std::string Hex(unsigned int code, int digits) {
  char buffer[16];
  std::snprintf(buffer, sizeof(buffer), "0x%0*X", digits, code);
  return buffer;
}

// throws "<call> failed: EGL_..." with the thread's last EGL error
[[noreturn]] void ThrowEglError(const std::string& call) {
  throw std::runtime_error(call + " failed: " + EglErrorName(eglGetError()));
}

void CheckEgl(EGLBoolean ok, const char* call) {
  if (ok != EGL_TRUE) ThrowEglError(call);
}

// true when the space-separated extension list holds `name` as a whole word
bool HasExtension(const char* extensions, const char* name) {
  if (extensions == nullptr) return false;
  const size_t length = std::strlen(name);
  for (const char* p = extensions; (p = std::strstr(p, name)) != nullptr; p += length) {
    const bool starts = p == extensions || p[-1] == ' ';
    const bool ends = p[length] == '\0' || p[length] == ' ';
    if (starts && ends) return true;
  }
  return false;
}

template <typename T>
T LoadEglFunction(const char* name) {
  auto function = reinterpret_cast<T>(eglGetProcAddress(name));
  if (function == nullptr) {
    throw std::runtime_error(std::string("eglGetProcAddress failed: ") + name + " not found");
  }
  return function;
}

// displays are shared per platform and native handle inside EGL: initialise once, terminate when
// the last context on them is gone
std::mutex display_mutex;
std::map<EGLDisplay, int> display_users;

void InitializeDisplay(EGLDisplay display) {
  std::lock_guard<std::mutex> lock(display_mutex);
  int& users = display_users[display];
  if (users == 0) {
    EGLint major = 0;
    EGLint minor = 0;
    if (eglInitialize(display, &major, &minor) != EGL_TRUE) {
      display_users.erase(display);
      ThrowEglError("eglInitialize");
    }
  }
  ++users;
}

void ReleaseDisplay(EGLDisplay display) {
  std::lock_guard<std::mutex> lock(display_mutex);
  auto it = display_users.find(display);
  if (it == display_users.end()) return;
  if (--it->second == 0) {
    eglTerminate(display);
    display_users.erase(it);
  }
}

// one EGL device as eglQueryDevicesEXT lists it
struct DeviceInfo {
  EGLDeviceEXT device = nullptr;
  int index = 0;
  bool software = false;
  std::string name;  // DRM node or "software"
};

std::vector<DeviceInfo> ListDevices(const char* client_extensions) {
  std::vector<DeviceInfo> devices;
  if (!HasExtension(client_extensions, "EGL_EXT_device_enumeration") &&
      !HasExtension(client_extensions, "EGL_EXT_device_base")) {
    return devices;
  }
  const auto query_devices = LoadEglFunction<PFNEGLQUERYDEVICESEXTPROC>("eglQueryDevicesEXT");
  const auto query_device_string =
      LoadEglFunction<PFNEGLQUERYDEVICESTRINGEXTPROC>("eglQueryDeviceStringEXT");

  // list every device, then note which are software rasterisers
  EGLint count = 0;
  CheckEgl(query_devices(0, nullptr, &count), "eglQueryDevicesEXT");
  std::vector<EGLDeviceEXT> handles(count);
  CheckEgl(query_devices(count, handles.data(), &count), "eglQueryDevicesEXT");
  for (EGLint i = 0; i < count; ++i) {
    DeviceInfo info;
    info.device = handles[i];
    info.index = i;
    const char* extensions = query_device_string(handles[i], EGL_EXTENSIONS);
    info.software = HasExtension(extensions, "EGL_MESA_device_software");
    if (info.software) {
      info.name = "software";
    } else if (HasExtension(extensions, "EGL_EXT_device_drm")) {
      const char* file = query_device_string(handles[i], EGL_DRM_DEVICE_FILE_EXT);
      info.name = file != nullptr ? file : "drm";
    } else if (HasExtension(extensions, "EGL_NV_device_cuda")) {
      info.name = "cuda";
    } else {
      info.name = "gpu";
    }
    devices.push_back(info);
  }
  return devices;
}

std::string PlatformOverride() {
  const char* value = std::getenv("STACKGEN_EGL_PLATFORM");
  if (value == nullptr || value[0] == '\0') return "";
  const std::string platform = value;
  if (platform != "device" && platform != "surfaceless") {
    throw std::runtime_error("STACKGEN_EGL_PLATFORM: unknown platform '" + platform +
                             "' (expected 'device' or 'surfaceless')");
  }
  return platform;
}

}  // namespace

struct EglContext::Impl {
  EglPlatform platform = EglPlatform::kSurfaceless;
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
  EGLSurface surface = EGL_NO_SURFACE;  // a 1x1 pbuffer, only without surfaceless contexts
  std::string platform_text;
  std::string renderer;
  std::string version;

  // opens and initialises the display of the chosen platform; throws when none works
  void OpenDisplay();
  // creates the 3.3 core context (and pbuffer where needed) and makes it current
  void CreateContext();
};

void EglContext::Impl::OpenDisplay() {
  const char* client_extensions = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  if (client_extensions == nullptr) ThrowEglError("eglQueryString(EGL_EXTENSIONS)");
  if (!HasExtension(client_extensions, "EGL_EXT_platform_base")) {
    throw std::runtime_error("EGL client extension EGL_EXT_platform_base missing");
  }
  const auto get_platform_display =
      LoadEglFunction<PFNEGLGETPLATFORMDISPLAYEXTPROC>("eglGetPlatformDisplayEXT");
  const std::string forced = PlatformOverride();

  // device platform: GPU devices first; software devices only when the platform is forced
  std::string device_errors;
  if (forced != "surfaceless" && HasExtension(client_extensions, "EGL_EXT_platform_device")) {
    std::vector<DeviceInfo> devices = ListDevices(client_extensions);
    std::vector<DeviceInfo> candidates;
    for (const DeviceInfo& info : devices) {
      if (!info.software) candidates.push_back(info);
    }
    if (forced == "device") {
      for (const DeviceInfo& info : devices) {
        if (info.software) candidates.push_back(info);
      }
    }
    for (const DeviceInfo& info : candidates) {
      EGLDisplay candidate = get_platform_display(EGL_PLATFORM_DEVICE_EXT, info.device, nullptr);
      if (candidate == EGL_NO_DISPLAY) {
        device_errors += " device " + std::to_string(info.index) +
                         ": eglGetPlatformDisplayEXT failed: " + EglErrorName(eglGetError()) + ";";
        continue;
      }
      try {
        InitializeDisplay(candidate);
      } catch (const std::exception& e) {
        device_errors += " device " + std::to_string(info.index) + ": " + e.what() + ";";
        continue;
      }
      display = candidate;
      platform = EglPlatform::kDevice;
      platform_text = "EGL device platform (device " + std::to_string(info.index) + " of " +
                      std::to_string(devices.size()) + ", " + info.name + ")";
      return;
    }
  }
  if (forced == "device") {
    throw std::runtime_error(
        "STACKGEN_EGL_PLATFORM=device: no EGL device could be initialised" +
        (device_errors.empty() ? std::string(" (none listed)") : device_errors));
  }

  // mesa surfaceless platform
  if (!HasExtension(client_extensions, "EGL_MESA_platform_surfaceless")) {
    throw std::runtime_error(
        "no usable EGL platform: no GPU device and EGL_MESA_platform_surfaceless"
        " missing" +
        device_errors);
  }
  display = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
  if (display == EGL_NO_DISPLAY) ThrowEglError("eglGetPlatformDisplayEXT(surfaceless)");
  InitializeDisplay(display);
  platform = EglPlatform::kSurfaceless;
  platform_text = "EGL surfaceless platform (Mesa)";
}

void EglContext::Impl::CreateContext() {
  CheckEgl(eglBindAPI(EGL_OPENGL_API), "eglBindAPI(EGL_OPENGL_API)");
  const char* extensions = eglQueryString(display, EGL_EXTENSIONS);
  if (extensions == nullptr) ThrowEglError("eglQueryString(display, EGL_EXTENSIONS)");
  const bool surfaceless = HasExtension(extensions, "EGL_KHR_surfaceless_context");

  // a config for desktop OpenGL, with pbuffers where the display has them
  EGLint config_attributes[] = {EGL_SURFACE_TYPE,
                                EGL_PBUFFER_BIT,
                                EGL_RENDERABLE_TYPE,
                                EGL_OPENGL_BIT,
                                EGL_RED_SIZE,
                                8,
                                EGL_GREEN_SIZE,
                                8,
                                EGL_BLUE_SIZE,
                                8,
                                EGL_NONE};
  EGLConfig config = nullptr;
  EGLint config_count = 0;
  CheckEgl(eglChooseConfig(display, config_attributes, &config, 1, &config_count),
           "eglChooseConfig");
  bool has_pbuffer = config_count > 0;
  if (!has_pbuffer && surfaceless) {
    config_attributes[1] = EGL_DONT_CARE;
    CheckEgl(eglChooseConfig(display, config_attributes, &config, 1, &config_count),
             "eglChooseConfig");
  }
  if (config_count == 0) {
    throw std::runtime_error("eglChooseConfig failed: no config for OpenGL with RGB8" +
                             std::string(surfaceless ? "" : " and pbuffers"));
  }

  // opengl 3.3 core, no surface
  const EGLint context_attributes[] = {EGL_CONTEXT_MAJOR_VERSION,
                                       3,
                                       EGL_CONTEXT_MINOR_VERSION,
                                       3,
                                       EGL_CONTEXT_OPENGL_PROFILE_MASK,
                                       EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                       EGL_NONE};
  context = eglCreateContext(display, config, EGL_NO_CONTEXT, context_attributes);
  if (context == EGL_NO_CONTEXT) ThrowEglError("eglCreateContext(OpenGL 3.3 core)");
  if (!surfaceless) {
    const EGLint pbuffer_attributes[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
    surface = eglCreatePbufferSurface(display, config, pbuffer_attributes);
    if (surface == EGL_NO_SURFACE) ThrowEglError("eglCreatePbufferSurface");
  }
  CheckEgl(eglMakeCurrent(display, surface, surface, context), "eglMakeCurrent");

  // check the version and note what runs it
  GLint major = 0;
  GLint minor = 0;
  glGetIntegerv(GL_MAJOR_VERSION, &major);
  glGetIntegerv(GL_MINOR_VERSION, &minor);
  CheckGlError("glGetIntegerv(GL_MAJOR_VERSION)");
  if (major * 10 + minor < 33) {
    throw std::runtime_error("eglCreateContext gave OpenGL " + std::to_string(major) + "." +
                             std::to_string(minor) + ", need 3.3 core");
  }
  const auto* renderer_string = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const auto* version_string = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  renderer = renderer_string != nullptr ? renderer_string : "?";
  version = version_string != nullptr ? version_string : "?";
  if (!surfaceless) platform_text += ", 1x1 pbuffer";
}

EglContext::EglContext() : impl_(std::make_unique<Impl>()) {
  impl_->OpenDisplay();
  try {
    impl_->CreateContext();
  } catch (...) {
    // leave nothing behind
    if (eglGetCurrentContext() == impl_->context && impl_->context != EGL_NO_CONTEXT) {
      eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    }
    if (impl_->surface != EGL_NO_SURFACE) eglDestroySurface(impl_->display, impl_->surface);
    if (impl_->context != EGL_NO_CONTEXT) eglDestroyContext(impl_->display, impl_->context);
    ReleaseDisplay(impl_->display);
    throw;
  }
}

EglContext::~EglContext() {
  // release the context from this thread so destroying it frees its objects now
  if (eglGetCurrentContext() == impl_->context) {
    eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
  }
  if (impl_->surface != EGL_NO_SURFACE) eglDestroySurface(impl_->display, impl_->surface);
  eglDestroyContext(impl_->display, impl_->context);
  ReleaseDisplay(impl_->display);
}

void EglContext::MakeCurrent() {
  if (eglGetCurrentContext() == impl_->context) return;
  CheckEgl(eglMakeCurrent(impl_->display, impl_->surface, impl_->surface, impl_->context),
           "eglMakeCurrent");
}

EglPlatform EglContext::platform() const { return impl_->platform; }

std::string EglContext::Description() const {
  return impl_->platform_text + "; GL_RENDERER " + impl_->renderer + "; GL_VERSION " +
         impl_->version;
}

std::string EglErrorName(int code) {
  switch (code) {
    case EGL_SUCCESS:
      return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED:
      return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS:
      return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC:
      return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE:
      return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG:
      return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT:
      return "EGL_BAD_CONTEXT";
    case EGL_BAD_CURRENT_SURFACE:
      return "EGL_BAD_CURRENT_SURFACE";
    case EGL_BAD_DISPLAY:
      return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH:
      return "EGL_BAD_MATCH";
    case EGL_BAD_NATIVE_PIXMAP:
      return "EGL_BAD_NATIVE_PIXMAP";
    case EGL_BAD_NATIVE_WINDOW:
      return "EGL_BAD_NATIVE_WINDOW";
    case EGL_BAD_PARAMETER:
      return "EGL_BAD_PARAMETER";
    case EGL_BAD_SURFACE:
      return "EGL_BAD_SURFACE";
    case EGL_CONTEXT_LOST:
      return "EGL_CONTEXT_LOST";
    case EGL_BAD_DEVICE_EXT:
      return "EGL_BAD_DEVICE_EXT";
    default:
      return "EGL error " + Hex(static_cast<unsigned int>(code), 4);
  }
}

std::string GlErrorName(unsigned int code) {
  switch (code) {
    case GL_NO_ERROR:
      return "GL_NO_ERROR";
    case GL_INVALID_ENUM:
      return "GL_INVALID_ENUM";
    case GL_INVALID_VALUE:
      return "GL_INVALID_VALUE";
    case GL_INVALID_OPERATION:
      return "GL_INVALID_OPERATION";
    case GL_INVALID_FRAMEBUFFER_OPERATION:
      return "GL_INVALID_FRAMEBUFFER_OPERATION";
    case GL_OUT_OF_MEMORY:
      return "GL_OUT_OF_MEMORY";
    case GL_STACK_UNDERFLOW:
      return "GL_STACK_UNDERFLOW";
    case GL_STACK_OVERFLOW:
      return "GL_STACK_OVERFLOW";
    default:
      return "GL error " + Hex(code, 4);
  }
}

void CheckGlError(const char* what) {
  GLenum error = glGetError();
  if (error == GL_NO_ERROR) return;
  // drain every pending flag so the next check starts clean
  std::string names = GlErrorName(error);
  for (int i = 0; i < 16 && (error = glGetError()) != GL_NO_ERROR; ++i) {
    names += ", " + GlErrorName(error);
  }
  throw std::runtime_error(std::string(what) + ": " + names);
}

}  // namespace stackgen
