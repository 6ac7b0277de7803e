// SPDX-License-Identifier: Apache-2.0
// Build-triangle-cluster: inputs of every shape, every per-info rule (one failing and
// one passing input each), sizes, determinism and memory faults.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <functional>
#include <limits>
#include <set>

namespace clastrace::engine {
namespace {

using test::Arena;
using BuildInfo = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
using Input = VkClusterAccelerationStructureTriangleClusterInputNV;

// Decoded triangles in the app's order, for comparing objects built from different encodings.
std::vector<std::array<float, 9>> triangles_of(const std::vector<std::byte>& bytes) {
    const auto h = read_object_header(bytes).header;
    EXPECT_TRUE(h);
    std::vector<std::array<float, 9>> out(h ? h->triangle_count : 0);
    for (uint32_t i = 0; h && i < h->triangle_count; ++i) {
        const DecodedTriangle t = decode_triangle(bytes, *h, i);
        for (int v = 0; v < 3; ++v)
            for (int k = 0; k < 3; ++k) out[t.original_index][3 * v + k] = t.v[v][k];
    }
    return out;
}

TEST(ClusterBuild, GridBuildsAndTraces) {
    Arena arena;
    const test::Mesh m = test::grid(8);
    auto info = test::cluster_info(arena, m);
    const ClusterObject o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_TRUE(o.findings.empty()) << o.findings[0].message;
    ASSERT_EQ(object_size_from_header(o.bytes), o.bytes.size());
    Ray ray{{3.5f, 2.5f, 5.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, 100.0f};
    const Hit h = trace_closest(o.bytes, ray, 0);
    ASSERT_TRUE(h.hit);
    EXPECT_NEAR(h.t, 5.0f, 0.25f);
    EXPECT_EQ(h.cluster_id, 7u);
}

TEST(ClusterBuild, EveryIndexTypeAndStrideGivesTheSameTriangles) {
    const test::Mesh m = test::grid(6);
    Arena arena;
    const auto reference = build_triangle_cluster(arena.memory, test::cluster_info(arena, m),
                                                  test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(reference.ok);
    const auto expected = triangles_of(reference.bytes);
    for (uint32_t size : {1u, 2u, 4u}) {
        for (uint32_t stride : {0u, size, 2 * size, 8u}) {
            if (stride % size) continue;
            const uint32_t step = stride ? stride : size;
            std::vector<uint8_t> ib(m.indices.size() * step, 0xAB);
            for (size_t i = 0; i < m.indices.size(); ++i)
                std::memcpy(ib.data() + i * step, &m.indices[i], size);  // little-endian low bytes
            BuildInfo info = test::cluster_info(arena, m);
            info.indexType = size;
            info.indexBufferStride = uint16_t(stride);
            info.indexBuffer = arena.put_vec(ib, 1);  // unaligned on purpose
            const auto o = build_triangle_cluster(arena.memory, info, test::default_input(),
                                                  EngineProperties{}, 0);
            ASSERT_TRUE(o.ok) << size << " " << stride;
            EXPECT_TRUE(o.findings.empty());
            EXPECT_EQ(triangles_of(o.bytes), expected)
                << "index size " << size << " stride " << stride;
            EXPECT_EQ(o.bytes, reference.bytes) << "same triangles must give the same bytes";
        }
    }
}

TEST(ClusterBuild, VertexStrideWithPadding) {
    const test::Mesh m = test::grid(5);
    Arena arena;
    const auto reference = build_triangle_cluster(arena.memory, test::cluster_info(arena, m),
                                                  test::default_input(), EngineProperties{}, 0);
    std::vector<float> padded;
    for (size_t v = 0; v < m.positions.size() / 3; ++v)
        padded.insert(padded.end(),
                      {m.positions[3 * v], m.positions[3 * v + 1], m.positions[3 * v + 2], -7.0f});
    BuildInfo info = test::cluster_info(arena, m);
    info.vertexBuffer = arena.put_vec(padded);
    info.vertexBufferStride = 16;
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_EQ(o.bytes, reference.bytes);
    info.vertexBufferStride = 0;  // packed: reads the padded floats as positions
    const auto wrong =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(wrong.ok);
    EXPECT_NE(wrong.bytes, reference.bytes);
}

TEST(ClusterBuild, PerTriangleGeometryDataOnlyWhenItVaries) {
    const test::Mesh m = test::grid(4);  // 32 triangles
    Arena arena;
    BuildInfo info = test::cluster_info(arena, m);
    info.baseGeometryIndexAndGeometryFlags.geometryIndex = 10;
    info.baseGeometryIndexAndGeometryFlags.geometryFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
    const auto uniform =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(uniform.ok);
    const auto hu = read_object_header(uniform.bytes).header;
    EXPECT_FALSE(hu->header_flags & kHasTriangleData);

    std::vector<VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV> g(32);
    for (uint32_t t = 0; t < 32; ++t) g[t].geometryIndex = t % 3;
    info.geometryIndexAndFlagsBuffer = arena.put_vec(g);
    const auto varying =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(varying.ok);
    EXPECT_TRUE(varying.findings.empty()) << varying.findings[0].message;
    const auto hv = read_object_header(varying.bytes).header;
    EXPECT_TRUE(hv->header_flags & kHasTriangleData);
    EXPECT_EQ(varying.bytes.size(), uniform.bytes.size() + 4 * 32);
    EXPECT_EQ(hv->max_geometry_index, 12u);
    for (uint32_t i = 0; i < 32; ++i) {
        const DecodedTriangle t = decode_triangle(varying.bytes, *hv, i);
        EXPECT_EQ(t.geometry_index_and_flags & 0xFFFFFF, 10 + t.original_index % 3);
        EXPECT_EQ(t.geometry_index_and_flags >> 29,
                  uint32_t(VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV));
    }
    // Same per-triangle value everywhere: no section either.
    for (auto& e : g) e.geometryIndex = 2;
    info.geometryIndexAndFlagsBuffer = arena.put_vec(g);
    const auto same =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    EXPECT_EQ(same.bytes.size(), uniform.bytes.size());
    EXPECT_EQ(read_object_header(same.bytes).header->base_geometry_index_and_flags & 0xFFFFFF, 12u);
}

TEST(ClusterBuild, OpacityMicromapRecordedOnlyWhenUsed) {
    const test::Mesh m = test::grid(2);  // 8 triangles
    Arena arena;
    BuildInfo info = test::cluster_info(arena, m);
    const auto plain =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    EXPECT_FALSE(read_object_header(plain.bytes).header->header_flags & kHasOpacityMicromap);
    std::vector<uint16_t> omm = {0, 1, 2, 3, 0xFFFB, 5, 6, 7};
    info.opacityMicromapArray = arena.alloc(64);
    info.opacityMicromapIndexBuffer = arena.put_vec(omm);
    info.opacityMicromapIndexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
    const auto with =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(with.ok);
    const auto h = read_object_header(with.bytes).header;
    ASSERT_TRUE(h->header_flags & kHasOpacityMicromap);
    OpacityMicromapSection sec;
    std::memcpy(&sec, with.bytes.data() + h->omm_offset, sizeof sec);
    EXPECT_EQ(sec.opacity_micromap_array, info.opacityMicromapArray);
    EXPECT_EQ(sec.index_type, 2u);
    std::vector<int32_t> stored(8);
    std::memcpy(stored.data(), with.bytes.data() + h->omm_offset + sizeof sec, 32);
    std::vector<int32_t> expected(8);
    for (uint32_t i = 0; i < 8; ++i)
        expected[decode_triangle(with.bytes, *h, i).original_index] = stored[i];
    EXPECT_EQ(expected, (std::vector<int32_t>{0, 1, 2, 3, -5, 5, 6, 7}));
}

// ---- Per-info valid usage: each rule gets a failing input; the baseline passes all. ----

struct RuleCase {
    const char* rule;
    std::function<void(Arena&, BuildInfo&, Input&, EngineProperties&)> mutate;
    std::set<std::string> also = {};  // rules the same mutation necessarily breaks too
};

TEST(ClusterBuildRules, BaselinePassesEveryRule) {
    Arena arena;
    const test::Mesh m = test::grid(4);
    BuildInfo info = test::cluster_info(arena, m);
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_TRUE(o.findings.empty()) << o.findings[0].rule;
}

TEST(ClusterBuildRules, EachRuleFailsAndPasses) {
    const std::vector<RuleCase> cases = {
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10488",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.clusterID = 0xFFFFFFFFu; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-triangleCount-10489",
         [](Arena&, BuildInfo&, Input&, EngineProperties& p) { p.max_triangles_per_cluster = 31; },
         {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterTriangleCount-"
          "10440"}},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexCount-10490",
         [](Arena&, BuildInfo&, Input&, EngineProperties& p) { p.max_vertices_per_cluster = 24; },
         {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterVertexCount-10441"}},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-10491",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.indexType = 6; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-opacityMicromapIndexType-"
         "10492",
         [](Arena& a, BuildInfo& i, Input&, EngineProperties&) {
             i.opacityMicromapArray = a.alloc(64);
             i.opacityMicromapIndexType = 3;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-"
         "10493",
         [](Arena&, BuildInfo& i, Input& in, EngineProperties&) {
             in.minPositionTruncateBitCount = 8;
             i.positionTruncateBitCount = 7;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-"
         "10493",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.positionTruncateBitCount = 33; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexBufferStride-10494",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.indexBufferStride = 6; },
         {kRuleIndexOutOfRange}},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexBufferStride-10495",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.vertexBufferStride = 14; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-baseGeometryIndex-10496",
         [](Arena&, BuildInfo& i, Input& in, EngineProperties& p) {
             p.max_cluster_geometry_index = 100;
             in.maxGeometryIndexValue = 1000;
             i.baseGeometryIndexAndGeometryFlags.geometryIndex = 100;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterFlags-parameter",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.clusterFlags = 0x10; }},
        {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439",
         [](Arena&, BuildInfo&, Input& in, EngineProperties&) {
             in.vertexFormat = VK_FORMAT_R8_UINT;
         }},
        {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterTriangleCount-10440",
         [](Arena&, BuildInfo&, Input& in, EngineProperties&) {
             in.maxClusterTriangleCount = 300;
         }},
        {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterVertexCount-10441",
         [](Arena&, BuildInfo&, Input& in, EngineProperties&) { in.maxClusterVertexCount = 257; }},
        {"VUID-VkClusterAccelerationStructureTriangleClusterInputNV-minPositionTruncateBitCount-"
         "10442",
         [](Arena&, BuildInfo&, Input& in, EngineProperties&) {
             in.minPositionTruncateBitCount = 33;
         },
         {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-"
          "10493"}},
        {"VUID-VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV-reserved-10487",
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) {
             i.baseGeometryIndexAndGeometryFlags.reserved = 1;
         }},
        {"VUID-VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV-reserved-10487",
         [](Arena& a, BuildInfo& i, Input&, EngineProperties&) {
             std::vector<uint32_t> g(32, 0);
             g[31] = 0x01000000u;
             i.geometryIndexAndFlagsBuffer = a.put_vec(g);
         }},
        {kRuleCountAboveInput,
         [](Arena&, BuildInfo&, Input& in, EngineProperties&) { in.maxClusterTriangleCount = 10; }},
        {kRuleGeometryIndexAboveInput,
         [](Arena&, BuildInfo& i, Input& in, EngineProperties&) {
             in.maxGeometryIndexValue = 4;
             i.baseGeometryIndexAndGeometryFlags.geometryIndex = 5;
         }},
        {kRuleUniqueGeometryCount,
         [](Arena& a, BuildInfo& i, Input& in, EngineProperties&) {
             in.maxClusterUniqueGeometryCount = 2;
             std::vector<uint32_t> g(32);
             for (uint32_t t = 0; t < 32; ++t) g[t] = t % 3;
             i.geometryIndexAndFlagsBuffer = a.put_vec(g);
         }},
        {kRuleIndexOutOfRange,
         [](Arena& a, BuildInfo& i, Input&, EngineProperties&) {
             std::vector<uint32_t> idx(96, 0);
             for (uint32_t k = 0; k < 96; ++k) idx[k] = k % 25;
             idx[5] = 25;  // == vertexCount
             i.indexBuffer = a.put_vec(idx);
         }},
        {kRuleMemoryFault,
         [](Arena&, BuildInfo& i, Input&, EngineProperties&) { i.vertexBuffer = 0x10; }},
        {kRuleMemoryFault, [](Arena& a, BuildInfo& i, Input&,
                              EngineProperties&) { i.indexBuffer = a.base + a.size - 8; }},
    };
    for (const RuleCase& c : cases) {
        Arena arena;
        const test::Mesh m = test::grid(4);  // 25 vertices, 32 triangles
        BuildInfo info = test::cluster_info(arena, m);
        Input input = test::default_input();
        EngineProperties props;
        c.mutate(arena, info, input, props);
        const auto o = build_triangle_cluster(arena.memory, info, input, props, 42);
        ASSERT_TRUE(has_rule(o.findings, c.rule)) << "expected " << c.rule;
        for (const Finding& f : o.findings) {
            EXPECT_EQ(f.op_index, 42);
            EXPECT_NE(f.message.find("op 42"), std::string::npos) << f.message;
        }
        // Findings carry exactly the rules provoked (no collateral noise), except that
        // unsupported formats also stop the build.
        for (const Finding& f : o.findings)
            EXPECT_TRUE(f.rule == c.rule || c.also.count(f.rule))
                << c.rule << " came with " << f.rule;
    }
}

TEST(ClusterBuildRules, IndexOutOfRangeMakesTheTriangleInactiveNotACrash) {
    Arena arena;
    const std::vector<float> pos = {0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 0};
    const std::vector<uint32_t> idx = {0, 1, 2, 0, 1, 0xFFFFFFFFu, 1, 3, 2};
    BuildInfo info{};
    info.triangleCount = 3;
    info.vertexCount = 4;
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    info.indexBuffer = arena.put_vec(idx);
    info.vertexBuffer = arena.put_vec(pos);
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    ASSERT_TRUE(has_rule(o.findings, kRuleIndexOutOfRange));
    EXPECT_NE(o.findings[0].message.find("4294967295"), std::string::npos) << o.findings[0].message;
    // Triangle 0 and 2 still hit; triangle 1 is gone.
    Ray r0{{0.2f, 0.2f, 1}, 0, {0, 0, -1}, 10};
    EXPECT_EQ(trace_closest(o.bytes, r0, 0).triangle_index, 0u);
    Ray r2{{1.5f, 1.5f, 1}, 0, {0, 0, -1}, 10};
    EXPECT_EQ(trace_closest(o.bytes, r2, 0).triangle_index, 2u);
}

// Packed 8-bit indices are widened 16 at a time, the last few one by one: an out-of-range
// index at any position, in a block or in the tail, gives the same object and finding as the
// same index read as 32 bits.
TEST(ClusterBuildRules, PackedByteIndexOutOfRangeAtAnyPosition) {
    const test::Mesh m = test::grid(5);  // 36 vertices, 150 indices: 9 blocks of 16 and 6 more
    const uint32_t n_vertices = uint32_t(m.positions.size() / 3);
    Arena arena;
    for (size_t p = 0; p < m.indices.size(); ++p) {
        SCOPED_TRACE("out-of-range index at " + std::to_string(p));
        test::Mesh bad = m;
        bad.indices[p] = p % 2 ? 255u : n_vertices;
        const BuildInfo wide = test::cluster_info(arena, bad);
        const auto expected = build_triangle_cluster(arena.memory, wide, test::default_input(),
                                                     EngineProperties{}, 0);
        BuildInfo packed = wide;
        packed.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        packed.indexBufferStride = 0;
        packed.indexBuffer =
            arena.put_vec(std::vector<uint8_t>(bad.indices.begin(), bad.indices.end()), 1);
        const auto o = build_triangle_cluster(arena.memory, packed, test::default_input(),
                                              EngineProperties{}, 0);
        ASSERT_TRUE(o.ok);
        ASSERT_TRUE(has_rule(o.findings, kRuleIndexOutOfRange));
        EXPECT_NE(o.findings[0].message.find("first at index " + std::to_string(p) + " "),
                  std::string::npos)
            << o.findings[0].message;
        EXPECT_EQ(o.bytes, expected.bytes);
    }
}

TEST(ClusterBuildRules, CountsBeyondTheFormatFailCleanly) {
    Arena arena;
    const test::Mesh m = test::grid(4);
    BuildInfo info = test::cluster_info(arena, m);
    info.triangleCount = 300;
    EngineProperties p;
    p.max_triangles_per_cluster = 511;
    const auto o = build_triangle_cluster(arena.memory, info, test::default_input(), p, 0);
    EXPECT_FALSE(o.ok);
    EXPECT_TRUE(o.bytes.empty());
    EXPECT_TRUE(has_rule(o.findings, kRuleBeyondEngineFormat));
}

TEST(ClusterBuild, MaximumSizeCluster) {
    // 256 vertices and 256 triangles: the format's limits.
    std::vector<float> pos;
    std::vector<uint32_t> idx;
    for (uint32_t v = 0; v < 256; ++v)
        pos.insert(pos.end(), {float(v % 16), float(v / 16), float((v * 7) % 5) * 0.1f});
    for (uint32_t t = 0; t < 256; ++t) idx.insert(idx.end(), {t, (t + 1) % 256, (t + 17) % 256});
    Arena arena;
    BuildInfo info{};
    info.triangleCount = 256;
    info.vertexCount = 256;
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    info.indexBuffer = arena.put_vec(idx);
    info.vertexBuffer = arena.put_vec(pos);
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_TRUE(o.findings.empty());
    const auto h = read_object_header(o.bytes).header;
    ASSERT_TRUE(h);
    EXPECT_EQ(h->triangle_count, 256);
    EXPECT_EQ(h->vertex_count, 256);
    std::set<uint32_t> seen;
    for (uint32_t i = 0; i < 256; ++i) seen.insert(decode_triangle(o.bytes, *h, i).original_index);
    EXPECT_EQ(seen.size(), 256u);
    EXPECT_LE(o.bytes.size(),
              max_cluster_object_size(test::default_input(), EngineProperties{}, false));
}

TEST(ClusterBuild, ReportedSizeIsBytesWrittenAndWithinTheMaximum) {
    std::mt19937 rng(3);
    ClusterBuilder b;
    std::vector<std::byte> out;
    std::vector<Finding> f;
    for (int trial = 0; trial < 50; ++trial) {
        const uint32_t n = 1 + rng() % 11;
        const test::Mesh m = test::grid(n, 1.0f, trial);
        if (m.indices.size() / 3 > 256 || m.positions.size() / 3 > 256) continue;
        const uint32_t bits = rng() % 33;
        ASSERT_TRUE(b.build_from_arrays(trial, m.positions, m.indices, bits, 0, {}, out, f));
        const auto h = read_object_header(out).header;
        ASSERT_TRUE(h);
        EXPECT_EQ(h->object_size, out.size());
        EXPECT_EQ(out.size() % 4, 0u);
        Input in = test::default_input();
        in.minPositionTruncateBitCount = bits;
        EXPECT_LE(out.size(), max_cluster_object_size(in, EngineProperties{}, false));
        // Sections are 4-byte aligned inside the object (the object itself sits at
        // clusterByteAlignment in device memory).
        EXPECT_EQ(h->indices_offset % 4, 0u);
        EXPECT_EQ(h->positions_offset % 4, 0u);
        EXPECT_EQ(h->nodes_offset % 4, 0u);
    }
}

TEST(ClusterBuild, Deterministic) {
    const test::Mesh small = test::grid(3, 1.0f, 9), big = test::grid(11, 1.0f, 10);
    ClusterBuilder fresh, reused;
    std::vector<std::byte> a, b, scratch;
    std::vector<Finding> f;
    ASSERT_TRUE(fresh.build_from_arrays(5, small.positions, small.indices, 4, 0, {}, a, f));
    ASSERT_TRUE(reused.build_from_arrays(6, big.positions, big.indices, 0, 0, {}, b,
                                         f));  // dirty scratch and buffer
    ASSERT_TRUE(reused.build_from_arrays(5, small.positions, small.indices, 4, 0, {}, b, f));
    EXPECT_EQ(a, b);
    Arena arena;
    auto info = test::cluster_info(arena, small);
    const auto o1 =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    const auto o2 =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    EXPECT_EQ(o1.bytes, o2.bytes);
}

}  // namespace
}  // namespace clastrace::engine

namespace clastrace::engine {
namespace {

// Streamed objects (laid out in scratch, written once with non-temporal stores) are the
// cached ones byte for byte: into a vector of another size, into one of the same size left
// with stale bytes (a rebuild writes it without zero-filling first, so every padding byte must
// be written), and a failed build leaves the vector empty.
TEST(ClusterBuild, StreamedObjectsEqualCachedOnes) {
    Arena arena;
    ClusterBuilder cached, streamed;
    streamed.set_object_stores(ObjectStores::kStreaming);
    std::vector<std::byte> expected, out;
    std::vector<Finding> f;
    for (const auto& [n, truncate] :
         {std::pair{11u, 0u}, {3u, 9u}, {7u, 0u}, {1u, 5u}, {11u, 3u}}) {
        auto info = test::cluster_info(arena, test::grid(n, 1.0f, n));
        info.positionTruncateBitCount = truncate;
        ASSERT_TRUE(cached.build_triangle_cluster(arena.memory, info, test::default_input(), 0,
                                                  expected, f));
        ASSERT_TRUE(
            streamed.build_triangle_cluster(arena.memory, info, test::default_input(), 0, out, f));
        EXPECT_EQ(out, expected) << "grid " << n << ", other size before";
        std::fill(out.begin(), out.end(), std::byte{0xAB});
        ASSERT_TRUE(
            streamed.build_triangle_cluster(arena.memory, info, test::default_input(), 0, out, f));
        EXPECT_EQ(out, expected) << "grid " << n << ", same size, stale bytes";
    }
    EXPECT_TRUE(f.empty());
    auto bad = test::cluster_info(arena, test::grid(2));
    bad.vertexBuffer = 0xABC000;
    EXPECT_FALSE(
        streamed.build_triangle_cluster(arena.memory, bad, test::default_input(), 0, out, f));
    EXPECT_TRUE(out.empty());
}

// A cluster whose vertices are all finite takes the common gather (vertices widened once, no
// NaN tests); one vertex no triangle uses set to infinity sends the same triangles through the
// exact gather. Both must give the same bounds, BVH, stored indices and triangle order, from
// 8 to 242 triangles.
TEST(ClusterBuild, CommonGatherEqualsTheExactOne) {
    ClusterBuilder builder;
    std::vector<std::byte> common, exact;
    std::vector<Finding> f;
    auto section = [](const std::vector<std::byte>& o, uint32_t offset, size_t size) {
        return std::vector<std::byte>(o.begin() + offset, o.begin() + offset + size);
    };
    for (const auto& [n, seed] : {std::pair{2u, 3u}, {5u, 4u}, {7u, 5u}, {9u, 6u}, {11u, 7u}}) {
        const test::Mesh m = test::grid(n, 1.5f, seed, 2.0f);
        std::vector<float> with_infinity = m.positions;
        with_infinity.insert(with_infinity.end(), {std::numeric_limits<float>::infinity(), 0, 0});
        ASSERT_TRUE(builder.build_from_arrays(1, m.positions, m.indices, 0, 0, {}, common, f));
        ASSERT_TRUE(builder.build_from_arrays(1, with_infinity, m.indices, 0, 0, {}, exact, f));
        const auto a = read_object_header(common).header, b = read_object_header(exact).header;
        ASSERT_TRUE(a && b);
        const uint32_t triangles = a->triangle_count;
        EXPECT_EQ(std::memcmp(a->bounds_min, b->bounds_min, 24), 0) << "grid " << n;
        ASSERT_EQ(a->node_count, b->node_count) << "grid " << n;
        EXPECT_EQ(a->header_flags, b->header_flags) << "grid " << n;
        EXPECT_EQ(section(common, a->nodes_offset, 8 * a->node_count),
                  section(exact, b->nodes_offset, 8 * b->node_count))
            << "grid " << n;
        EXPECT_EQ(section(common, a->indices_offset, 3 * triangles),
                  section(exact, b->indices_offset, 3 * triangles))
            << "grid " << n;
        if (a->header_flags & kHasTriangleOrder) {
            EXPECT_EQ(section(common, a->triangle_order_offset, triangles),
                      section(exact, b->triangle_order_offset, triangles))
                << "grid " << n;
        }
    }
    EXPECT_TRUE(f.empty());
}

TEST(ClusterBuildRules, FaultFindingNamesFieldAddressAndOp) {
    test::Arena arena;
    const test::Mesh m = test::grid(2);
    auto info = test::cluster_info(arena, m);
    info.vertexBuffer = 0xABC000;
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 17);
    ASSERT_FALSE(o.ok);
    ASSERT_EQ(o.findings.size(), 1u);
    EXPECT_EQ(o.findings[0].rule, kRuleMemoryFault);
    EXPECT_EQ(o.findings[0].address, 0xABC000u);
    EXPECT_EQ(o.findings[0].op_index, 17);
    EXPECT_NE(o.findings[0].message.find("vertexBuffer"), std::string::npos)
        << o.findings[0].message;
    EXPECT_NE(o.findings[0].message.find("0xabc000"), std::string::npos) << o.findings[0].message;
    EXPECT_NE(o.findings[0].message.find("op 17"), std::string::npos) << o.findings[0].message;
}

TEST(ClusterBuildRules, ClusterWithoutVerticesHasOnlyInactiveTriangles) {
    test::Arena arena;
    const std::vector<uint32_t> idx = {0, 0, 0, 1, 2, 3};
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
    info.triangleCount = 2;
    info.vertexCount = 0;
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    info.indexBuffer = arena.put_vec(idx);
    info.vertexBuffer = arena.alloc(16);
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_TRUE(has_rule(o.findings, kRuleIndexOutOfRange));
    const auto view = open_clas(o.bytes);
    ASSERT_TRUE(view);
    EXPECT_EQ(view->header.node_count, 0);
    EXPECT_FALSE(trace_any(*view, Ray{{0, 0, 1}, 0, {0, 0, -1}, 10}, 0));
    // Empty cluster: a valid object too.
    info.triangleCount = 0;
    const auto empty =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(empty.ok);
    EXPECT_TRUE(empty.findings.empty());
    EXPECT_EQ(empty.bytes.size(), sizeof(ObjectHeader));
}

// Packed 8-bit indices take the build's copy path; an empty cluster's are an empty span with a
// null data(), which that copy once handed memcpy (UBSan: null argument; session 16's fuzzing).
TEST(ClusterBuildRules, EmptyClusterWithPacked8BitIndices) {
    test::Arena arena;
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
    info.triangleCount = 0;
    info.vertexCount = 0;
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
    info.indexBuffer = arena.alloc(16);
    info.vertexBuffer = arena.alloc(64);
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    EXPECT_TRUE(o.findings.empty());
    EXPECT_EQ(o.bytes.size(), sizeof(ObjectHeader));
}

}  // namespace
}  // namespace clastrace::engine

namespace clastrace::engine {
namespace {

TEST(EngineProperties, CapturedPropertiesOverrideDefaultsAndDriveTheRules) {
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV vk =
        EngineProperties::nvidia_default().to_vk();
    EXPECT_EQ(vk.sType,
              VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV);
    EXPECT_EQ(vk.maxTrianglesPerCluster, 256u);
    EXPECT_EQ(vk.clusterByteAlignment, 128u);
    vk.maxTrianglesPerCluster = 64;
    vk.clusterByteAlignment = 256;
    vk.clusterTemplateByteAlignment = 64;
    const EngineProperties p = EngineProperties::from_vk(vk);
    EXPECT_EQ(p.max_triangles_per_cluster, 64u);
    EXPECT_EQ(object_alignment(false, p), 256u);
    EXPECT_EQ(object_alignment(true, p), 64u);
    const auto round = p.to_vk();
    EXPECT_EQ(std::memcmp(&round.maxVerticesPerCluster, &vk.maxVerticesPerCluster, 32), 0);
    // A 72-triangle cluster is fine by default and breaks 10489 under the captured limit.
    test::Arena arena;
    const test::Mesh m = test::grid(6);
    auto info = test::cluster_info(arena, m);
    auto input = test::default_input();
    input.maxClusterTriangleCount = 64;
    EXPECT_FALSE(has_rule(
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0)
            .findings,
        "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-triangleCount-10489"));
    EXPECT_TRUE(has_rule(
        build_triangle_cluster(arena.memory, info, input, p, 0).findings,
        "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-triangleCount-10489"));
}

}  // namespace
}  // namespace clastrace::engine
