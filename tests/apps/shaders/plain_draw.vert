// SPDX-License-Identifier: Apache-2.0
// address_draw_app: a vertex shader that reaches no memory (its draws are not recorded).
#version 460

void main() { gl_Position = vec4(float(gl_VertexIndex), 0.0, 0.0, 1.0); }
