#version 330 core
layout(location = 0) out uint bits_out;
uniform uint object_bit;  // ORed into the target by glLogicOp(GL_OR)

void main() { bits_out = object_bit; }
