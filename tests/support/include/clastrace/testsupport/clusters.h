// SPDX-License-Identifier: Apache-2.0
// Splits a mesh into clusters with meshoptimizer, the way a Mega-Geometry style engine would
// before it builds one CLAS per cluster.
#pragma once

#include "clastrace/testsupport/mesh.h"

namespace clastrace::testsupport {

struct MeshCluster {
    std::vector<uint32_t> vertices;                 // mesh vertex ids, in cluster-local order
    std::vector<std::array<uint8_t, 3>> triangles;  // cluster-local vertex indices
    std::vector<uint32_t> mesh_triangles;           // for each local triangle, its mesh triangle id
};

// meshopt_buildMeshlets (0.18: max_vertices <= 255, max_triangles <= 512 and a multiple of 4).
// Soups are spatially sorted first so that clusters stay compact.
std::vector<MeshCluster> build_clusters(const TriangleMesh& mesh, size_t max_vertices,
                                        size_t max_triangles);

size_t total_triangles(const std::vector<MeshCluster>& clusters);

}  // namespace clastrace::testsupport
