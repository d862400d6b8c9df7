// The background image of a physically based frame as linear radiance: its display values
// (an sRGB texture, decoded by the sampler), times a scale; id, camera z and surface 0 as where
// nothing is drawn.
in vec2 texture_coordinates;
layout(location = 0) out vec4 color_out;
layout(location = 1) out uint instance_out;
layout(location = 2) out float depth_out;
layout(location = 3) out uint surface_out;
uniform sampler2D background_image;
uniform float background_scale;

void main() {
  color_out = vec4(background_scale * texture(background_image, texture_coordinates).rgb, 1.0);
  instance_out = 0u;
  depth_out = 0.0;
  surface_out = 0u;
}
