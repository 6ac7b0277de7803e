// SPDX-License-Identifier: Apache-2.0
// The cluster BVH's two partitions (cluster_internal.h, bvh_uses_ssse3): the SSSE3 one, which
// packs 16 triangle indices at a time, and the portable loop must build the same objects byte
// for byte, for every triangle count and for ties, inactive and NaN triangles.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/testsupport/cluster_scene.h"
#include "cluster_internal.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;

namespace {

struct Cluster {
    std::vector<float> positions;
    std::vector<uint32_t> indices;
    uint32_t truncate_bits = 0;
};

// The object of one cluster with the partition `ssse3` names.
std::vector<std::byte> build_with(const Cluster& c, bool ssse3) {
    eng::detail::force_bvh_ssse3(ssse3);
    eng::ClusterBuilder builder(eng::EngineProperties::nvidia_default());
    std::vector<std::byte> object;
    std::vector<eng::Finding> findings;
    EXPECT_TRUE(builder.build_from_arrays(3, c.positions, c.indices, c.truncate_bits, 0, {},
                                          object, findings));
    eng::detail::force_bvh_ssse3(std::nullopt);
    return object;
}

std::vector<Cluster> mesh_clusters(const ts::TriangleMesh& m) {
    std::vector<Cluster> out;
    for (const ts::MeshCluster& mc : ts::build_clusters(m, 64, 124)) {
        Cluster c;
        for (uint32_t v : mc.vertices)
            c.positions.insert(c.positions.end(), m.positions[v].begin(), m.positions[v].end());
        for (const auto& t : mc.triangles) c.indices.insert(c.indices.end(), t.begin(), t.end());
        out.push_back(std::move(c));
    }
    return out;
}

// n triangles over 256 random vertices: coordinates on a coarse lattice when `ties` (many
// equal centroid keys), a few NaN coordinates and out-of-range indices when `odd`.
Cluster random_cluster(std::mt19937& rng, uint32_t n, bool ties, bool odd) {
    Cluster c;
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    for (int v = 0; v < 256; ++v)
        for (int k = 0; k < 3; ++k) {
            const float x = unit(rng);
            c.positions.push_back(ties ? std::floor(x * 3.0f) : x * (k == 1 ? 0.1f : 10.0f));
        }
    std::uniform_int_distribution<uint32_t> vertex(0, 255);
    for (uint32_t t = 0; t < 3 * n; ++t) c.indices.push_back(vertex(rng));
    if (odd) {
        for (size_t i = 7; i < c.positions.size(); i += 97)
            c.positions[i] = std::numeric_limits<float>::quiet_NaN();
        for (size_t i = 11; i < c.indices.size(); i += 53) c.indices[i] = 300;
    }
    return c;
}

TEST(BvhPartition, Ssse3AndPortableBuildTheSameObjects) {
    eng::detail::force_bvh_ssse3(true);
    const bool has_ssse3 = eng::detail::bvh_uses_ssse3();
    eng::detail::force_bvh_ssse3(std::nullopt);
    if (!has_ssse3) GTEST_SKIP() << "no SSSE3 partition on this CPU: the portable loop is the only one";
    std::vector<Cluster> clusters;
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(3, 10.0f), ts::make_terrain(30, 30, 2),
          ts::make_random_soup(2000, 3, 100.0f, 2.0f), ts::make_torus(40, 16, 1.0f, 0.3f)}) {
        std::vector<Cluster> more = mesh_clusters(m);
        clusters.insert(clusters.end(), more.begin(), more.end());
    }
    std::mt19937 rng(22);
    for (uint32_t n = 1; n <= 256; ++n) {
        clusters.push_back(random_cluster(rng, n, false, false));
        clusters.push_back(random_cluster(rng, n, true, n % 3 == 0));
    }
    clusters.back().truncate_bits = 12;
    size_t compared = 0;
    for (const Cluster& c : clusters) {
        const std::vector<std::byte> portable = build_with(c, false);
        ASSERT_EQ(build_with(c, true), portable)
            << "cluster " << compared << ": " << c.indices.size() / 3 << " triangles";
        ++compared;
    }
    EXPECT_GT(compared, 600u);
}

}  // namespace
