// SPDX-License-Identifier: Apache-2.0
#include "mesh_clusters.h"

#include <meshoptimizer.h>

#include <algorithm>

namespace cluster_scene {

ClusteredMesh clusterMesh(const TriangleMesh& mesh, uint32_t maxVertices, uint32_t maxTriangles,
                          uint32_t maxClusters) {
    const size_t bound = meshopt_buildMeshletsBound(mesh.indices.size(), maxVertices, maxTriangles);
    std::vector<meshopt_Meshlet> meshlets(bound);
    std::vector<unsigned int> meshletVertices(bound * maxVertices);
    std::vector<unsigned char> meshletTriangles(bound * maxTriangles * 3);
    // cone_weight 0: group by locality only (no backface-cone culling in this sample).
    const size_t count =
        meshopt_buildMeshlets(meshlets.data(), meshletVertices.data(), meshletTriangles.data(),
                              mesh.indices.data(), mesh.indices.size(), mesh.positions.data(),
                              mesh.vertexCount(), 12, maxVertices, maxTriangles, 0.0f);
    ClusteredMesh out;
    const size_t kept = maxClusters ? std::min<size_t>(count, maxClusters) : count;
    for (size_t m = 0; m < kept; ++m) {
        const meshopt_Meshlet& meshlet = meshlets[m];
        MeshCluster c;
        c.firstVertex = out.totalVertices();
        c.vertexCount = meshlet.vertex_count;
        c.firstIndex = uint32_t(out.indices.size());
        c.triangleCount = meshlet.triangle_count;
        for (uint32_t v = 0; v < meshlet.vertex_count; ++v) {
            const float* p =
                &mesh.positions[3 * size_t(meshletVertices[meshlet.vertex_offset + v])];
            out.positions.insert(out.positions.end(), p, p + 3);
        }
        out.indices.insert(out.indices.end(), meshletTriangles.begin() + meshlet.triangle_offset,
                           meshletTriangles.begin() + meshlet.triangle_offset +
                               3 * meshlet.triangle_count);
        out.maxClusterVertices = std::max(out.maxClusterVertices, c.vertexCount);
        out.maxClusterTriangles = std::max(out.maxClusterTriangles, c.triangleCount);
        out.clusters.push_back(c);
    }
    return out;
}

}  // namespace cluster_scene
