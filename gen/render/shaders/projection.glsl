// The exact pinhole model with image row v in framebuffer row v (row 0 first in memory, at the
// top of the image):
//   x_clip = 2 fx / w x + ((2 cx + 1) / w - 1) z,  y_clip = 2 fy / h y + ((2 cy + 1) / h - 1) z,
//   z_clip = a z + b (near -> -1, far -> 1),      w_clip = z.
// Every program drawing into the image uses it with `invariant`, so all cover the same pixels.
uniform mat4 camera_from_object;  // mm
uniform vec4 projection;          // (2 fx / w, (2 cx + 1) / w - 1, 2 fy / h, (2 cy + 1) / h - 1)
uniform vec2 depth_coefficients;  // (a, b): z_clip = a z + b
invariant gl_Position;

vec4 ClipFromCamera(vec3 p) {
  return vec4(projection.x * p.x + projection.y * p.z, projection.z * p.y + projection.w * p.z,
              depth_coefficients.x * p.z + depth_coefficients.y, p.z);
}
