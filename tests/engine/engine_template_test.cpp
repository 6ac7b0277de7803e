// SPDX-License-Identifier: Apache-2.0
// Cluster templates: with and without positions, instantiation with offsets and the
// instance's vertex buffer, the bounding-box limit, get-template-indices, and the rules.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "clastrace/engine/vertex_format.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

#include <bit>
#include <functional>

namespace clastrace::engine {
namespace {

using test::Arena;
using TemplateInfo = VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV;
using InstInfo = VkClusterAccelerationStructureInstantiateClusterInfoNV;

TemplateInfo template_info(Arena& arena, const test::Mesh& m, bool with_positions) {
    TemplateInfo t{};
    t.clusterID = 100;
    t.triangleCount = uint32_t(m.indices.size() / 3);
    t.vertexCount = uint32_t(m.positions.size() / 3);
    t.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    t.indexBuffer = arena.put_vec(m.indices);
    t.vertexBuffer = with_positions ? arena.put_vec(m.positions) : 0;
    t.baseGeometryIndexAndGeometryFlags.geometryIndex = 7;
    return t;
}

// Places an object's bytes in device memory (as the command would) and returns its address.
uint64_t place(Arena& arena, const std::vector<std::byte>& bytes, uint64_t align = 32) {
    return arena.put(bytes.data(), bytes.size(), align);
}

TEST(ClusterTemplate, WithPositionsInstantiatesToTheDirectBuild) {
    Arena arena;
    const test::Mesh m = test::grid(5);
    TemplateInfo ti = template_info(arena, m, true);
    ti.positionTruncateBitCount = 6;
    const auto tmpl = build_triangle_cluster_template(arena.memory, ti, test::default_input(),
                                                      EngineProperties{}, 0);
    ASSERT_TRUE(tmpl.ok);
    EXPECT_TRUE(tmpl.findings.empty()) << tmpl.findings[0].message;
    const auto h = read_object_header(tmpl.bytes).header;
    ASSERT_TRUE(h);
    EXPECT_EQ(h->object_type, uint8_t(ObjectType::kTriangleClusterTemplate));
    EXPECT_TRUE(h->header_flags & kHasPositions);
    EXPECT_EQ(h->node_count, 0) << "templates are not traced: no BVH bytes";
    EXPECT_FALSE(open_clas(tmpl.bytes)) << "a template is no CLAS";

    InstInfo ii{};
    ii.clusterTemplateAddress = place(arena, tmpl.bytes);
    ii.clusterIdOffset = 5;
    const auto inst = instantiate_triangle_cluster(arena.memory, ii, test::default_input(),
                                                   EngineProperties{}, 1);
    ASSERT_TRUE(inst.ok);
    EXPECT_TRUE(inst.findings.empty()) << inst.findings[0].message;

    // The same cluster built directly, with clusterID 105.
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV bi = test::cluster_info(arena, m, 105);
    bi.positionTruncateBitCount = 6;
    bi.baseGeometryIndexAndGeometryFlags.geometryIndex = 7;
    const auto direct =
        build_triangle_cluster(arena.memory, bi, test::default_input(), EngineProperties{}, 2);
    ASSERT_TRUE(direct.ok);
    EXPECT_EQ(inst.bytes, direct.bytes);
}

TEST(ClusterTemplate, WithoutPositionsUsesTheInstanceVertexBuffer) {
    Arena arena;
    const test::Mesh shape = test::grid(4);
    const auto tmpl =
        build_triangle_cluster_template(arena.memory, template_info(arena, shape, false),
                                        test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(tmpl.ok);
    const auto h = read_object_header(tmpl.bytes).header;
    EXPECT_FALSE(h->header_flags & kHasPositions);
    const uint64_t at = place(arena, tmpl.bytes);

    // Instance: moved and scaled vertices, stride 16.
    test::Mesh moved = test::grid(4, 2.0f, 99, 3.0f);
    std::vector<float> padded;
    for (size_t v = 0; v < moved.positions.size() / 3; ++v)
        padded.insert(padded.end(), {moved.positions[3 * v], moved.positions[3 * v + 1],
                                     moved.positions[3 * v + 2], 0.0f});
    InstInfo ii{};
    ii.clusterTemplateAddress = at;
    ii.vertexBuffer = {arena.put_vec(padded), 16};
    ii.geometryIndexOffset = uint32_t(-3) & 0xFFFFFFu;  // signed: 7 - 3 = 4
    const auto inst = instantiate_triangle_cluster(arena.memory, ii, test::default_input(),
                                                   EngineProperties{}, 0);
    ASSERT_TRUE(inst.ok);
    EXPECT_TRUE(inst.findings.empty()) << inst.findings[0].message;
    const auto ih = read_object_header(inst.bytes).header;
    EXPECT_EQ(ih->cluster_id, 100u);
    EXPECT_EQ(ih->base_geometry_index_and_flags & 0xFFFFFF, 4u);

    auto bi = test::cluster_info(arena, moved, 100);
    bi.indexBuffer = arena.put_vec(shape.indices);
    bi.baseGeometryIndexAndGeometryFlags.geometryIndex = 4;
    const auto direct =
        build_triangle_cluster(arena.memory, bi, test::default_input(), EngineProperties{}, 0);
    EXPECT_EQ(inst.bytes, direct.bytes);

    Ray r{{3.3f, 2.7f, 20.0f}, 0.0f, {0, 0, -1}, 100.0f};
    const Hit hit = trace_closest(inst.bytes, r, 0);
    ASSERT_TRUE(hit.hit);
    EXPECT_EQ(hit.geometry_index, 4u);
    EXPECT_NEAR(hit.t, 17.0f, 1.0f);
}

TEST(ClusterTemplate, TruncationOfTheTemplateAppliesToInstancePositions) {
    Arena arena;
    const test::Mesh m = test::grid(3);
    TemplateInfo ti = template_info(arena, m, false);
    ti.positionTruncateBitCount = 20;
    const auto tmpl = build_triangle_cluster_template(arena.memory, ti, test::default_input(),
                                                      EngineProperties{}, 0);
    ASSERT_TRUE(tmpl.ok);
    InstInfo ii{};
    ii.clusterTemplateAddress = place(arena, tmpl.bytes);
    ii.vertexBuffer = {arena.put_vec(m.positions), 0};
    const auto inst = instantiate_triangle_cluster(arena.memory, ii, test::default_input(),
                                                   EngineProperties{}, 0);
    ASSERT_TRUE(inst.ok);
    const auto h = read_object_header(inst.bytes).header;
    EXPECT_EQ(h->position_truncate_bits, 20);
    for (uint32_t v = 0; v < h->vertex_count; ++v) {
        float xyz[3];
        decode_position(inst.bytes, *h, v, xyz);
        for (int k = 0; k < 3; ++k)
            EXPECT_EQ(std::bit_cast<uint32_t>(xyz[k]),
                      std::bit_cast<uint32_t>(truncate_position(m.positions[3 * v + k], 20)));
    }
}

TEST(ClusterTemplate, BoundingBoxLimit) {
    Arena arena;
    const test::Mesh m = test::grid(3);  // x, y in [0, 3], z in [-0.2, 0.2]
    TemplateInfo ti = template_info(arena, m, false);
    const float limit[6] = {-1, -1, -1, 4, 4, 1};
    ti.instantiationBoundingBoxLimit = arena.put(limit, 24, 32);
    const auto tmpl = build_triangle_cluster_template(arena.memory, ti, test::default_input(),
                                                      EngineProperties{}, 0);
    ASSERT_TRUE(tmpl.ok);
    EXPECT_TRUE(tmpl.findings.empty());
    EXPECT_TRUE(read_object_header(tmpl.bytes).header->header_flags & kHasBoundsLimit);
    const uint64_t at = place(arena, tmpl.bytes);

    InstInfo inside{};
    inside.clusterTemplateAddress = at;
    inside.vertexBuffer = {arena.put_vec(m.positions), 12};
    const auto ok = instantiate_triangle_cluster(arena.memory, inside, test::default_input(),
                                                 EngineProperties{}, 0);
    ASSERT_TRUE(ok.ok);
    EXPECT_FALSE(has_rule(ok.findings, kRuleInstanceOutsideLimit));

    test::Mesh far = m;
    far.positions[3 * 4 + 2] = 1.5f;  // vertex 4's z beyond the limit
    InstInfo outside = inside;
    outside.vertexBuffer = {arena.put_vec(far.positions), 12};
    const auto bad = instantiate_triangle_cluster(arena.memory, outside, test::default_input(),
                                                  EngineProperties{}, 9);
    ASSERT_TRUE(bad.ok) << "a finding, not a failure";
    ASSERT_TRUE(has_rule(bad.findings, kRuleInstanceOutsideLimit));
    EXPECT_NE(bad.findings[0].message.find("first is vertex 4"), std::string::npos)
        << bad.findings[0].message;

    // Misaligned limit address: 10505.
    TemplateInfo misaligned = ti;
    misaligned.instantiationBoundingBoxLimit = arena.put(limit, 24, 32) + 4;
    arena.put(limit, 24, 4);  // keep the 24 bytes readable
    const auto mt = build_triangle_cluster_template(arena.memory, misaligned, test::default_input(),
                                                    EngineProperties{}, 0);
    EXPECT_TRUE(has_rule(mt.findings,
                         "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
                         "instantiationBoundingBoxLimit-10505"));
}

TEST(ClusterTemplate, GetTemplateIndicesReturnsTheAppsIndices) {
    Arena arena;
    const test::Mesh m = test::grid(4);
    TemplateInfo ti = template_info(arena, m, false);
    std::vector<uint16_t> idx16(m.indices.begin(), m.indices.end());
    ti.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
    ti.indexBuffer = arena.put_vec(idx16);
    const auto tmpl = build_triangle_cluster_template(arena.memory, ti, test::default_input(),
                                                      EngineProperties{}, 0);
    ASSERT_TRUE(tmpl.ok);
    VkClusterAccelerationStructureGetTemplateIndicesInfoNV gi{place(arena, tmpl.bytes)};
    const auto got = get_cluster_template_indices(arena.memory, gi, 0);
    ASSERT_TRUE(got.ok);
    ASSERT_EQ(got.bytes.size(), 12 * (m.indices.size() / 3));
    std::vector<uint32_t> values(m.indices.size());
    std::memcpy(values.data(), got.bytes.data(), got.bytes.size());
    EXPECT_EQ(values, m.indices);

    // Not a template: a CLAS, and plain zeros.
    const auto clas = build_triangle_cluster(arena.memory, test::cluster_info(arena, m),
                                             test::default_input(), EngineProperties{}, 0);
    gi.clusterTemplateAddress = place(arena, clas.bytes);
    EXPECT_TRUE(
        has_rule(get_cluster_template_indices(arena.memory, gi, 0).findings, kRuleNotATemplate));
    gi.clusterTemplateAddress = arena.alloc(256);
    const auto zeros = get_cluster_template_indices(arena.memory, gi, 0);
    EXPECT_FALSE(zeros.ok);
    EXPECT_TRUE(has_rule(zeros.findings, kRuleNotATemplate));
    gi.clusterTemplateAddress = 0x42;
    EXPECT_TRUE(
        has_rule(get_cluster_template_indices(arena.memory, gi, 0).findings, kRuleMemoryFault));
}

TEST(ClusterTemplateRules, TemplateInfoRules) {
    struct Case {
        const char* rule;
        std::function<void(Arena&, TemplateInfo&,
                           VkClusterAccelerationStructureTriangleClusterInputNV&,
                           EngineProperties&)>
            mutate;
    };
    const std::vector<Case> cases = {
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-clusterID-10497",
         [](auto&, auto& t, auto&, auto&) { t.clusterID = 0xFFFFFFFFu; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-triangleCount-"
         "10498",
         [](auto&, auto&, auto& in, auto& p) {
             p.max_triangles_per_cluster = in.maxClusterTriangleCount = 20;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexCount-10499",
         [](auto&, auto&, auto& in, auto& p) {
             p.max_vertices_per_cluster = in.maxClusterVertexCount = 20;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexType-10500",
         [](auto&, auto& t, auto&, auto&) { t.indexType = 0; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
         "opacityMicromapIndexType-10501",
         [](Arena& a, auto& t, auto&, auto&) {
             t.opacityMicromapArray = a.alloc(64);
             t.opacityMicromapIndexType = 0;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
         "positionTruncateBitCount-10502",
         [](auto&, auto& t, auto& in, auto&) {
             in.minPositionTruncateBitCount = 4;
             t.positionTruncateBitCount = 3;
         }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexBufferStride-"
         "10503",
         [](auto&, auto& t, auto&, auto&) { t.indexBufferStride = 2; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexBufferStride-"
         "10504",
         [](auto&, auto& t, auto&, auto&) { t.vertexBufferStride = 13; }},
        {"VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-baseGeometryIndex-"
         "10506",
         [](auto&, auto& t, auto&, auto& p) {
             p.max_cluster_geometry_index = 7;
             t.baseGeometryIndexAndGeometryFlags.geometryIndex = 7;
         }},
        {kRuleIndexOutOfRange,
         [](Arena& a, auto& t, auto&, auto&) {
             std::vector<uint32_t> idx(96, 99);
             t.indexBuffer = a.put_vec(idx);
         }},
    };
    for (const Case& c : cases) {
        Arena arena;
        const test::Mesh m = test::grid(4);
        TemplateInfo ti = template_info(arena, m, true);
        auto input = test::default_input();
        EngineProperties props;
        {
            const auto base = build_triangle_cluster_template(arena.memory, ti, input, props, 0);
            ASSERT_TRUE(base.ok);
            EXPECT_FALSE(has_rule(base.findings, c.rule)) << "baseline breaks " << c.rule;
        }
        c.mutate(arena, ti, input, props);
        const auto o = build_triangle_cluster_template(arena.memory, ti, input, props, 0);
        EXPECT_TRUE(has_rule(o.findings, c.rule)) << "expected " << c.rule;
    }
}

TEST(ClusterTemplateRules, InstantiateRules) {
    Arena arena;
    const test::Mesh m = test::grid(3);
    const auto no_pos =
        build_triangle_cluster_template(arena.memory, template_info(arena, m, false),
                                        test::default_input(), EngineProperties{}, 0);
    const uint64_t at = place(arena, no_pos.bytes);
    const uint64_t vb = arena.put_vec(m.positions);
    InstInfo good{};
    good.clusterTemplateAddress = at;
    good.vertexBuffer = {vb, 12};
    const auto passing = instantiate_triangle_cluster(arena.memory, good, test::default_input(),
                                                      EngineProperties{}, 0);
    ASSERT_TRUE(passing.ok);
    EXPECT_TRUE(passing.findings.empty());

    InstInfo i = good;
    i.vertexBuffer = {0, 0};
    auto o =
        instantiate_triangle_cluster(arena.memory, i, test::default_input(), EngineProperties{}, 0);
    EXPECT_FALSE(o.ok);
    EXPECT_TRUE(
        has_rule(o.findings,
                 "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10507"));

    o = instantiate_triangle_cluster(arena.memory, good,
                                     test::default_input(VK_FORMAT_R32G32B32A32_SFLOAT),
                                     EngineProperties{}, 0);
    EXPECT_TRUE(
        has_rule(o.findings,
                 "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10508"));

    i = good;
    i.reserved = 1;
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), EngineProperties{}, 0);
    EXPECT_TRUE(
        has_rule(o.findings,
                 "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-reserved-10509"));

    i = good;
    i.geometryIndexOffset = 0x800000;  // -2^23: below zero
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), EngineProperties{}, 0);
    EXPECT_TRUE(has_rule(
        o.findings,
        "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-geometryIndexOffset-10510"));
    EngineProperties small;
    small.max_cluster_geometry_index = 9;
    i = good;
    i.geometryIndexOffset = 2;  // 7 + 2 = 9: not less than 9
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), small, 0);
    EXPECT_TRUE(has_rule(
        o.findings,
        "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-geometryIndexOffset-10510"));
    i.geometryIndexOffset = 1;
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), small, 0);
    EXPECT_FALSE(has_rule(
        o.findings,
        "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-geometryIndexOffset-10510"));

    i = good;
    i.clusterTemplateAddress = arena.alloc(512);  // zeros
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), EngineProperties{}, 0);
    EXPECT_FALSE(o.ok);
    EXPECT_TRUE(has_rule(o.findings, kRuleNotATemplate));

    i = good;
    i.vertexBuffer = {arena.base + arena.size - 24, 12};  // runs off the region
    o = instantiate_triangle_cluster(arena.memory, i, test::default_input(), EngineProperties{}, 0);
    EXPECT_FALSE(o.ok);
    EXPECT_TRUE(has_rule(o.findings, kRuleMemoryFault));
}

}  // namespace
}  // namespace clastrace::engine
