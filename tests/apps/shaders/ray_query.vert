// SPDX-License-Identifier: Apache-2.0
// ray_consumers_app: the compute ray query again, from a vertex shader (one vertex, rasterizer
// discard): results[18] = 1 on a hit, 2 on a miss.
#version 460
#extension GL_EXT_ray_query : require

layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) buffer Results {
    uint values[];
} results;

void main() {
    rayQueryEXT query;
    rayQueryInitializeEXT(query, scene, gl_RayFlagsOpaqueEXT, 0xFF, vec3(0.25, 0.25, -1.0), 0.0,
                          vec3(0.0, 0.0, 1.0), 10.0);
    while (rayQueryProceedEXT(query)) {
    }
    const bool hit = rayQueryGetIntersectionTypeEXT(query, true) ==
                     gl_RayQueryCommittedIntersectionTriangleEXT;
    results.values[18] = hit ? 1u : 2u;
    gl_Position = vec4(0.0);
}
