#version 330 core
layout(location = 0) in vec3 position_object;
uniform mat4 light_clip_from_object;

void main() { gl_Position = light_clip_from_object * vec4(position_object, 1.0); }
