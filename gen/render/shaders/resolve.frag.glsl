// Unpacks the multisampled coverage pass for the resolve on the CPU (Renderer, ResolveEdges):
// the surface each of the pixel's first four samples sees, as one RGBA16UI texel (a sample
// beyond SAMPLES repeats sample 0).
layout(location = 0) out uvec4 surfaces_out;
uniform usampler2DMS coverage;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  uint s0 = texelFetch(coverage, p, 0).r;
  uvec4 out_value = uvec4(s0);
#if SAMPLES > 1
  out_value.y = texelFetch(coverage, p, 1).r;
#endif
#if SAMPLES > 2
  out_value.z = texelFetch(coverage, p, 2).r;
  out_value.w = texelFetch(coverage, p, 3).r;
#endif
  surfaces_out = out_value;
}
