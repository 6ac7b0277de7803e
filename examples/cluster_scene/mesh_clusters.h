// SPDX-License-Identifier: Apache-2.0
// A triangle mesh cut into clusters with meshoptimizer, laid out the way the cluster
// extension reads them: each cluster's positions packed (12-byte stride) and its triangles
// as 8-bit local indices.
#pragma once

#include "obj_mesh.h"

#include <cstdint>
#include <vector>

namespace cluster_scene {

struct MeshCluster {
    uint32_t firstVertex = 0;  // into ClusteredMesh::positions (vertices, not floats)
    uint32_t vertexCount = 0;
    uint32_t firstIndex = 0;  // into ClusteredMesh::indices
    uint32_t triangleCount = 0;
};

struct ClusteredMesh {
    std::vector<float> positions;
    std::vector<uint8_t> indices;
    std::vector<MeshCluster> clusters;
    uint32_t maxClusterVertices = 0, maxClusterTriangles = 0;
    uint32_t totalVertices() const { return uint32_t(positions.size() / 3); }
    uint32_t totalTriangles() const { return uint32_t(indices.size() / 3); }
};

// meshopt_buildMeshlets with at most `maxVertices` vertices and `maxTriangles` triangles a
// cluster (both within the extension's 256), keeping the first `maxClusters` clusters (0: all).
ClusteredMesh clusterMesh(const TriangleMesh& mesh, uint32_t maxVertices, uint32_t maxTriangles,
                          uint32_t maxClusters);

}  // namespace cluster_scene
