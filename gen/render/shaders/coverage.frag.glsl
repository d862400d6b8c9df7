// The coverage pass of anti-aliased physically based frames: which surface each sample of a
// multisampled framebuffer sees (item index + 1; 0 = nothing), for resolve.frag.glsl.
layout(location = 0) out uint surface_out;
uniform uint surface_id;

void main() { surface_out = surface_id; }
