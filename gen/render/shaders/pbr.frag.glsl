// Physically based colour: the metallic-roughness model (brdf.glsl) lit by point and directional
// lights with shadow maps (shadow_lookup.glsl) and by an environment as the split sum (Karis
// 2013; bevyengine/bevy environment_map.wgsl): radiance prefiltered by roughness, irradiance as
// spherical harmonics (evaluated per vertex, scene.vert.glsl), the DFG lookup table, with Filament's multiple-scattering energy
// compensation (docs/Filament.md 4.7.2). The diffuse lobe gets what the specular albedo leaves,
// so a white surface in a uniform environment reflects exactly that environment (the furnace
// test). Writes linear radiance (the tone curve comes later), the instance id, camera z and the
// surface (item index + 1, for resolve.frag.glsl) of the same fragment; with PROJECTOR, also how
// much of a 3D camera's projected pattern comes back to the camera from this surface; with
// ENVIRONMENT, also the environment's share of the colour (location 5, read where what surrounds
// a surface is to hide some of it: RenderOptions::environment_occlusion_mm).
in vec3 position_camera;
in vec3 normal_camera;
layout(location = 0) out vec4 color_out;
layout(location = 1) out uint instance_out;
layout(location = 2) out float depth_out;
layout(location = 3) out uint surface_out;
#if PROJECTOR
layout(location = 4) out float projector_return_out;
uniform vec3 projector_camera;  // the projector's position, camera frame, mm
#endif
uniform uint instance_id;
uniform uint surface_id;
uniform vec3 base_color_linear;
uniform float metallic;
uniform float roughness;      // perceptual, clamped to [0.03, 1]
uniform float dielectric_f0;  // reflectance at normal incidence of a non-metal
uniform sampler2D dfg_lut;    // (n.v, roughness) -> (Fresnel peak part, albedo for f0 = 1)
#if LIGHT_COUNT > 0
uniform vec4 light_vector_camera[LIGHT_COUNT];
uniform vec3 light_irradiance[LIGHT_COUNT];  // at normal incidence, linear RGB
#endif
#if TEXTURED
in vec2 texture_coordinates;
uniform sampler2D material_texture;
#endif
#if ENVIRONMENT
layout(location = 5) out vec4 environment_out;
uniform mat3 environment_from_camera;
uniform sampler2D environment_radiance;  // octahedral, level k: roughness k / max_lod
uniform float environment_max_lod;
uniform vec3 environment_intensity;  // the strength times the environment's colour
in vec3 irradiance;  // from the vertex shader, irradiance_sh at the normal (and its opposite)
in vec3 irradiance_back;

// the octahedral map's texture coordinates of a direction (environment.h, OctahedralOf)
vec2 OctahedralUv(vec3 d) {
  d /= abs(d.x) + abs(d.y) + abs(d.z);
  vec2 p = d.xy;
  if (d.z < 0.0) p = (1.0 - abs(d.yx)) * vec2(d.x >= 0.0 ? 1.0 : -1.0, d.y >= 0.0 ? 1.0 : -1.0);
  return p * 0.5 + 0.5;
}
#endif

#if DETAIL
// procedural surface detail (renderer.h, SurfaceDetail), from the position in features
in vec3 detail_position;
in vec3 detail_normal;
uniform int detail_kind;        // 1 cast, 2 brushed, 3 scuffed, 4 moulded, 5 wood
uniform float detail_strength;  // 0..1

// a hash of a lattice point to 0..1 (Inigo Quilez's), and smooth value noise between them
float Hash(vec3 p) {
  p = fract(p * 0.3183099 + 0.1) * 17.0;
  return fract(p.x * p.y * p.z * (p.x + p.y + p.z));
}
float ValueNoise(vec3 x) {
  vec3 i = floor(x);
  vec3 f = fract(x);
  f = f * f * (3.0 - 2.0 * f);
  return mix(mix(mix(Hash(i), Hash(i + vec3(1, 0, 0)), f.x),
                 mix(Hash(i + vec3(0, 1, 0)), Hash(i + vec3(1, 1, 0)), f.x), f.y),
             mix(mix(Hash(i + vec3(0, 0, 1)), Hash(i + vec3(1, 0, 1)), f.x),
                 mix(Hash(i + vec3(0, 1, 1)), Hash(i + vec3(1, 1, 1)), f.x), f.y),
             f.z);
}

// what the detail does here: (roughness factor, brightness factor, dust: 0..1 towards grey)
vec3 Detail(vec3 p) {
  float k = detail_strength;
  if (detail_kind == 1) {
    // cast: two octaves of mottling
    float m = 0.65 * ValueNoise(p) + 0.35 * ValueNoise(2.7 * p + 11.0) - 0.5;
    return vec3(1.0 + 1.2 * k * m, 1.0 - 0.5 * k * m, 0.0);
  }
  if (detail_kind == 2) {
    // brushed: streaks along x, long and thin
    float s = 0.7 * ValueNoise(p * vec3(0.04, 5.0, 5.0)) +
              0.3 * ValueNoise(p * vec3(0.1, 17.0, 17.0) + 5.0) - 0.5;
    return vec3(1.0 + 1.4 * k * s, 1.0 + 0.4 * k * s, 0.0);
  }
  if (detail_kind == 5) {
    // wood: growth rings one feature apart across y, bent by slow noise, and fine grain along x
    float w = p.y + 1.6 * ValueNoise(p * vec3(0.03, 0.25, 0.25) + 17.0);
    float ring = smoothstep(0.2, 0.9, 0.5 + 0.5 * sin(6.2831853 * w));
    float grain = ValueNoise(p * vec3(0.05, 6.0, 6.0) + 23.0);
    return vec3(1.0 + 0.3 * k * (grain - 0.5), 1.0 - k * (0.45 * ring + 0.25 * grain), 0.0);
  }
  // scuffed: dust in patches, and thin scuff marks that roughen and lighten
  float dust = smoothstep(0.45, 0.8, 0.7 * ValueNoise(0.3 * p) + 0.3 * ValueNoise(1.7 * p + 3.0));
  float scuff = smoothstep(0.82, 0.95, ValueNoise(p * vec3(0.12, 3.0, 0.12) + 7.0)) *
                smoothstep(0.4, 0.6, ValueNoise(0.5 * p + 13.0));
  vec3 scuffed = vec3(1.0 + k * (0.9 * dust + 0.8 * scuff), 1.0 + 0.5 * k * scuff, 0.7 * k * dust);
  if (detail_kind == 3) return scuffed;
  // moulded: that, and the marks of injection moulding: rings left by ejector pins, one every 5
  // features in the plane of the face (the two axes the normal is furthest from), and faint flow
  // lines around the gate
  vec3 a = abs(detail_normal);
  vec2 q = a.z >= a.x && a.z >= a.y ? p.xy : (a.y >= a.x ? p.xz : p.yz);
  float ring = 1.0 - smoothstep(0.0, 0.04, abs(length(fract(0.2 * q) - 0.5) - 0.12));
  float flow = 0.5 + 0.5 * sin(3.0 * length(p));
  return scuffed + vec3(k * (0.6 * ring + 0.25 * flow), -0.2 * k * ring, 0.0);
}
#endif

void main() {
  // shade both sides: the back of a two-sided (open) mesh uses the flipped normal
  vec3 n = normalize(gl_FrontFacing ? normal_camera : -normal_camera);
  vec3 v = normalize(-position_camera);
  vec3 base = base_color_linear;
#if TEXTURED
  base *= SrgbToLinear(texture(material_texture, texture_coordinates).rgb);
#endif
  float r = clamp(roughness, 0.03, 1.0);
  float metal = metallic;
#if DETAIL
  vec3 detail = Detail(detail_position);
  r = clamp(r * detail.x, 0.03, 1.0);
  base = mix(min(base * detail.y, vec3(1.0)), vec3(0.3), detail.z);
  metal *= 1.0 - detail.z;  // dust is no metal
#endif
  float alpha = r * r;
  vec3 f0 = mix(vec3(dielectric_f0), base, metal);
  vec3 diffuse_color = base * (1.0 - metal);
  float n_dot_v = max(dot(n, v), 1e-4);

  // specular albedo from the lookup table; multiple scattering lifts it to the full albedo of
  // f0 = 1, and the diffuse lobe takes the rest
  vec2 dfg = texture(dfg_lut, vec2(n_dot_v, r)).xy;
  vec3 energy_compensation = vec3(1.0) + f0 * (1.0 / dfg.y - 1.0);
  vec3 specular_albedo = mix(dfg.xxx, dfg.yyy, f0) * energy_compensation;
  vec3 diffuse_weight = diffuse_color * (vec3(1.0) - specular_albedo);

  vec3 linear = vec3(0.0);
#if LIGHT_COUNT > 0
  for (int i = 0; i < LIGHT_COUNT; ++i) {
    vec3 l = normalize(light_vector_camera[i].xyz - position_camera * light_vector_camera[i].w);
    float n_dot_l = dot(n, l);
    if (n_dot_l <= 0.0) continue;
#if SHADOWS
    float lit = LitFraction(i);
#else
    const float lit = 1.0;
#endif
    vec3 h = normalize(l + v);
    float n_dot_h = max(dot(n, h), 0.0);
    float v_dot_h = max(dot(v, h), 0.0);
    vec3 specular = D_GGX(n_dot_h, alpha) * V_SmithGGXCorrelated(n_dot_v, n_dot_l, alpha) *
                    F_Schlick(f0, v_dot_h) * energy_compensation;
    linear += (diffuse_weight * (1.0 / kPi) + specular) * (light_irradiance[i] * (n_dot_l * lit));
  }
#endif
#if ENVIRONMENT
  vec3 reflected = environment_from_camera * reflect(-v, n);
  vec3 prefiltered = textureLod(environment_radiance, OctahedralUv(reflected),
                                r * environment_max_lod).rgb;
  vec3 environment = environment_intensity *
                     (diffuse_weight * (gl_FrontFacing ? irradiance : irradiance_back) +
                      specular_albedo * prefiltered);
  linear += environment;
  environment_out = vec4(environment, 1.0);
#endif
#if PROJECTOR
  // the pattern's light, from the projector to the camera over this surface's BRDF, relative to
  // a white matte surface facing the projector (pi x BRDF x cos): the same material, normal and
  // detail as the colour, so a polished face mirrors the pattern past the camera and returns
  // nothing, while matte plastic returns its albedo
  vec3 lp = normalize(projector_camera - position_camera);
  float n_dot_lp = dot(n, lp);
  float pattern = 0.0;
  if (n_dot_lp > 0.0) {
    vec3 hp = normalize(lp + v);
    vec3 specular_p = D_GGX(max(dot(n, hp), 0.0), alpha) *
                      V_SmithGGXCorrelated(n_dot_v, n_dot_lp, alpha) *
                      F_Schlick(f0, max(dot(v, hp), 0.0)) * energy_compensation;
    vec3 brdf = diffuse_weight * (1.0 / kPi) + specular_p;
    pattern = kPi * n_dot_lp * dot(brdf, vec3(1.0 / 3.0));
  }
  projector_return_out = pattern;
#endif
  color_out = vec4(linear, 1.0);
  instance_out = instance_id;
  depth_out = position_camera.z;
  surface_out = surface_id;
}
