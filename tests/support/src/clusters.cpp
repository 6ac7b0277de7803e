// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/clusters.h"

#include <meshoptimizer.h>

#include <unordered_map>
#include <stdexcept>

namespace clastrace::testsupport {
namespace {

struct CornersHash {
    size_t operator()(const std::array<uint32_t, 3>& c) const {
        uint64_t h = 0x9E3779B97F4A7C15ull;
        for (uint32_t v : c) h = (h ^ v) * 0xBF58476D1CE4E5B9ull;
        return size_t(h ^ (h >> 31));
    }
};
using CornerMap = std::unordered_map<std::array<uint32_t, 3>, std::vector<uint32_t>, CornersHash>;

}  // namespace

std::vector<MeshCluster> build_clusters(const TriangleMesh& mesh, size_t max_vertices,
                                        size_t max_triangles) {
    if (max_vertices < 3 || max_vertices > 255 || max_triangles < 4 || max_triangles > 512 ||
        max_triangles % 4 != 0)
        throw std::invalid_argument("build_clusters: limits outside meshoptimizer 0.18's range");
    std::vector<uint32_t> indices;
    indices.reserve(mesh.triangles.size() * 3);
    for (const Triangle& t : mesh.triangles) indices.insert(indices.end(), t.begin(), t.end());
    // Spatial order keeps clusters compact for soups; meshlets then follow that order.
    std::vector<uint32_t> sorted(indices.size());
    meshopt_spatialSortTriangles(sorted.data(), indices.data(), indices.size(),
                                 &mesh.positions[0][0], mesh.positions.size(), sizeof(Float3));

    // The sort permutes triangles; recover each sorted triangle's mesh id through its corners.
    CornerMap by_corners;
    by_corners.reserve(mesh.triangles.size());
    for (uint32_t t = 0; t < mesh.triangles.size(); ++t) by_corners[mesh.triangles[t]].push_back(t);
    std::vector<uint32_t> sorted_ids(mesh.triangles.size());
    for (size_t t = 0; t < sorted_ids.size(); ++t) {
        auto& ids = by_corners.at({sorted[3 * t], sorted[3 * t + 1], sorted[3 * t + 2]});
        sorted_ids[t] = ids.back();
        ids.pop_back();
    }

    const size_t bound = meshopt_buildMeshletsBound(sorted.size(), max_vertices, max_triangles);
    std::vector<meshopt_Meshlet> meshlets(bound);
    std::vector<unsigned int> meshlet_vertices(bound * max_vertices);
    std::vector<unsigned char> meshlet_triangles(bound * max_triangles * 3);
    const size_t count =
        meshopt_buildMeshlets(meshlets.data(), meshlet_vertices.data(), meshlet_triangles.data(),
                              sorted.data(), sorted.size(), &mesh.positions[0][0],
                              mesh.positions.size(), sizeof(Float3), max_vertices, max_triangles,
                              0.0f);

    // meshopt does not say which input triangle each meshlet triangle is; match by corners.
    CornerMap sorted_by_corners;
    sorted_by_corners.reserve(sorted_ids.size());
    for (uint32_t t = 0; t < sorted_ids.size(); ++t)
        sorted_by_corners[{sorted[3 * t], sorted[3 * t + 1], sorted[3 * t + 2]}].push_back(
            sorted_ids[t]);

    std::vector<MeshCluster> clusters(count);
    for (size_t m = 0; m < count; ++m) {
        const meshopt_Meshlet& ml = meshlets[m];
        MeshCluster& c = clusters[m];
        c.vertices.assign(meshlet_vertices.begin() + ml.vertex_offset,
                          meshlet_vertices.begin() + ml.vertex_offset + ml.vertex_count);
        for (size_t t = 0; t < ml.triangle_count; ++t) {
            const unsigned char* tri = &meshlet_triangles[ml.triangle_offset + 3 * t];
            c.triangles.push_back({tri[0], tri[1], tri[2]});
            std::array<uint32_t, 3> corners{c.vertices[tri[0]], c.vertices[tri[1]],
                                            c.vertices[tri[2]]};
            auto it = sorted_by_corners.find(corners);
            if (it == sorted_by_corners.end() || it->second.empty())
                throw std::logic_error("build_clusters: meshlet triangle not found in the input");
            c.mesh_triangles.push_back(it->second.back());
            it->second.pop_back();
        }
    }
    return clusters;
}

size_t total_triangles(const std::vector<MeshCluster>& clusters) {
    size_t n = 0;
    for (const MeshCluster& c : clusters) n += c.triangles.size();
    return n;
}

}  // namespace clastrace::testsupport
