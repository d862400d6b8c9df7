// The vertex shader of the scene programs. LIGHT_COUNT, SHADOWS, TEXTURED, ENVIRONMENT and DETAIL are
// defined per
// program: a loop with a constant count unrolls (a uniform count makes llvmpipe about twice as
// slow), and scenes without shadows or textures pay nothing for them. A light is a vec4: (unit
// direction towards the light, 0) for a directional light, (position, 1) for a point light,
// both in the camera frame, mm.
layout(location = 0) in vec3 position_object;
layout(location = 1) in vec3 normal_object;
layout(location = 2) in vec2 uv_object;  // v = 0 at the bottom of the texture image
out vec3 position_camera;
out vec3 normal_camera;
#if TEXTURED
out vec2 texture_coordinates;  // t = 0 at row 0 of the uploaded image, its top: t = 1 - v
#endif
#if ENVIRONMENT
uniform mat3 environment_from_camera;
uniform vec3 irradiance_sh[9];  // radiance of a white Lambertian surface, world z up
// at the vertex's normal and its opposite: low-frequency, so interpolated across a triangle
out vec3 irradiance;
out vec3 irradiance_back;

vec3 Irradiance(vec3 n) {
  vec3 e = irradiance_sh[0] * 0.282095 + irradiance_sh[1] * (0.488603 * n.y) +
           irradiance_sh[2] * (0.488603 * n.z) + irradiance_sh[3] * (0.488603 * n.x) +
           irradiance_sh[4] * (1.092548 * n.x * n.y) + irradiance_sh[5] * (1.092548 * n.y * n.z) +
           irradiance_sh[6] * (0.315392 * (3.0 * n.z * n.z - 1.0)) +
           irradiance_sh[7] * (1.092548 * n.x * n.z) +
           irradiance_sh[8] * (0.546274 * (n.x * n.x - n.y * n.y));
  return max(e, vec3(0.0));
}
#endif
#if DETAIL
uniform vec4 detail_frame;  // (offset, 1 / feature size in mm)
out vec3 detail_position;   // the position in the object's frame, in features
out vec3 detail_normal;     // the normal in the object's frame
#endif
#if SHADOWS
uniform vec4 light_vector_camera[LIGHT_COUNT];
uniform mat4 shadow_from_camera[LIGHT_COUNT];      // to (s, t, depth) of each map, homogeneous
uniform float shadow_normal_offset_mm[LIGHT_COUNT];
out vec4 shadow_coordinates[LIGHT_COUNT];
#endif

void main() {
  vec4 p = camera_from_object * vec4(position_object, 1.0);
  position_camera = p.xyz;
  normal_camera = mat3(camera_from_object) * normal_object;
#if TEXTURED
  texture_coordinates = vec2(uv_object.x, 1.0 - uv_object.y);
#endif
#if DETAIL
  detail_position = position_object * detail_frame.w + detail_frame.xyz;
  detail_normal = normal_object;
#endif
#if SHADOWS
  // look the surface up in each map a little off it, along the normal on the light's side and
  // more at grazing light, so it does not shadow itself
  vec3 n = normalize(normal_camera);
  for (int i = 0; i < LIGHT_COUNT; ++i) {
    vec3 l = normalize(light_vector_camera[i].xyz - p.xyz * light_vector_camera[i].w);
    float n_dot_l = dot(n, l);
    float sine = sqrt(max(1.0 - n_dot_l * n_dot_l, 0.0));
    vec3 offset = (n_dot_l >= 0.0 ? n : -n) * (shadow_normal_offset_mm[i] * sine);
    shadow_coordinates[i] = shadow_from_camera[i] * vec4(p.xyz + offset, 1.0);
  }
#endif
#if ENVIRONMENT
  // both sides of a two-sided mesh: the fragment shader picks the side facing the camera
  vec3 normal_environment = environment_from_camera * normalize(normal_camera);
  irradiance = Irradiance(normal_environment);
  irradiance_back = Irradiance(-normal_environment);
#endif
  gl_Position = ClipFromCamera(p.xyz);
}
