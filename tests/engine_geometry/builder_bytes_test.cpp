// SPDX-License-Identifier: Apache-2.0
// The builders' output bytes, pinned: replay compares engine-made objects with captured
// ones byte for byte, so sharing the binned-SAH core must not move a single node. The
// hashes were taken from the builders before issue 18's refactoring.
#include "nv_scene.h"

#include <clastrace/engine/blas.h>
#include <clastrace/engine/cluster_build.h>
#include <clastrace/testsupport/clusters.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <limits>
#include <vector>

namespace clastrace::engine {
namespace {

namespace ts = clastrace::testsupport;

uint64_t fnv1a(const std::byte* p, size_t n, uint64_t h = 0xcbf29ce484222325ull) {
    for (size_t i = 0; i < n; ++i) h = (h ^ uint64_t(p[i])) * 0x100000001b3ull;
    return h;
}

struct SplitMix {
    uint64_t s;
    uint64_t next() {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    float unit() { return float(next() >> 40) / float(1 << 24) * 2.0f - 1.0f; }  // [-1, 1)
};

// Box sets that reach every branch of a binned SAH builder: spread, clustered, coincident
// centroids, exponentially spaced (deep chains), huge and empty boxes, and sizes above the
// parallel thresholds.
std::vector<std::vector<float>> box_sets() {
    std::vector<std::vector<float>> sets;  // 6 floats per box: min xyz, max xyz
    SplitMix rng{18};
    auto random_set = [&](size_t n, float extent, float size) {
        std::vector<float> s;
        for (size_t i = 0; i < n; ++i) {
            float c[3], h[3];
            for (int a = 0; a < 3; ++a)
                c[a] = rng.unit() * extent, h[a] = (rng.unit() + 1.0f) * size;
            s.insert(s.end(), {c[0] - h[0], c[1] - h[1], c[2] - h[2], c[0] + h[0], c[1] + h[1],
                               c[2] + h[2]});
        }
        return s;
    };
    sets.push_back(random_set(7, 10, 1));
    sets.push_back(random_set(300, 100, 2));
    sets.push_back(random_set(20000, 1000, 3));
    std::vector<float> coincident;
    for (int i = 0; i < 40; ++i) coincident.insert(coincident.end(), {-1, -1, -1, 1, 1, 1});
    sets.push_back(coincident);
    std::vector<float> chain;
    for (int i = 0; i < 120; ++i) {
        const float x = std::ldexp(1.0f, i - 60);
        chain.insert(chain.end(), {x, 0, 0, x * 1.5f, 1, 1});
    }
    sets.push_back(chain);
    std::vector<float> extremes = random_set(50, 1, 1);
    const float big = std::numeric_limits<float>::max();
    extremes.insert(extremes.end(), {-big, -big, -big, big, big, big});
    extremes.insert(extremes.end(), {1, 1, 1, 0, 0, 0});  // empty: left out
    extremes.insert(extremes.end(), {big / 2, 0, 0, big, 1, 1});
    sets.push_back(extremes);
    return sets;
}

TEST(BuilderBytes, ClusterBottomLevelIsUnchanged) {
    std::vector<uint64_t> hashes;
    for (const std::vector<float>& set : box_sets()) {
        std::vector<ClusterBox> boxes;
        for (size_t i = 0; i < set.size() / 6; ++i) {
            ClusterBox b{};
            std::memcpy(b.bounds_min, &set[6 * i], 12);
            std::memcpy(b.bounds_max, &set[6 * i + 3], 12);
            b.clas_address = 0x1000 * (i + 1);
            b.reference_index = uint32_t(i);
            b.cluster_id = uint32_t(i);
            boxes.push_back(b);
        }
        const std::vector<std::byte> bytes = build_bottom_level(boxes, uint32_t(boxes.size()));
        hashes.push_back(fnv1a(bytes.data(), bytes.size()));
    }
    const std::vector<uint64_t> expected = {0xc99c0cc937580a26ull, 0xc786a9dce19c5c99ull,
                                            0xdea85221d31dd556ull, 0xbd987114ce2c13b2ull,
                                            0x2848535972659fd4ull, 0x1a52d61e7715331bull};
    EXPECT_EQ(hashes, expected);
}

// The NV bottom level over AABBs (the boxes as given) and a top level with one instance per
// box, for both build qualities: the binned SAH tree and the fast-build Morton tree. The SAH
// hashes were retaken for issue 22's faster SAH builder (exact sweep under 17 items, Embree's
// bin counts above), and again when SAH bottom levels stopped splitting ranges that fit one
// leaf and took bins and float costs all the way down (the top levels did not move): replay compares cluster outputs byte for byte, never NV
// or KHR objects, so only these pins moved; the Morton ones did not.
TEST(BuilderBytes, NvObjectsAreUnchanged) {
    std::vector<uint64_t> hashes;
    for (VkBuildAccelerationStructureFlagsNV flags :
         {VkBuildAccelerationStructureFlagsNV(0),
          VkBuildAccelerationStructureFlagsNV(
              VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        for (const std::vector<float>& set : box_sets()) {
            nvtest::BlasSpec blas;
            blas.aabbs = true;
            nvtest::GeometrySpec g;
            for (size_t i = 0; i < set.size() / 6; ++i)
                g.boxes.push_back({set[6 * i], set[6 * i + 1], set[6 * i + 2], set[6 * i + 3],
                                   set[6 * i + 4], set[6 * i + 5]});
            blas.geometries.push_back(g);
            std::vector<nvtest::InstanceSpec> instances(std::min<size_t>(set.size() / 6, 2000));
            for (size_t i = 0; i < instances.size(); ++i) {
                // Translate each instance to its box's low corner where that is finite and modest.
                for (int a = 0; a < 3; ++a) {
                    const float x = set[6 * i + a];
                    instances[i].transform[4 * a + 3] =
                        std::isfinite(x) && std::fabs(x) < 1e6f ? x : 0.0f;
                }
            }
            auto scene = nvtest::build_scene({blas}, instances, flags);
            for (const NvObjectBinding* o : {&scene->blas[0], &scene->tlas}) {
                auto bytes = scene->world.memory.read_bytes(o->address, o->size, {"test", -1});
                hashes.push_back(fnv1a(bytes.data(), bytes.size()));
            }
        }
    }
    // Per box set: SAH bottom level, SAH top level; then the same with PREFER_FAST_BUILD.
    const std::vector<uint64_t> expected = {
        0x82c025878887613full, 0xc11f296328bdc6b5ull, 0x760006f8453e6ed4ull, 0x7a31fdc4180526f7ull,
        0xa9a06375fb2f9d1cull, 0x0869f6a6a888734cull, 0xb5f3d47942bc4194ull, 0x2366bd1808147471ull,
        0x9c90dadeff6b53b4ull, 0x30787de7fa2ff6f3ull, 0xb3a52330e64078f7ull, 0x8cd531307dc60bf8ull,
        0x2be801b37ea3a4ceull, 0x66db919b141c0cadull, 0xe93bf70a3e797064ull, 0x1ab892b26f52541full,
        0x971fd42a7cc1ca78ull, 0xeed00887dcbe5984ull, 0x3a50a889b61a817cull, 0x2390390b6db21099ull,
        0x87e04cc022020571ull, 0xe09ad3ba4eb314cbull, 0x1c9d12ac16c23d4full, 0x1e3078beb39228c0ull};
    EXPECT_EQ(hashes, expected);
}

// Triangle bottom levels through the whole NV build (gather, boxes, tree, record write), both
// builders, on the bench's meshes and on triangles the gather treats apart (NaN vertices,
// 16-bit indices, a transform). Taken before issue 22's build-speed work, which must not move
// a byte; the SAH ones retaken when bottom levels stopped splitting ranges that fit one leaf
// and took bins and float costs all the way down (issue 22 round 4).
TEST(BuilderBytes, NvTriangleObjectsAreUnchanged) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    ts::TriangleMesh holes = ts::make_icosphere(3, 2.0f);
    for (size_t i = 0; i < holes.positions.size(); i += 7) holes.positions[i][i % 3] = nan;
    std::vector<nvtest::BlasSpec> blases;
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(4, 1.0f), ts::make_terrain(60, 60, 1),
          ts::make_random_soup(5000, 5, 1.0f, 0.05f), ts::make_torus(60, 30, 1.0f, 0.3f), holes}) {
        nvtest::BlasSpec spec;
        spec.geometries.push_back({m, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
        blases.push_back(spec);
    }
    std::vector<uint64_t> hashes;
    for (VkBuildAccelerationStructureFlagsNV flags :
         {VkBuildAccelerationStructureFlagsNV(0),
          VkBuildAccelerationStructureFlagsNV(
              VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        for (size_t k = 0; k <= blases.size(); ++k) {
            nvtest::NvWorld w;
            // The last case: the NaN mesh again, through 16-bit indices and a transform.
            const bool narrow = k == blases.size();
            NvObjectInfo info = w.blas_info(blases[narrow ? k - 1 : k], flags);
            if (narrow) {
                std::vector<uint16_t> indices;
                for (const auto& t : holes.triangles)
                    for (uint32_t v : t) indices.push_back(uint16_t(v));
                const float transform[12] = {0, 2, 0, 1, -1, 0, 0, 2, 0, 0, 0.5f, 3};
                NvTriangles& t = info.geometries[0].triangles;
                t.index_address = w.put(indices.data(), indices.size() * 2, "indices16");
                t.index_type = VK_INDEX_TYPE_UINT16;
                t.transform_address = w.put(transform, sizeof transform, "transform");
            }
            NvObjectBinding dst = w.make_object(info, "blas");
            const ExecutionRecord r = w.build(info, dst);
            ASSERT_TRUE(r.ops[0].executed);
            auto bytes = w.memory.read_bytes(dst.address, dst.size, {"test", -1});
            hashes.push_back(fnv1a(bytes.data(), bytes.size()));
        }
    }
    // Per mesh (icosphere, terrain, soup, torus, NaN holes, NaN holes narrow): SAH, then the
    // same with PREFER_FAST_BUILD (Morton).
    const std::vector<uint64_t> expected = {0xaa3d44af0513dafdull, 0x04262d072675e76full,
                                            0xfc12e204b1dbd511ull, 0xf39617396253bd2aull,
                                            0xebfcaba37773cd41ull, 0x40cc3435e7145cc2ull,
                                            0x76e0042ecabae0ceull, 0x4d84bfc8ed62bcbaull,
                                            0xaf9c3cef6f56be9eull, 0x24a31880513378dfull,
                                            0x5446bc66cb60efb9ull, 0x9c876e9c8a469486ull};
    EXPECT_EQ(hashes, expected);
}


// CLAS objects (the per-cluster BVH and encoding) over meshoptimizer clusters of the bench's
// meshes and over clusters the build treats apart: 256 triangles, odd counts, NaN vertices,
// coincident and flat triangles, truncated positions. Replay compares cluster outputs byte for
// byte, so issue 22's cluster build-speed work must not move a byte: taken before it.
TEST(BuilderBytes, ClusterObjectsAreUnchanged) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    ClusterBuilder builder(EngineProperties::nvidia_default());
    std::vector<std::byte> object;
    std::vector<Finding> findings;
    auto add = [&](uint64_t& h, std::span<const float> positions, std::span<const uint32_t> indices,
                   uint32_t truncate_bits) {
        ASSERT_TRUE(builder.build_from_arrays(7, positions, indices, truncate_bits, 0, {}, object,
                                              findings));
        h = fnv1a(object.data(), object.size(), h);
    };
    std::vector<uint64_t> hashes;
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(4, 10.0f), ts::make_terrain(40, 40, 2),
          ts::make_random_soup(3000, 3, 100.0f, 2.0f), ts::make_torus(50, 20, 1.0f, 0.3f)}) {
        uint64_t h = 0xcbf29ce484222325ull;
        for (const ts::MeshCluster& c : ts::build_clusters(m, 64, 124)) {
            std::vector<float> positions;
            for (uint32_t v : c.vertices)
                positions.insert(positions.end(), m.positions[v].begin(), m.positions[v].end());
            std::vector<uint32_t> indices;
            for (const auto& t : c.triangles) indices.insert(indices.end(), t.begin(), t.end());
            for (uint32_t bits : {0u, 12u}) add(h, positions, indices, bits);
        }
        hashes.push_back(h);
    }
    // Hand-made clusters: every triangle count 1..256 over a 16 x 16 grid of vertices (odd
    // counts, the largest cluster), then NaN vertices, coincident and flat triangles.
    SplitMix rng{22};
    std::vector<float> grid;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) grid.insert(grid.end(), {float(x), rng.unit(), float(y)});
    std::vector<uint32_t> grid_indices;
    for (uint32_t t = 0; t < 256; ++t) {
        const uint32_t v = (t * 37) % 240;
        grid_indices.insert(grid_indices.end(), {v, v + 1, v + 16});
    }
    uint64_t h = 0xcbf29ce484222325ull;
    for (uint32_t n = 1; n <= 256; ++n) add(h, grid, std::span(grid_indices).first(3 * n), 0);
    hashes.push_back(h);
    std::vector<float> odd = grid;
    for (size_t i = 0; i < odd.size(); i += 29) odd[i] = nan;
    for (size_t i = 5; i < 60; i += 3) odd[i] = odd[2];  // coincident coordinates
    std::vector<uint32_t> flat = grid_indices;
    for (size_t t = 0; t < flat.size() / 3; t += 5) flat[3 * t + 2] = flat[3 * t];
    h = 0xcbf29ce484222325ull;
    for (uint32_t n : {3u, 17u, 100u, 255u, 256u}) {
        add(h, odd, std::span(grid_indices).first(3 * n), 0);
        add(h, grid, std::span(flat).first(3 * n), 20);
    }
    hashes.push_back(h);
    // Per mesh (icosphere, terrain, soup, torus), then the grid clusters, then the odd ones.
    const std::vector<uint64_t> expected = {0x1a44b4c6ed607a60ull, 0x1223e3d4e803e94dull,
                                            0x33c5d2c461cc48c1ull, 0x942f210a74a31ef0ull,
                                            0xe18cdcb00904623cull, 0xbcf3e08d64f87513ull};
    EXPECT_EQ(hashes, expected);
}

}  // namespace
}  // namespace clastrace::engine
