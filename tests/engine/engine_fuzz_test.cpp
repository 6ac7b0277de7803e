// SPDX-License-Identifier: Apache-2.0
// Hostile inputs: random counts, addresses, strides and types through every op. Each op
// must end in findings or a valid object: no escaped exception, crash or runaway memory
// (the sanitizer build runs this too).
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

#include <random>

namespace clastrace::engine {
namespace {

using test::Arena;

template <class Info>
void randomize(std::mt19937_64& rng, Arena& arena, uint64_t good_idx, uint64_t good_vtx,
               Info& info) {
    auto addr = [&](uint64_t good) -> uint64_t {
        switch (rng() % 12) {
        case 0: return 0;
        case 1: return rng();
        case 2: return arena.base + arena.size - (rng() % 64);
        default: return good + (rng() % 3 == 0 ? rng() % 16 : 0);
        }
    };
    info.clusterID = rng() % 4 == 0 ? 0xFFFFFFFFu : uint32_t(rng());
    info.clusterFlags = rng() % 4 == 0 ? uint32_t(rng()) : 0;
    info.triangleCount = rng() % 8 ? rng() % 257 : rng() % 512;
    info.vertexCount = rng() % 8 ? rng() % 257 : rng() % 512;
    info.positionTruncateBitCount = rng() % 8 ? rng() % 33 : rng() % 64;
    info.indexType = rng() % 8 ? 1u << (rng() % 3) : rng() % 16;
    info.opacityMicromapIndexType = rng() % 16;
    info.baseGeometryIndexAndGeometryFlags.geometryIndex = rng() % 3 ? rng() % 16 : uint32_t(rng());
    info.baseGeometryIndexAndGeometryFlags.geometryFlags = rng() % 8;
    info.indexBufferStride = uint16_t(rng() % 3 ? rng() % 9 : rng());
    info.vertexBufferStride = uint16_t(rng() % 3 ? rng() % 32 : rng());
    info.geometryIndexAndFlagsBufferStride = uint16_t(rng() % 9);
    info.opacityMicromapIndexBufferStride = uint16_t(rng() % 9);
    info.indexBuffer = addr(good_idx);
    info.vertexBuffer = addr(good_vtx);
    info.geometryIndexAndFlagsBuffer = rng() % 2 ? 0 : addr(good_idx);
    info.opacityMicromapArray = rng() % 2 ? 0 : addr(good_idx);
    info.opacityMicromapIndexBuffer = rng() % 2 ? 0 : addr(good_idx);
}

void expect_valid(const ClusterObject& o, bool is_clas) {
    if (!o.ok) {
        EXPECT_TRUE(o.bytes.empty());
        EXPECT_FALSE(o.findings.empty()) << "a failed op must say why";
        return;
    }
    const HeaderCheck hc = read_object_header(o.bytes);
    ASSERT_TRUE(hc.header) << hc.error;
    EXPECT_EQ(hc.header->object_size, o.bytes.size());
    if (is_clas) {
        const auto view = open_clas(o.bytes);
        ASSERT_TRUE(view);
        (void)trace_closest(*view, Ray{{0.5f, 0.5f, 5}, 0, {0.01f, 0.01f, -1}, 100}, 0);
    }
}

TEST(EngineFuzz, RandomBuildTemplateAndInstantiateInputs) {
    std::mt19937_64 rng(2024);
    Arena arena;
    // Plausible data to point at: random bytes that decode to anything.
    std::vector<uint32_t> junk(4096);
    for (auto& w : junk) w = uint32_t(rng() % 7 == 0 ? rng() : rng() % 300);
    const uint64_t idx = arena.put_vec(junk);
    std::vector<float> fpos(4096);
    for (auto& f : fpos) f = float(int(rng() % 2000) - 1000) * 0.01f;
    const uint64_t vtx = arena.put_vec(fpos);
    int built = 0, failed = 0;
    std::vector<uint64_t> templates;
    for (int trial = 0; trial < 1500; ++trial) {
        auto input = test::default_input(rng() % 10 == 0 ? VkFormat(rng() % 200)
                                                         : VK_FORMAT_R32G32B32_SFLOAT);
        input.maxClusterTriangleCount = uint32_t(rng() % 600);
        input.maxClusterVertexCount = uint32_t(rng() % 600);
        input.minPositionTruncateBitCount = uint32_t(rng() % 40);
        if (trial % 2 == 0) {
            VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
            randomize(rng, arena, idx, vtx, info);
            EngineProperties props;
            if (trial % 4 == 0)
                props.max_triangles_per_cluster = props.max_vertices_per_cluster = 511;
            const auto o = build_triangle_cluster(arena.memory, info, input, props, trial);
            expect_valid(o, true);
            (o.ok ? built : failed)++;
        } else {
            VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV info{};
            randomize(rng, arena, idx, vtx, info);
            info.instantiationBoundingBoxLimit = rng() % 2 ? 0 : vtx + (rng() % 8) * 4;
            const auto o = build_triangle_cluster_template(arena.memory, info, input,
                                                           EngineProperties{}, trial);
            expect_valid(o, false);
            (o.ok ? built : failed)++;
            if (o.ok && templates.size() < 64) {
                std::vector<std::byte> bytes = o.bytes;
                if (rng() % 2) bytes[rng() % bytes.size()] = std::byte(rng());  // corrupt some
                templates.push_back(arena.put(bytes.data(), bytes.size(), 32));
            }
        }
    }
    for (int trial = 0; trial < 600 && !templates.empty(); ++trial) {
        VkClusterAccelerationStructureInstantiateClusterInfoNV ii{};
        ii.clusterIdOffset = uint32_t(rng());
        ii.geometryIndexOffset = uint32_t(rng()) & 0xFFFFFF;
        ii.reserved = rng() % 8 == 0 ? 1 : 0;
        ii.clusterTemplateAddress = rng() % 8 == 0 ? rng() : templates[rng() % templates.size()];
        ii.vertexBuffer = {rng() % 3 ? vtx : (rng() % 2 ? 0 : rng()), rng() % 3 ? 12u : rng() % 64};
        auto input = test::default_input();
        const auto o =
            instantiate_triangle_cluster(arena.memory, ii, input, EngineProperties{}, trial);
        expect_valid(o, true);
        VkClusterAccelerationStructureGetTemplateIndicesInfoNV gi{ii.clusterTemplateAddress};
        const auto g = get_cluster_template_indices(arena.memory, gi, trial);
        if (g.ok) {
            EXPECT_EQ(g.bytes.size() % 12, 0u);
        }
    }
    EXPECT_GT(built, 50);
    EXPECT_GT(failed, 50);
}

}  // namespace
}  // namespace clastrace::engine
