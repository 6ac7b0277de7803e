// SPDX-License-Identifier: Apache-2.0
// The NV engine at the extremes: NaN vertices, degenerate triangles, coordinates near
// FLT_MAX and in the denormal range, huge instance scales, zero-instance and all-inactive
// objects, hostile counts/strides/handles, and random damage to object bytes.
#include "nv_scene.h"

#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>
#include <cstring>
#include <random>

namespace clastrace::nvtest {
namespace {

bool has(const eng::ExecutionRecord& r, const std::string& rule) {
    for (const auto& f : r.findings)
        if (f.rule == rule) return true;
    return false;
}

BlasSpec one_mesh(ts::TriangleMesh m, uint32_t flags = VK_GEOMETRY_OPAQUE_BIT_NV) {
    BlasSpec s;
    s.geometries.push_back({std::move(m), {}, flags});
    return s;
}

ts::TriangleMesh quad(float half, float z) {
    ts::TriangleMesh m;
    m.positions = {{-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

TEST(NvExtremes, NanVerticesMakeTrianglesInactiveAsTheSpecSays) {
    ts::TriangleMesh m = ts::make_icosphere(2, 1.0f);
    const float nan = std::nanf("");
    for (size_t v = 0; v < m.positions.size(); v += 3)
        m.positions[v][0] = nan;  // X NaN: inactive, silently
    for (const auto& t :
         m.triangles)  // Z NaN only, in a triangle with no X NaN: undefined, reported
        if (!std::isnan(m.positions[t[0]][0]) && !std::isnan(m.positions[t[1]][0]) &&
            !std::isnan(m.positions[t[2]][0])) {
            m.positions[t[1]][2] = nan;
            break;
        }
    NvWorld w;
    auto info = w.blas_info(one_mesh(m));
    auto obj = w.make_object(info, "blas");
    const auto r = w.build(info, obj);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(has(r, eng::kRuleNvNanComponent));
    auto h = eng::read_nv_header(w.memory.read_bytes(obj.address, 96, {}), nullptr);
    ASSERT_TRUE(h);
    EXPECT_LT(h->primitive_count, m.triangles.size());
    EXPECT_EQ(h->input_count, m.triangles.size());
    // No ray ever reports an inactive triangle.
    auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
    ASSERT_TRUE(scene);
    ts::Bounds box;
    box.extend({-2, -2, -2});
    box.extend({2, 2, 2});
    for (const auto& t : ts::random_rays(box, 4000, 3)) {
        const eng::NvHit hit =
            scene->closest(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]},
                                    0,
                                    {t.direction[0], t.direction[1], t.direction[2]},
                                    t.tmax},
                           0, 0xFF);
        if (!hit.hit) continue;
        const auto& tri = m.triangles[hit.primitive_index];
        for (uint32_t v : tri) {
            EXPECT_FALSE(std::isnan(m.positions[v][0]));
            EXPECT_FALSE(std::isnan(m.positions[v][2]));
        }
    }
    // Every vertex NaN: an object with no tree, never hit, in a TLAS too.
    for (auto& p : m.positions) p[0] = nan;
    std::vector<BlasSpec> blas{one_mesh(m)};
    auto s = build_scene(blas, std::vector<InstanceSpec>(3));
    EXPECT_TRUE(s->findings.empty());
    auto top = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(top);
    EXPECT_FALSE(top->closest(eng::Ray{{0, 0, 5}, 0, {0, 0, -1}, 100}, 0, 0xFF).hit);
    EXPECT_FALSE(top->any(eng::Ray{{0, 0, 5}, 0, {0, 0, -1}, 100}, 0, 0xFF));
}

TEST(NvExtremes, DegenerateTrianglesAreNeverHit) {
    ts::TriangleMesh m;
    m.positions = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0},   // collinear
                   {1, 1, 0}, {1, 1, 0}, {1, 1, 0},   // one point
                   {0, 2, 0}, {0, 2, 0}, {1, 3, 0}};  // two equal vertices
    m.triangles = {{0, 1, 2}, {3, 4, 5}, {6, 7, 8}};
    NvWorld w;
    auto info = w.blas_info(one_mesh(m));
    auto obj = w.make_object(info, "blas");
    ASSERT_TRUE(w.build(info, obj).ops[0].executed);
    auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
    ASSERT_TRUE(scene);
    // Rays straight at the points and segments, and grazing along the line.
    for (const eng::Ray& r :
         {eng::Ray{{1, 0, 5}, 0, {0, 0, -1}, 10}, eng::Ray{{1, 1, 5}, 0, {0, 0, -1}, 10},
          eng::Ray{{0, 2, 5}, 0, {0, 0, -1}, 10}, eng::Ray{{-1, 0, 0}, 0, {1, 0, 0}, 10},
          eng::Ray{{0.5f, 2.5f, 5}, 0, {0, 0, -1}, 10}})
        EXPECT_FALSE(scene->closest(r, 0, 0xFF).hit);
}

TEST(NvExtremes, HugeAndTinyCoordinatesKeepTheirT) {
    for (float z : {1e30f, 1e37f, 3.0e38f}) {
        NvWorld w;
        auto info = w.blas_info(one_mesh(quad(z, z)));  // a quad as wide as it is far
        auto obj = w.make_object(info, "blas");
        ASSERT_TRUE(w.build(info, obj).ops[0].executed);
        auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
        ASSERT_TRUE(scene);
        const eng::NvHit h =
            scene->closest(eng::Ray{{0.25f * z, -0.5f * z, 0}, 0, {0, 0, 1}, FLT_MAX}, 0, 0xFF);
        ASSERT_TRUE(h.hit) << z;
        EXPECT_EQ(h.t, z);
    }
    for (float s : {1e-20f, 1e-30f, 1e-38f, 1e-40f /*denormal*/}) {
        NvWorld w;
        auto info = w.blas_info(one_mesh(quad(s, s)));
        auto obj = w.make_object(info, "blas");
        ASSERT_TRUE(w.build(info, obj).ops[0].executed);
        auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
        ASSERT_TRUE(scene);
        const eng::NvHit h =
            scene->closest(eng::Ray{{0.25f * s, 0.5f * s, 0}, 0, {0, 0, 1}, 1}, 0, 0xFF);
        ASSERT_TRUE(h.hit) << s;
        EXPECT_EQ(h.t, s);
    }
    // Instances scaled by 1e30 and 1e-30: t follows the world-space ray.
    std::vector<BlasSpec> blas{one_mesh(quad(1, 1))};
    std::vector<InstanceSpec> inst(2);
    for (int r = 0; r < 3; ++r) {
        inst[0].transform[5 * r] = 1e30f;
        inst[1].transform[5 * r] = 1e-30f;
    }
    inst[0].mask = 0x01;
    inst[1].mask = 0x02;
    auto sc = build_scene(blas, inst);
    ASSERT_TRUE(sc->findings.empty());
    auto top = eng::NvScene::open(sc->world.memory, sc->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(top);
    const eng::NvHit big = top->closest(eng::Ray{{0, 0, 0}, 0, {0, 0, 1}, FLT_MAX}, 0, 0x01);
    ASSERT_TRUE(big.hit);
    EXPECT_FLOAT_EQ(big.t, 1e30f);
    const eng::NvHit small = top->closest(eng::Ray{{0, 0, 0}, 0, {0, 0, 1}, 1}, 0, 0x02);
    ASSERT_TRUE(small.hit);
    EXPECT_FLOAT_EQ(small.t, 1e-30f);
    // A singular instance transform (scale 0) is never entered.
    inst[0].transform[0] = 0;
    auto singular = build_scene(blas, {inst[0]});
    auto top2 =
        eng::NvScene::open(singular->world.memory, singular->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(top2);
    EXPECT_FALSE(top2->closest(eng::Ray{{0, 0, 0}, 0, {0, 0, 1}, FLT_MAX}, 0, 0xFF).hit);
}

// Infinite coordinates (a float overflow upstream) give boxes with infinite centroids: the
// build must bin them without undefined behaviour (found by engine_nv_fuzzer) and the
// finite triangles must still answer.
// A grid of 24x24 quads (far more than a leaf) spanning [-s, s]^2 at height s, built by
// both builders (SAH and PREFER_FAST_BUILD's Morton codes): huge extents must not overflow
// the bin or code arithmetic and denormal ones must still separate; every cell centre is
// hit at t = s.
TEST(NvExtremes, BothBuildersSplitHugeAndTinyGrids) {
    constexpr int n = 24;
    for (VkBuildAccelerationStructureFlagsNV flags :
         {0u, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        for (float s : {3.0e38f, 1e30f, 1.0f, 1e-30f, 1e-40f /*denormal*/}) {
            ts::TriangleMesh m;
            auto coord = [&](int i) { return s * (float(i) / n * 2.0f - 1.0f); };
            for (int j = 0; j <= n; ++j)
                for (int i = 0; i <= n; ++i) m.positions.push_back({coord(i), coord(j), s});
            for (int j = 0; j < n; ++j)
                for (int i = 0; i < n; ++i) {
                    const uint32_t a = uint32_t(j * (n + 1) + i), b = a + 1, c = a + n + 1,
                                   d = c + 1;
                    m.triangles.push_back({a, b, d});
                    m.triangles.push_back({a, d, c});
                }
            NvWorld w;
            auto info = w.blas_info(one_mesh(m), flags);
            auto obj = w.make_object(info, "blas");
            const auto r = w.build(info, obj);
            ASSERT_TRUE(r.ops[0].executed) << s;
            std::string error;
            const auto view =
                eng::open_nv_object(w.memory.read_bytes(obj.address, r.ops[0].dst_size, {}),
                                    &error);
            ASSERT_TRUE(view) << error;
            EXPECT_GT(view->header.node_count, 2u * n * n / 4) << s;  // split down to small leaves
            auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
            ASSERT_TRUE(scene);
            int hits = 0;
            for (int j = 0; j < n; ++j)
                for (int i = 0; i < n; ++i) {
                    const float x = 0.5f * coord(i) + 0.5f * coord(i + 1),
                                y = 0.5f * coord(j) + 0.5f * coord(j + 1);
                    const eng::NvHit h =
                        scene->closest(eng::Ray{{x, y, 0}, 0, {0, 0, 1}, FLT_MAX}, 0, 0xFF);
                    hits += h.hit && h.t == s && h.primitive_index / 2 == uint32_t(j * n + i);
                }
            EXPECT_EQ(hits, n * n) << "scale " << s << " flags " << flags;
        }
    }
}

TEST(NvExtremes, InfiniteCoordinatesBuildAndFiniteTrianglesStillHit) {
    for (VkBuildAccelerationStructureFlagsNV flags :
         {0u, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        ts::TriangleMesh m = quad(1, 0);
        const float inf = INFINITY;
        const uint32_t base = uint32_t(m.positions.size());
        m.positions.push_back({inf, 0, 0});
        m.positions.push_back({inf, 1, 0});
        m.positions.push_back({-inf, inf, inf});
        for (int k = 0; k < 6; ++k) m.triangles.push_back({base, base + 1, base + 2});
        NvWorld w;
        auto info = w.blas_info(one_mesh(m), flags);
        auto obj = w.make_object(info, "blas");
        ASSERT_TRUE(w.build(info, obj).ops[0].executed);
        auto scene = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
        ASSERT_TRUE(scene);
        const eng::NvHit h = scene->closest(eng::Ray{{0.2f, 0.3f, 5}, 0, {0, 0, -1}, 10}, 0, 0xFF);
        ASSERT_TRUE(h.hit);
        EXPECT_LT(h.primitive_index, 2u);
        EXPECT_FLOAT_EQ(h.t, 5.0f);
    }
}

TEST(NvExtremes, RaysWithNanInfOrEmptyIntervalsMissQuietly) {
    auto s = build_scene({one_mesh(ts::make_icosphere(1, 1))}, std::vector<InstanceSpec>(1));
    auto top = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(top);
    const float nan = std::nanf(""), inf = INFINITY;
    for (const eng::Ray& r :
         {eng::Ray{{nan, 0, 5}, 0, {0, 0, -1}, 10}, eng::Ray{{0, 0, 5}, 0, {nan, 0, -1}, 10},
          eng::Ray{{0, 0, 5}, nan, {0, 0, -1}, 10}, eng::Ray{{0, 0, 5}, 5, {0, 0, -1}, 1},
          eng::Ray{{0, 0, 5}, 0, {0, 0, 0}, 10}, eng::Ray{{inf, 0, 5}, 0, {0, 0, -1}, 10}})
        EXPECT_FALSE(top->closest(r, 0, 0xFF).hit);
    EXPECT_TRUE(top->closest(eng::Ray{{0, 0, 5}, 0, {0, 0, -1}, inf}, 0, 0xFF).hit);
}

TEST(NvExtremes, HostileCountsStridesAndHandlesEndInFindingsNotAllocations) {
    NvWorld w;
    auto base = w.blas_info(one_mesh(ts::make_icosphere(1, 1)));
    auto make_dst = [&](const eng::NvObjectInfo& created) { return w.make_object(created, "dst"); };
    {
        auto info = base;  // 2^32 - 1 vertices in a 4 KiB buffer, no indices: dst far too small
        info.geometries[0].triangles.index_type = VK_INDEX_TYPE_NONE_NV;
        info.geometries[0].triangles.index_address = 0;
        info.geometries[0].triangles.index_count = 0;
        info.geometries[0].triangles.vertex_count = 0xFFFFFFFFu;
        auto dst = make_dst(base);
        dst.created.reset();
        const auto r = w.build(info, dst);
        EXPECT_FALSE(r.ops[0].executed);
        EXPECT_TRUE(has(r, eng::kVuidInfoTriangleCount) || has(r, eng::kRuleNvObjectTooLarge));
    }
    {
        auto info = base;  // stride 0: every vertex the same; fits, builds, never hit
        info.geometries[0].triangles.vertex_stride = 0;
        auto dst = make_dst(info);
        const auto r = w.build(info, dst);
        EXPECT_TRUE(r.ops[0].executed);
        auto scene = eng::NvScene::open_bottom(w.memory, dst.address, nullptr);
        ASSERT_TRUE(scene);
        EXPECT_FALSE(scene->closest(eng::Ray{{0, 0, 5}, 0, {0, 0, -1}, 10}, 0, 0xFF).hit);
    }
    {
        auto info = base;  // a stride that wraps the address space
        info.geometries[0].triangles.vertex_stride = ~0ull / 3;
        auto dst = make_dst(info);
        const auto r = w.build(info, dst);
        EXPECT_FALSE(r.ops[0].executed);
        EXPECT_TRUE(has(r, eng::kRuleNvMemoryFault));
    }
    {
        // An AABB count of 2^32 - 1 with stride 0 into an object created for 8.
        eng::NvObjectInfo info;
        eng::NvGeometry g;
        g.type = VK_GEOMETRY_TYPE_AABBS_NV;
        const float box[6] = {0, 0, 0, 1, 1, 1};
        g.aabbs.address = w.put(box, 24, "box");
        g.aabbs.count = 8;
        info.geometries.push_back(g);
        auto dst = make_dst(info);
        info.geometries[0].aabbs.count = 0xFFFFFFFFu;
        const auto r = w.build(info, dst);
        EXPECT_FALSE(r.ops[0].executed);
        EXPECT_TRUE(has(r, eng::kVuidNvDstCompatible));
    }
    {
        // 2^24 - 1 instances read from a 64-byte buffer.
        eng::NvObjectInfo top;
        top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        top.instance_count = 1;
        auto dst = make_dst(top);
        top.instance_count = 16777215;
        dst.created.reset();
        const uint8_t one[64] = {};
        const auto r = w.build(top, dst, w.put(one, 64, "i"));
        EXPECT_FALSE(r.ops[0].executed);
        EXPECT_TRUE(has(r, eng::kRuleNvObjectTooLarge));
        top.instance_count = 16777216;
        EXPECT_TRUE(has(w.build(top, dst, w.put(one, 64, "i")), eng::kVuidInfoInstanceCount));
    }
    {
        // Garbage handles in every instance record: each one found wanting, nothing crashes.
        std::mt19937_64 rng(3);
        std::vector<uint8_t> bytes(64 * 64);
        for (auto& b : bytes) b = uint8_t(rng());
        eng::NvObjectInfo top;
        top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        top.instance_count = 64;
        auto dst = make_dst(top);
        const auto r = w.build(top, dst, w.put(bytes.data(), bytes.size(), "garbage"));
        EXPECT_TRUE(r.ops[0].executed);
        EXPECT_TRUE(has(r, eng::kRuleNvBlasNotBuilt));
        auto scene = eng::NvScene::open(w.memory, dst.address, nullptr, nullptr);
        ASSERT_TRUE(scene);
        EXPECT_EQ(scene->instances_reached(), 0u);
    }
}

// Random damage to built objects: open_nv_object rejects it or the bytes trace safely.
TEST(NvExtremes, RandomDamageToObjectBytesIsRejectedOrTracedSafely) {
    std::vector<BlasSpec> blas{one_mesh(ts::make_icosphere(2, 1.0f))};
    blas.push_back(BlasSpec{true, {{{}, random_boxes(30, 2), 0}}});
    auto s = build_scene(blas, random_instances(10, 2, 2.0f, 4));
    ASSERT_TRUE(s->findings.empty());
    std::mt19937_64 rng(12);
    size_t opened = 0, rejected = 0;
    for (int round = 0; round < 2000; ++round) {
        const auto& target = round % 2 ? s->tlas : s->blas[size_t(round / 2) % 2];
        auto head =
            eng::read_nv_header(s->world.memory.read_bytes(target.address, 96, {}), nullptr);
        ASSERT_TRUE(head);
        const uint64_t size = head->object_size;
        std::vector<std::byte> saved(size);
        auto live = s->world.memory.write_bytes(target.address, size, {});
        std::memcpy(saved.data(), live.data(), size);
        for (int k = 0, n = 1 + int(rng() % 6); k < n; ++k) {
            const uint64_t at = rng() % size;
            if (rng() % 2)
                live[at] = std::byte(rng());
            else if (at + 4 <= size) {
                const uint32_t v = rng() % 3 ? uint32_t(rng() % 64) : uint32_t(rng());
                std::memcpy(live.data() + at, &v, 4);
            }
        }
        std::string error;
        auto scene = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, &error);
        if (scene) {
            ++opened;
            for (int k = 0; k < 10; ++k) {
                const eng::Ray r{{float(int(rng() % 7)) - 3, float(int(rng() % 7)) - 3, 6},
                                 0,
                                 {0.05f, 0.1f, -1},
                                 100};
                (void)scene->closest(r, uint32_t(rng() % 256), 0xFF);
                (void)scene->any(r, 0, 0xFF);
            }
        } else {
            ++rejected;
        }
        std::memcpy(s->world.memory.write_bytes(target.address, size, {}).data(), saved.data(),
                    size);
    }
    EXPECT_GT(opened, 0u);
    EXPECT_GT(rejected, 0u);
}

}  // namespace
}  // namespace clastrace::nvtest
