// SPDX-License-Identifier: Apache-2.0
// The sample's mesh side: its OBJ reader on real, hand-written and randomly damaged files,
// and meshoptimizer clustering that keeps every triangle of the mesh.
#include "mesh_clusters.h"
#include "obj_mesh.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <unistd.h>

namespace {

namespace fs = std::filesystem;
using cluster_scene::ClusteredMesh;
using cluster_scene::TriangleMesh;

const char* kModels = "/usr/share/assimp/models/OBJ";

class ObjFiles : public ::testing::Test {
protected:
    fs::path dir;
    void SetUp() override {
        dir = fs::temp_directory_path() / ("clastrace_obj_" + std::to_string(::getpid()));
        fs::create_directories(dir);
    }
    void TearDown() override { fs::remove_all(dir); }
    fs::path write(const std::string& name, const std::string& text) {
        std::ofstream(dir / name, std::ios::binary) << text;
        return dir / name;
    }
    static std::string load(const fs::path& path, TriangleMesh& mesh) {
        std::string error;
        return cluster_scene::loadObj(path.string(), mesh, error) ? "" : error;
    }
};

TEST_F(ObjFiles, ReadsTheWusonModel) {
    const fs::path wuson = fs::path(kModels) / "WusonOBJ.obj";
    if (!fs::exists(wuson)) GTEST_SKIP() << "assimp-testmodels is not installed";
    TriangleMesh mesh;
    ASSERT_EQ(load(wuson, mesh), "");
    EXPECT_EQ(mesh.vertexCount(), 2117u);    // its 'v' lines
    EXPECT_EQ(mesh.triangleCount(), 3732u);  // its 'f' lines, all triangles
    for (uint32_t i : mesh.indices) ASSERT_LT(i, mesh.vertexCount());
}

TEST_F(ObjFiles, FaceFormsNegativeIndicesAndPolygons) {
    TriangleMesh mesh;
    ASSERT_EQ(load(write("forms.obj",
                         "# comment\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
                         "g group\nusemtl m\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -2//1 -1//1\r\n"),
                   mesh),
              "");
    EXPECT_EQ(mesh.indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 0, 2, 3}));
    EXPECT_EQ(mesh.positions[6], 1.0f);
}

TEST_F(ObjFiles, EachDamageNamesFileLineAndRule) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"v 0 0 0\nv 1 0\nf 1 2 1\n", ":2: vertex with fewer than 3 coordinates"},
        {"v 0 0 0\nv 1 x 0\n", ":2: coordinate 'x' is not a number"},
        {"v 0 0 nan\n", ":1: coordinate 'nan' is not finite"},
        {"v 0 0 1e999\n", ":1: coordinate '1e999' is not finite"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", ":4: face corner 0 names no vertex"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", ":4: face corner -4 names no vertex"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", ":4: face corner"},
        {"v 0 0 0\nv 1 0 0\nf 1 2\n", ":3: face with fewer than 3 corners"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n", ":4: face corner 'a' is not a vertex index"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\n", ": no faces"},
        {"", ": no faces"},
    };
    for (size_t i = 0; i < cases.size(); ++i) {
        const fs::path path = write("bad" + std::to_string(i) + ".obj", cases[i].first);
        TriangleMesh mesh;
        const std::string error = load(path, mesh);
        EXPECT_EQ(error.rfind(path.string(), 0), 0u) << error;
        EXPECT_NE(error.find(cases[i].second), std::string::npos) << "case " << i << ": " << error;
    }
    TriangleMesh mesh;
    EXPECT_NE(load(dir / "missing.obj", mesh).find("missing.obj: cannot open"), std::string::npos);
}

// Every OBJ of assimp-testmodels either reads into a mesh whose indices all name a vertex, or
// fails with a message naming the file (some are deliberately odd: UTF-16, "3.1+e2").
TEST_F(ObjFiles, EveryTestModelReadsOrFailsClearly) {
    if (!fs::exists(kModels)) GTEST_SKIP() << "assimp-testmodels is not installed";
    size_t read = 0;
    for (const auto& entry : fs::directory_iterator(kModels)) {
        if (entry.path().extension() != ".obj") continue;
        TriangleMesh mesh;
        const std::string error = load(entry.path(), mesh);
        if (error.empty()) {
            ++read;
            for (uint32_t i : mesh.indices) ASSERT_LT(i, mesh.vertexCount()) << entry.path();
        } else {
            EXPECT_EQ(error.rfind(entry.path().string(), 0), 0u) << error;
        }
    }
    EXPECT_GE(read, 10u);
}

// Deterministic random damage (byte flips, truncation, inserted digits and signs) over a real
// model: never a crash or an index out of range; failures name the file and a line.
TEST_F(ObjFiles, RandomlyDamagedFilesNeverEscape) {
    const fs::path source = fs::path(kModels) / "box.obj";
    if (!fs::exists(source)) GTEST_SKIP() << "assimp-testmodels is not installed";
    std::ifstream in(source, std::ios::binary);
    const std::string original((std::istreambuf_iterator<char>(in)),
                               std::istreambuf_iterator<char>());
    std::mt19937 random(6);
    const std::string alphabet = "0123456789-+.e /\nvfnaxE";
    size_t failed = 0;
    for (int round = 0; round < 300; ++round) {
        std::string text = original;
        const int edits = 1 + int(random() % 6);
        for (int e = 0; e < edits && !text.empty(); ++e) {
            const size_t at = random() % text.size();
            switch (random() % 3) {
            case 0: text[at] = alphabet[random() % alphabet.size()]; break;
            case 1: text.insert(at, 1, alphabet[random() % alphabet.size()]); break;
            default: text.resize(at); break;
            }
        }
        const fs::path path = write("mutant.obj", text);
        TriangleMesh mesh;
        const std::string error = load(path, mesh);
        if (error.empty()) {
            ASSERT_EQ(mesh.indices.size() % 3, 0u);
            for (uint32_t i : mesh.indices) ASSERT_LT(i, mesh.vertexCount()) << text;
            for (float p : mesh.positions) ASSERT_TRUE(std::isfinite(p)) << text;
        } else {
            ++failed;
            ASSERT_EQ(error.rfind(path.string() + ":", 0), 0u) << error;
        }
    }
    EXPECT_GT(failed, 0u);  // the damage did reach the reader
}

// Clustering keeps every triangle (same corner positions), within the asked limits, and
// --max-clusters keeps a prefix.
TEST(MeshClusters, EveryTriangleLandsInOneClusterWithinLimits) {
    const fs::path wuson = fs::path(kModels) / "WusonOBJ.obj";
    if (!fs::exists(wuson)) GTEST_SKIP() << "assimp-testmodels is not installed";
    TriangleMesh mesh;
    std::string error;
    ASSERT_TRUE(cluster_scene::loadObj(wuson.string(), mesh, error)) << error;
    using Triangle = std::array<float, 9>;
    auto canonical = [](Triangle t) {  // rotation-invariant: start at the smallest corner
        std::array<std::array<float, 3>, 3> c{
            {{t[0], t[1], t[2]}, {t[3], t[4], t[5]}, {t[6], t[7], t[8]}}};
        const size_t first = size_t(std::min_element(c.begin(), c.end()) - c.begin());
        Triangle out;
        for (size_t k = 0; k < 3; ++k)
            for (size_t a = 0; a < 3; ++a) out[3 * k + a] = c[(first + k) % 3][a];
        return out;
    };
    std::vector<Triangle> want;
    for (size_t t = 0; t < mesh.triangleCount(); ++t) {
        Triangle tri;
        for (size_t k = 0; k < 3; ++k)
            for (size_t a = 0; a < 3; ++a)
                tri[3 * k + a] = mesh.positions[3 * mesh.indices[3 * t + k] + a];
        want.push_back(canonical(tri));
    }
    std::sort(want.begin(), want.end());

    const ClusteredMesh clusters = cluster_scene::clusterMesh(mesh, 64, 124, 0);
    EXPECT_GT(clusters.clusters.size(), 3732u / 124);
    EXPECT_LE(clusters.maxClusterVertices, 64u);
    EXPECT_LE(clusters.maxClusterTriangles, 124u);
    std::vector<Triangle> got;
    for (const auto& c : clusters.clusters) {
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            Triangle tri;
            for (size_t k = 0; k < 3; ++k) {
                const uint8_t local = clusters.indices[c.firstIndex + 3 * t + k];
                ASSERT_LT(local, c.vertexCount);
                for (size_t a = 0; a < 3; ++a)
                    tri[3 * k + a] = clusters.positions[3 * (c.firstVertex + local) + a];
            }
            got.push_back(canonical(tri));
        }
    }
    std::sort(got.begin(), got.end());
    EXPECT_EQ(got, want);

    const ClusteredMesh some = cluster_scene::clusterMesh(mesh, 64, 124, 5);
    ASSERT_EQ(some.clusters.size(), 5u);
    EXPECT_EQ(some.clusters[4].triangleCount, clusters.clusters[4].triangleCount);
}

}  // namespace
