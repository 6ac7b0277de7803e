// SPDX-License-Identifier: Apache-2.0
// ray_consumers_app "address-in-buffer": the top level named by a device address read from a
// storage buffer (the capture's source 4), the same ray query as ray_query.comp. With `trace` 0
// the address is not converted: the buffer may hold any bytes. Writes 1 on a committed triangle
// hit, 2 on a miss, 3 when it does not trace.
#version 460
#extension GL_EXT_ray_query : require
#extension GL_ARB_gpu_shader_int64 : require
layout(local_size_x = 1) in;

layout(set = 0, binding = 0, std430) readonly buffer Scene {
    uint64_t address;
    uint trace;
    uint slot;
} scene;
layout(set = 0, binding = 1, std430) buffer Results {
    uint values[];
} results;

void main() {
    if (scene.trace == 0u) {
        results.values[scene.slot] = 3u;
        return;
    }
    rayQueryEXT query;
    rayQueryInitializeEXT(query, accelerationStructureEXT(scene.address), gl_RayFlagsOpaqueEXT,
                          0xFF, vec3(0.25, 0.25, -1.0), 0.0, vec3(0.0, 0.0, 1.0), 10.0);
    while (rayQueryProceedEXT(query)) {
    }
    const bool hit = rayQueryGetIntersectionTypeEXT(query, true) ==
                     gl_RayQueryCommittedIntersectionTriangleEXT;
    results.values[scene.slot] = hit ? 1u : 2u;
}
