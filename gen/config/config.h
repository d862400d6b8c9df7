#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "stackgen_config.pb.h"

namespace stackgen {

/// Thrown for a config that cannot be used; the text names the file, line and field.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A parsed and validated generator config.
struct LoadedConfig {
  config::GeneratorConfig config;
  /// The file it came from (or the name given to ParseConfig).
  std::string path;
  /// Folder that relative paths in the config (meshes) are resolved against.
  std::string base_dir;
  /// Whether part i's class_name was left out and taken from its mesh's file name.
  std::vector<bool> class_from_file;

  /// `relative` resolved against base_dir (absolute paths are kept).
  std::string Resolve(const std::string& relative) const;
};

/// Reads and validates a config file. Throws ConfigError naming the file (and line and field)
/// when it is unreadable, has a syntax error or unknown field, or holds an out-of-range value
/// or an impossible set-up (e.g. a camera that cannot see the bin).
LoadedConfig LoadConfig(const std::string& path);

/// As LoadConfig, for config text; `name` stands for the file in messages, `base_dir` resolves
/// relative paths.
LoadedConfig ParseConfig(const std::string& text, const std::string& name,
                         const std::string& base_dir);

/// The config a program reads when no --config is given: share/stackgen/config/default.pbtxt
/// beside an installed program (<prefix>/bin/../share/...: `cmake --install`, the .deb, or one
/// unpacked anywhere), else `built_in`, the source tree's, for programs run from a build folder.
std::string DefaultConfigPath(const std::string& built_in);

/// The whole config with every default written out, as protobuf text.
std::string EffectiveConfigText(const config::GeneratorConfig& config);

/// Pose of the camera in the world (bin) frame: above the bin's floor centre, looking straight
/// down, image x along world x, image y along world -y. Millimetres.
Eigen::Isometry3d WorldFromCamera(const config::CameraConfig& camera);

/// The principal point of the camera, with negative config values meaning the image centre.
Eigen::Vector2d PrincipalPoint(const config::CameraConfig& camera);

}  // namespace stackgen
