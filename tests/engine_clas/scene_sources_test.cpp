// SPDX-License-Identifier: Apache-2.0
// The scene sources the proof rests on: if a loader or the clustering dropped or reordered
// triangles, agreement with Embree would prove nothing about the real meshes.
#include "clastrace/testsupport/clusters.h"
#include "clastrace/testsupport/mesh.h"

#include <gtest/gtest.h>

#include <bit>
#include <fstream>
#include <map>
#include <unistd.h>
#include <set>

namespace ts = clastrace::testsupport;

namespace {

std::filesystem::path temp_path(const std::string& name) {
    return std::filesystem::temp_directory_path() /
           ("clastrace_proof_" + std::to_string(::getpid()) + "_" + name);
}

void expect_same_mesh(const ts::TriangleMesh& a, const ts::TriangleMesh& b) {
    ASSERT_EQ(a.positions.size(), b.positions.size());
    ASSERT_EQ(a.triangles.size(), b.triangles.size());
    for (size_t i = 0; i < a.positions.size(); ++i)
        for (int k = 0; k < 3; ++k)
            ASSERT_EQ(a.positions[i][k], b.positions[i][k]) << "vertex " << i;
    for (size_t i = 0; i < a.triangles.size(); ++i)
        ASSERT_EQ(a.triangles[i], b.triangles[i]) << "triangle " << i;
}

}  // namespace

TEST(SceneSources, AssimpModelsLoad) {
    const auto dir = ts::assimp_models_dir();
    if (!std::filesystem::exists(dir / "OBJ/WusonOBJ.obj"))
        GTEST_SKIP() << "assimp-testmodels not installed";
    const ts::TriangleMesh wuson_obj = ts::load_obj(dir / "OBJ/WusonOBJ.obj");
    EXPECT_EQ(wuson_obj.positions.size(), 2117u);
    EXPECT_EQ(wuson_obj.triangles.size(), 3732u);  // all faces are triangles in this file
    const ts::TriangleMesh wuson_ply = ts::load_ply(dir / "PLY/Wuson.ply");  // ascii
    EXPECT_EQ(wuson_ply.positions.size(), 11184u);
    EXPECT_EQ(wuson_ply.triangles.size(), 3732u);
    const ts::TriangleMesh cube =
        ts::load_ply(dir / "PLY/cube_binary.ply");  // binary little endian, int indices
    EXPECT_EQ(cube.positions.size(), 8u);
    EXPECT_EQ(cube.triangles.size(), 12u);
    const ts::Bounds b = ts::bounds_of(cube);
    for (int k = 0; k < 3; ++k) EXPECT_LT(b.lo[k], b.hi[k]);
    const ts::TriangleMesh spider =
        ts::load_obj(dir / "OBJ/spider.obj");  // "v/vt/vn" face references
    EXPECT_EQ(spider.triangles.size(), 1368u);
}

TEST(SceneSources, QuadsAreFanTriangulatedAndNegativeIndicesResolve) {
    const auto path = temp_path("quad.obj");
    {
        std::ofstream out(path);
        out << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf -1 -2 -3\n";
    }
    const ts::TriangleMesh m = ts::load_obj(path);
    std::filesystem::remove(path);
    ASSERT_EQ(m.triangles.size(), 3u);
    EXPECT_EQ(m.triangles[0], (ts::Triangle{0, 1, 2}));
    EXPECT_EQ(m.triangles[1], (ts::Triangle{0, 2, 3}));
    EXPECT_EQ(m.triangles[2], (ts::Triangle{4, 3, 2}));
}

TEST(SceneSources, GeneratedFilesRoundTripExactly) {
    const ts::TriangleMesh torus = ts::make_torus(24, 12, 2.0f, 0.5f);
    for (const char* kind : {"obj", "ply-ascii", "ply-binary"}) {
        const auto path =
            temp_path(std::string(kind) + (std::string(kind) == "obj" ? ".obj" : ".ply"));
        if (std::string(kind) == "obj")
            ts::save_obj(torus, path);
        else
            ts::save_ply(torus, path, std::string(kind) == "ply-binary");
        const ts::TriangleMesh back = ts::load_mesh(path);
        std::filesystem::remove(path);
        SCOPED_TRACE(kind);
        expect_same_mesh(torus, back);
    }
}

TEST(SceneSources, MalformedFilesAreErrorsNamingTheFile) {
    const auto dir = ts::assimp_models_dir() / "invalid";
    if (std::filesystem::exists(dir / "malformed.obj")) {
        // "f 4 12 2 1" with 8 vertices, and index 0.
        try {
            ts::load_obj(dir / "malformed.obj");
            FAIL() << "malformed.obj loaded";
        } catch (const ts::MeshLoadError& e) {
            EXPECT_NE(std::string(e.what()).find("malformed.obj"), std::string::npos) << e.what();
        }
    }
    const ts::TriangleMesh tri = ts::make_random_soup(4, 1, 1.0f, 0.5f);
    const auto path = temp_path("trunc.ply");
    ts::save_ply(tri, path, true);
    std::filesystem::resize_file(path, std::filesystem::file_size(path) - 5);  // cut the last face
    EXPECT_THROW(ts::load_ply(path), ts::MeshLoadError);
    {
        std::ofstream out(path, std::ios::binary);
        out << "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float "
               "x\nproperty float y\n"
               "property float z\nend_header\n";
    }
    EXPECT_THROW(ts::load_ply(path),
                 ts::MeshLoadError);  // hostile count: an error, not a huge allocation
    {
        std::ofstream out(path, std::ios::binary);
        out << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float "
               "y\nproperty float z\n"
               "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 "
               "0\n0 1 0\n3 0 1 7\n";
    }
    EXPECT_THROW(ts::load_ply(path), ts::MeshLoadError);  // index 7 of 3 vertices
    std::filesystem::remove(path);
}

TEST(SceneSources, ClosedMeshesHaveEveryEdgeTwice) {
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(3, 1.0f), ts::make_torus(32, 16, 1.0f, 0.3f)}) {
        std::map<std::pair<uint32_t, uint32_t>, int> directed;
        for (const ts::Triangle& t : m.triangles)
            for (int k = 0; k < 3; ++k) ++directed[{t[k], t[(k + 1) % 3]}];
        for (const auto& [e, n] : directed) {
            ASSERT_EQ(n, 1) << m.name << " edge used twice in one direction";
            ASSERT_EQ(directed.count({e.second, e.first}), 1u) << m.name << " open edge";
        }
    }
}

TEST(SceneSources, MeshletsCoverEveryTriangleOnceWithinLimits) {
    struct Case {
        ts::TriangleMesh mesh;
        size_t max_v, max_t;
    };
    std::vector<Case> cases = {{ts::make_icosphere(4, 1.0f), 64, 124},
                               {ts::make_terrain(40, 30, 7), 255, 256},
                               {ts::make_random_soup(5000, 3, 10.0f, 0.5f), 128, 128}};
    for (const Case& c : cases) {
        SCOPED_TRACE(c.mesh.name);
        const auto clusters = ts::build_clusters(c.mesh, c.max_v, c.max_t);
        std::vector<int> seen(c.mesh.triangles.size(), 0);
        for (const ts::MeshCluster& cl : clusters) {
            ASSERT_LE(cl.vertices.size(), c.max_v);
            ASSERT_LE(cl.triangles.size(), c.max_t);
            ASSERT_EQ(cl.triangles.size(), cl.mesh_triangles.size());
            for (size_t t = 0; t < cl.triangles.size(); ++t) {
                const ts::Triangle& orig = c.mesh.triangles[cl.mesh_triangles[t]];
                for (int k = 0; k < 3; ++k) {
                    ASSERT_LT(cl.triangles[t][k], cl.vertices.size());
                    ASSERT_EQ(cl.vertices[cl.triangles[t][k]],
                              orig[k]);  // same corners, same winding
                }
                ++seen[cl.mesh_triangles[t]];
            }
        }
        for (size_t t = 0; t < seen.size(); ++t) ASSERT_EQ(seen[t], 1) << "triangle " << t;
    }
}

TEST(SceneSources, TruncationZeroesExactlyTheLowBits) {
    EXPECT_EQ(ts::truncate_float(1.0f, 0), 1.0f);
    EXPECT_EQ(std::bit_cast<uint32_t>(ts::truncate_float(std::bit_cast<float>(0xFFFFFFFFu), 8)),
              0xFFFFFF00u);
    EXPECT_EQ(std::bit_cast<uint32_t>(ts::truncate_float(-1.5f, 32)), 0u);
    EXPECT_EQ(std::bit_cast<uint32_t>(ts::truncate_float(std::bit_cast<float>(0x3FFFFFFFu), 23)),
              0x3F800000u);
}
