// SPDX-License-Identifier: Apache-2.0
// address_draw_app: each vertex writes its index through a buffer device address taken from a
// push constant (GL_EXT_buffer_reference); nothing is rasterized.
#version 460
#extension GL_EXT_buffer_reference : require

layout(buffer_reference, std430, buffer_reference_align = 4) writeonly buffer Indices {
    uint values[];
};

layout(push_constant) uniform Target {
    Indices indices;
} target;

void main() {
    target.indices.values[gl_VertexIndex] = uint(gl_VertexIndex) + 1u;
    gl_Position = vec4(0.0);
}
