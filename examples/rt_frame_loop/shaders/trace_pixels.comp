#version 460
// SPDX-License-Identifier: Apache-2.0
// rt_frame_loop's rays: one ray query per pixel (frame_scene.cpp's pixel_ray and hit_colour),
// the closest hit's colour written to the frame's pixel buffer.
#extension GL_EXT_ray_query : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) writeonly buffer Pixels { uint pixels[]; };
layout(push_constant) uniform Frame { uint width; uint height; } frame;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (p.x >= frame.width || p.y >= frame.height) return;
    vec2 uv = (vec2(p) + 0.5) / vec2(frame.width, frame.height);
    vec3 origin = vec3(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, -1.0);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsOpaqueEXT, 0xff, origin, 0.0, vec3(0, 0, 1), 100.0);
    while (rayQueryProceedEXT(q)) {}
    uint colour = 0xff202020u;
    if (rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionTriangleEXT) {
        uint instance = rayQueryGetIntersectionInstanceCustomIndexEXT(q, true);
        uint primitive = rayQueryGetIntersectionPrimitiveIndexEXT(q, true);
        uint base = instance == 0u ? 0x00e05030u : 0x003060e0u;
        colour = 0xff000000u | (base + ((primitive * 0x40u) << 8));
    }
    pixels[p.y * frame.width + p.x] = colour;
}
