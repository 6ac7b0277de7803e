// SPDX-License-Identifier: Apache-2.0
// Triangle meshes for tests and benchmarks: loaders for real files, generators for closed
// procedural shapes and random soups. Positions only: that is all a cluster build reads.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace clastrace::testsupport {

using Float3 = std::array<float, 3>;
using Triangle = std::array<uint32_t, 3>;

struct TriangleMesh {
    std::string name;
    std::vector<Float3> positions;
    std::vector<Triangle> triangles;
};

// A loader failure names the file, the byte offset or line, and what was wrong.
struct MeshLoadError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// Wavefront OBJ: "v x y z" and "f a b c ..." (polygons fan-triangulated; negative = relative).
TriangleMesh load_obj(const std::filesystem::path& path);
// PLY, ascii or binary_little_endian: x/y/z of the vertex element and a face list property.
TriangleMesh load_ply(const std::filesystem::path& path);
// Chooses by extension (.obj, .ply).
TriangleMesh load_mesh(const std::filesystem::path& path);

void save_obj(const TriangleMesh& mesh, const std::filesystem::path& path);
void save_ply(const TriangleMesh& mesh, const std::filesystem::path& path, bool binary);

// Closed 2-manifold shapes with shared vertices (every edge has exactly two triangles).
TriangleMesh make_icosphere(int subdivisions, float radius);
TriangleMesh make_torus(int major_segments, int minor_segments, float major_radius,
                        float minor_radius);
// Height-field grid, open, shared vertices; nx*ny quads = 2*nx*ny triangles.
TriangleMesh make_terrain(int nx, int ny, uint64_t seed);
// Independent triangles (no shared vertices) of edge length up to max_edge inside [-box, box]^3.
TriangleMesh make_random_soup(size_t triangle_count, uint64_t seed, float box, float max_edge);

// Real meshes shipped by Debian's assimp-testmodels, when installed.
std::filesystem::path assimp_models_dir();

struct Bounds {
    Float3 lo{{3.4028235e38f, 3.4028235e38f, 3.4028235e38f}};
    Float3 hi{{-3.4028235e38f, -3.4028235e38f, -3.4028235e38f}};
    void extend(const Float3& p);
    Float3 center() const;
    float diagonal() const;
};
Bounds bounds_of(const TriangleMesh& mesh);

// The CLAS build zeroes the low `bits` bits of each 32-bit float pattern (bits 0..32).
float truncate_float(float value, unsigned bits);
Float3 truncate_position(const Float3& p, unsigned bits);

}  // namespace clastrace::testsupport
