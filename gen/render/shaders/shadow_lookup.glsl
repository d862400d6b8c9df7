// Shadow-map lookup of the scene programs (phong.frag.glsl, pbr.frag.glsl); the scene vertex
// shader writes shadow_coordinates.
#if SHADOWS
in vec4 shadow_coordinates[LIGHT_COUNT];
uniform sampler2DArrayShadow shadow_maps;  // layer i: light i
uniform float shadow_texel;                // 1 / map size
uniform float shadow_depth_bias[LIGHT_COUNT];

#if SHADOW_TAPS == 0
// Soft shadows of lamps of some size (percentage-closer soft shadows, Fernando 2005): the
// occluders around the point in the map give their mean distance d from the surface, and the
// point is lit by the share of the texels within d x tan(radius) that see the light, so a shadow
// is sharp where a part touches what it shades and soft further away. 8 taps find the occluders
// (none: lit; all: in the umbra, done), 16 filter the edge; both on Vogel's spiral turned per
// pixel (a grain the camera's noise hides, where fixed taps would draw bands).
uniform sampler2DArray shadow_depths;  // the maps' depths, not compared
// per light: perspective 0 or 1, near and far (mm from the light), texels of edge half width
// per mm of occluder distance (perspective: times the receiver's distance from the light)
uniform vec4 shadow_softness[LIGHT_COUNT];
const float kSoftSearchMm = 100.0;  // occluders up to this far from the surface soften it
const float kSoftMaxTexels = 48.0;  // the widest search and edge, texels
const vec2 kSearchTaps[8] = vec2[](
    vec2(0.25000, 0.00000), vec2(-0.31929, 0.29250), vec2(0.04887, -0.55688),
    vec2(0.40244, 0.52492), vec2(-0.73854, -0.13064), vec2(0.69960, -0.44503),
    vec2(-0.23400, 0.87048), vec2(-0.44627, -0.85927));
const vec2 kEdgeTaps[16] = vec2[](
    vec2(0.17678, 0.00000), vec2(-0.22577, 0.20683), vec2(0.03456, -0.39377),
    vec2(0.28457, 0.37117), vec2(-0.52222, -0.09237), vec2(0.49470, -0.31468),
    vec2(-0.16547, 0.61553), vec2(-0.31556, -0.60759), vec2(0.68464, 0.25003),
    vec2(-0.71226, 0.29401), vec2(0.34335, -0.73373), vec2(0.25373, 0.80893),
    vec2(-0.76475, -0.44319), vec2(0.89713, -0.19723), vec2(-0.54751, 0.77877),
    vec2(-0.12649, -0.97609));

// a map depth (0..1) as mm from light i (orthographic: up to a constant, which cancels)
float LightDistanceMm(int i, float depth) {
  vec4 s = shadow_softness[i];
  if (s.x < 0.5) return depth * (s.z - s.y);
  return 2.0 * s.z * s.y / ((s.z + s.y) - (2.0 * depth - 1.0) * (s.z - s.y));
}

float SoftLitFraction(int i, vec2 uv, float reference, float layer) {
  float receiver = LightDistanceMm(i, reference);
  float per_mm = shadow_softness[i].x < 0.5 ? shadow_softness[i].w
                                            : shadow_softness[i].w / receiver;
  if (per_mm <= 0.0) return texture(shadow_maps, vec4(uv, layer, reference));
  float angle = 6.2831853 * fract(sin(dot(gl_FragCoord.xy, vec2(12.9898, 78.233))) * 43758.5453);
  mat2 turn = mat2(cos(angle), sin(angle), -sin(angle), cos(angle)) * shadow_texel;
  mat2 search = turn * clamp(per_mm * kSoftSearchMm, 1.0, kSoftMaxTexels);
  float occluders = 0.0;
  float count = 0.0;
  for (int k = 0; k < 8; ++k) {
    float depth = texture(shadow_depths, vec3(uv + search * kSearchTaps[k], layer)).r;
    if (depth < reference) {
      occluders += LightDistanceMm(i, depth);
      count += 1.0;
    }
  }
  if (count == 0.0) return 1.0;
  if (count == 8.0) return 0.0;
  mat2 edge = turn * clamp((receiver - occluders / count) * per_mm, 0.5, kSoftMaxTexels);
  float lit = 0.0;
  for (int k = 0; k < 16; ++k) {
    lit += texture(shadow_maps, vec4(uv + edge * kEdgeTaps[k], layer, reference));
  }
  return lit * (1.0 / 16.0);
}
#endif

// fraction of the texels around the surface's point in map i that see light i: with
// SHADOW_TAPS 4, the 3 x 3 texels tent weighted (four 2 x 2 filtered taps half a texel off the
// point); with 1, the 2 x 2 texels of one filtered tap (a quarter of the cost); with 0, soft
// (SoftLitFraction)
float LitFraction(int i) {
  vec4 c = shadow_coordinates[i];
  vec3 p = c.xyz / c.w;
  // outside the map (behind a point light, beyond its cone): lit
  if (c.w <= 0.0 || any(lessThan(p, vec3(0.0))) || any(greaterThan(p, vec3(1.0)))) return 1.0;
  float reference = p.z - shadow_depth_bias[i];
  float layer = float(i);
#if SHADOW_TAPS == 1
  return texture(shadow_maps, vec4(p.x, p.y, layer, reference));
#elif SHADOW_TAPS == 0
  return SoftLitFraction(i, p.xy, reference, layer);
#else
  float h = 0.5 * shadow_texel;
  return 0.25 * (texture(shadow_maps, vec4(p.x - h, p.y - h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x + h, p.y - h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x - h, p.y + h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x + h, p.y + h, layer, reference)));
#endif
}
#endif
