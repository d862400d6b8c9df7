layout(location = 0) in vec3 position_object;

void main() {
  vec4 p = camera_from_object * vec4(position_object, 1.0);
  gl_Position = ClipFromCamera(p.xyz);
}
