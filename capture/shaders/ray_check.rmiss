#version 460
#extension GL_NV_ray_tracing : require
#extension GL_GOOGLE_include_directive : require
#include "ray_check_common.glsl"

layout(location = 0) rayPayloadInNV RayHit payload;

void main() { payload.hit = 0u; }
