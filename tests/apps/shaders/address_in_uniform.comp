// SPDX-License-Identifier: Apache-2.0
// ray_consumers_app "address-in-buffer": address_in_buffer.comp with the top level's device
// address read from a uniform buffer (bound with a dynamic offset) instead of a storage buffer.
// Writes 1 on a committed triangle hit, 2 on a miss, 3 when it does not trace.
#version 460
#extension GL_EXT_ray_query : require
#extension GL_ARB_gpu_shader_int64 : require
layout(local_size_x = 1) in;

layout(set = 0, binding = 0, std140) uniform Scene {
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
