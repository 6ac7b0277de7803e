// SPDX-License-Identifier: Apache-2.0
// A Wavefront OBJ reader for the sample: positions and faces only (normals, texture
// coordinates, groups and materials are skipped), polygons fanned into triangles.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace cluster_scene {

struct TriangleMesh {
    std::vector<float> positions;   // xyz per vertex
    std::vector<uint32_t> indices;  // three per triangle
    size_t vertexCount() const { return positions.size() / 3; }
    size_t triangleCount() const { return indices.size() / 3; }
};

// Reads `path`. On failure returns false and sets `error` to "FILE:LINE: what is wrong".
// Rejected: unreadable files, non-numeric or non-finite coordinates, face indices that
// name no vertex (1-based, negative = relative to the end), faces of fewer than 3 corners,
// and a file without a single triangle.
bool loadObj(const std::string& path, TriangleMesh& mesh, std::string& error);

// The mesh `copies` times side by side along x (each copy one mesh width and a tenth further):
// a large scene from a small file, for the trace-size and build benches.
void tileMesh(TriangleMesh& mesh, uint32_t copies);

}  // namespace cluster_scene
