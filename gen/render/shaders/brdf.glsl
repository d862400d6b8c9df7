// The terms of the metallic-roughness BRDF, one function each, named as in the literature:
// google/filament docs/Filament.md ("Physically based rendering in Filament", section 4) and
// shaders/src/brdf.fs. Roughness is perceptual; alpha = roughness^2.
const float kPi = 3.14159265358979;

// GGX / Trowbridge-Reitz normal distribution (Walter et al. 2007)
float D_GGX(float n_dot_h, float alpha) {
  float a2 = alpha * alpha;
  float f = (n_dot_h * a2 - n_dot_h) * n_dot_h + 1.0;
  return a2 / (kPi * f * f);
}

// Smith's height-correlated masking-shadowing as visibility G / (4 n.l n.v) (Heitz 2014)
float V_SmithGGXCorrelated(float n_dot_v, float n_dot_l, float alpha) {
  float a2 = alpha * alpha;
  float gv = n_dot_l * sqrt(n_dot_v * n_dot_v * (1.0 - a2) + a2);
  float gl = n_dot_v * sqrt(n_dot_l * n_dot_l * (1.0 - a2) + a2);
  return 0.5 / (gv + gl);
}

// Schlick's Fresnel approximation with f90 = 1
vec3 F_Schlick(vec3 f0, float v_dot_h) {
  float f = 1.0 - v_dot_h;
  float f2 = f * f;
  return f0 + (vec3(1.0) - f0) * (f2 * f2 * f);
}
