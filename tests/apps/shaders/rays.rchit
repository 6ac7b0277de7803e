// SPDX-License-Identifier: Apache-2.0
// ray_consumers_app: a hit writes 1.
#version 460
#extension GL_EXT_ray_tracing : require

layout(location = 0) rayPayloadInEXT uint payload;

void main() { payload = 1u; }
