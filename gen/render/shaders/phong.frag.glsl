// Blinn-Phong per light after the paper (ambient, diffuse, specular), display values with gamma 2;
// shadow_lookup.glsl comes before this file.
in vec3 position_camera;
in vec3 normal_camera;
layout(location = 0) out vec4 color_out;
layout(location = 1) out uint instance_out;
layout(location = 2) out float depth_out;
uniform uint instance_id;
uniform vec3 material_color_linear;
uniform float material_specular;
uniform float material_shininess;
#if LIGHT_COUNT > 0
uniform vec4 light_vector_camera[LIGHT_COUNT];
uniform vec3 light_terms[LIGHT_COUNT];  // (ambient, diffuse, specular)
#endif
#if TEXTURED
in vec2 texture_coordinates;
uniform sampler2D material_texture;
#endif

void main() {
  // shade both sides: the back of a two-sided (open) mesh uses the flipped normal
  vec3 n = normalize(gl_FrontFacing ? normal_camera : -normal_camera);
  vec3 v = normalize(-position_camera);
  vec3 albedo_linear = material_color_linear;
#if TEXTURED
  vec3 texel = texture(material_texture, texture_coordinates).rgb;
  albedo_linear *= texel * texel;
#endif

  // blinn-phong per light, in linear colour; a shadowed light keeps its ambient term only
  vec3 linear = vec3(0.0);
#if LIGHT_COUNT > 0
  for (int i = 0; i < LIGHT_COUNT; ++i) {
    vec3 l = normalize(light_vector_camera[i].xyz - position_camera * light_vector_camera[i].w);
#if SHADOWS
    float lit = LitFraction(i);
#else
    const float lit = 1.0;
#endif
    float n_dot_l = max(dot(n, l), 0.0);
    float highlight = 0.0;
    if (n_dot_l > 0.0) highlight = pow(max(dot(n, normalize(l + v)), 0.0), material_shininess);
    linear += (light_terms[i].x + light_terms[i].y * (n_dot_l * lit)) * albedo_linear +
              vec3(light_terms[i].z * material_specular * (highlight * lit));
  }
#endif

  // gamma 2 to display values (sqrt is far cheaper than pow on llvmpipe); id and camera z of
  // the same surface
  color_out = vec4(sqrt(clamp(linear, 0.0, 1.0)), 1.0);
  instance_out = instance_id;
  depth_out = position_camera.z;
}
