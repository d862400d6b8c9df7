#version 330 core
// One triangle covering the frame at the far plane (the resolve pass); texture_coordinates
// (0, 0) at the top left of the image (image row 0 is framebuffer row 0).
out vec2 texture_coordinates;

void main() {
  vec2 corner = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  texture_coordinates = corner;
  gl_Position = vec4(corner * 2.0 - 1.0, 1.0, 1.0);
}
