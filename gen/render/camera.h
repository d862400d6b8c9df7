#pragma once

namespace stackgen {

/// Pinhole intrinsics, OpenCV convention (pixel centres at integers): a point (x, y, z) in the
/// camera frame (x right, y down, z forward, mm) projects to (fx x / z + cx, fy y / z + cy) px.
/// The one type of a camera's intrinsics in the generator: the config's camera
/// (CameraIntrinsics), the drawn camera poses (gen/randomize/camera_pose.h) and the renderer's
/// camera (CameraModel) share it; the scene message's camera_info carries the same values.
struct Intrinsics {
  int width = 640;  // image size, pixels
  int height = 480;
  double fx = 800;  // focal lengths, pixels
  double fy = 800;
  double cx = 319.5;  // principal point, pixels
  double cy = 239.5;
};

}  // namespace stackgen
