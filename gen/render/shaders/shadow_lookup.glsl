// Shadow-map lookup of the scene programs (phong.frag.glsl, pbr.frag.glsl); the scene vertex
// shader writes shadow_coordinates.
#if SHADOWS
in vec4 shadow_coordinates[LIGHT_COUNT];
uniform sampler2DArrayShadow shadow_maps;  // layer i: light i
uniform float shadow_texel;                // 1 / map size
uniform float shadow_depth_bias[LIGHT_COUNT];

// fraction of the texels around the surface's point in map i that see light i: with
// SHADOW_TAPS 4, the 3 x 3 texels tent weighted (four 2 x 2 filtered taps half a texel off the
// point); with 1, the 2 x 2 texels of one filtered tap (a quarter of the cost)
float LitFraction(int i) {
  vec4 c = shadow_coordinates[i];
  vec3 p = c.xyz / c.w;
  // outside the map (behind a point light, beyond its cone): lit
  if (c.w <= 0.0 || any(lessThan(p, vec3(0.0))) || any(greaterThan(p, vec3(1.0)))) return 1.0;
  float reference = p.z - shadow_depth_bias[i];
  float layer = float(i);
#if SHADOW_TAPS == 1
  return texture(shadow_maps, vec4(p.x, p.y, layer, reference));
#else
  float h = 0.5 * shadow_texel;
  return 0.25 * (texture(shadow_maps, vec4(p.x - h, p.y - h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x + h, p.y - h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x - h, p.y + h, layer, reference)) +
                 texture(shadow_maps, vec4(p.x + h, p.y + h, layer, reference)));
#endif
}
#endif
