// SPDX-License-Identifier: Apache-2.0
// Numerical extremes: huge and tiny coordinates, denormals, Inf, NaN (inactive), zero-area,
// sliver and collapsed triangles, every positionTruncateBitCount, out-of-range indices and
// full 256-triangle / 256-vertex clusters. Each builds without crashing and traces as the
// geometry says it must.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "clastrace/testsupport/cluster_scene.h"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <iostream>
#include <limits>
#include <random>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kMax = std::numeric_limits<float>::max();

struct Built {
    std::vector<std::byte> bytes;
    std::vector<eng::Finding> findings;
    bool ok = false;
    std::string findings_text() const {
        std::string s;
        for (const auto& f : findings) s += f.rule + ": " + f.message + "\n";
        return s;
    }
};

// Writes positions and raw indices (any value, index_bytes wide) into a MemoryImage and builds
// one CLAS through the public op, as a replay would.
Built build(const std::vector<ts::Float3>& positions,
            const std::vector<std::array<uint32_t, 3>>& triangles, unsigned truncate_bits,
            uint32_t index_bytes = 4, uint32_t vertex_count_override = ~0u) {
    eng::MemoryImage memory;
    const VkBufferUsageFlags usage =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
        VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    const uint64_t vbase = 0x10000, ibase = 0x900000;
    auto& vr =
        memory.add_region(vbase, std::max<size_t>(positions.size() * 12, 16), usage, "vertices");
    auto& ir = memory.add_region(ibase, std::max<size_t>(triangles.size() * 3 * index_bytes, 16),
                                 usage, "indices");
    std::memcpy(vr.bytes.data(), positions.data(), positions.size() * 12);
    for (size_t t = 0; t < triangles.size(); ++t)
        for (int k = 0; k < 3; ++k)
            std::memcpy(ir.bytes.data() + (3 * t + k) * index_bytes, &triangles[t][k], index_bytes);
    VkClusterAccelerationStructureTriangleClusterInputNV input{};
    input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    input.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    input.maxClusterUniqueGeometryCount = 1;
    input.maxClusterTriangleCount = uint32_t(triangles.size());
    input.maxClusterVertexCount = uint32_t(positions.size());
    input.maxTotalTriangleCount = uint32_t(triangles.size());
    input.maxTotalVertexCount = uint32_t(positions.size());
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
    info.clusterID = 7;
    info.triangleCount = uint32_t(triangles.size()) & 0x1FF;
    info.vertexCount =
        (vertex_count_override != ~0u ? vertex_count_override : uint32_t(positions.size())) & 0x1FF;
    info.positionTruncateBitCount = truncate_bits & 0x3F;
    info.indexType = index_bytes;
    info.baseGeometryIndexAndGeometryFlags.geometryFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
    info.indexBuffer = ibase;
    info.vertexBuffer = vbase;
    const eng::ClusterObject obj =
        eng::build_triangle_cluster(memory, info, input, eng::EngineProperties::nvidia_default(),
                                    0);
    return {obj.bytes, obj.findings, obj.ok};
}

eng::Hit trace(const Built& b, ts::Float3 o, ts::Float3 d, float tmax = kInf) {
    eng::Ray r{{o[0], o[1], o[2]}, 0.0f, {d[0], d[1], d[2]}, tmax};
    return eng::trace_closest(b.bytes, r, 0);
}

// Stored triangles (decoded from the object), keyed by the app's triangle index.
std::map<uint32_t, eng::DecodedTriangle> stored_triangles(const Built& b) {
    std::map<uint32_t, eng::DecodedTriangle> out;
    const eng::HeaderCheck hc = eng::read_object_header(b.bytes);
    EXPECT_TRUE(hc.header.has_value()) << hc.error;
    if (!hc.header) return out;
    for (uint32_t i = 0; i < hc.header->triangle_count; ++i) {
        const eng::DecodedTriangle t = eng::decode_triangle(b.bytes, *hc.header, i);
        out[t.original_index] = t;
    }
    return out;
}

// A 2x2-quad patch at height z, scaled by s: 8 triangles, 9 vertices.
void patch(float s, float z, std::vector<ts::Float3>& pos,
           std::vector<std::array<uint32_t, 3>>& tris) {
    pos.clear();
    tris.clear();
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 3; ++x) pos.push_back({s * (x - 1), s * (y - 1), z});
    for (uint32_t y = 0; y < 2; ++y)
        for (uint32_t x = 0; x < 2; ++x) {
            const uint32_t a = y * 3 + x;
            tris.push_back({a, a + 1, a + 4});
            tris.push_back({a, a + 4, a + 3});
        }
}

}  // namespace

TEST(Extremes, CoordinatesNearFloatMax) {
    for (float s : {1e30f, 1e38f, 3.4e38f, kMax}) {
        std::vector<ts::Float3> pos;
        std::vector<std::array<uint32_t, 3>> tris;
        patch(s, s * 0.5f, pos, tris);  // spans [-s, s]^2: edge vectors overflow float, not double
        const Built b = build(pos, tris, 0);
        ASSERT_TRUE(b.ok) << s << "\n" << b.findings_text();
        size_t hits = 0;
        for (float fx : {-0.7f, -0.2f, 0.0f, 0.3f, 0.9f})
            for (float fy : {-0.9f, 0.0f, 0.5f}) {
                const eng::Hit h = trace(b, {fx * s, fy * s, 0.0f}, {0, 0, 1});
                ASSERT_TRUE(h.hit) << "scale " << s << " at " << fx << "," << fy;
                EXPECT_FLOAT_EQ(h.t, s * 0.5f);
                ++hits;
                // From the far side, downwards: origin at +FLT_MAX.
                const eng::Hit h2 = trace(b, {fx * s, fy * s, kMax}, {0, 0, -1});
                ASSERT_TRUE(h2.hit);
                EXPECT_NEAR(double(h2.t), double(kMax) - double(s) * 0.5, double(kMax) * 1e-6);
            }
        EXPECT_EQ(hits, 15u);
        if (s <= kMax / 1.5f) {
            EXPECT_FALSE(trace(b, {1.5f * s, 0, 0}, {0, 0, 1}).hit);
        }
    }
}

TEST(Extremes, TinyAndDenormalCoordinates) {
    for (float s : {1e-30f, 1e-38f, 1.17549435e-38f /*FLT_MIN*/, 1e-40f /*denormal*/,
                    1e-44f /*few-bit denormal*/}) {
        std::vector<ts::Float3> pos;
        std::vector<std::array<uint32_t, 3>> tris;
        patch(s, s, pos, tris);
        const Built b = build(pos, tris, 0);
        ASSERT_TRUE(b.ok) << s << "\n" << b.findings_text();
        // Stored positions are the inputs bit for bit (no flush to zero).
        for (const auto& [idx, t] : stored_triangles(b))
            for (int c = 0; c < 3; ++c)
                for (int k = 0; k < 3; ++k)
                    ASSERT_EQ(std::bit_cast<uint32_t>(t.v[c][k]),
                              std::bit_cast<uint32_t>(pos[tris[idx][c]][k]))
                        << s;
        for (float fx : {-0.5f, 0.25f})
            for (float fy : {-0.75f, 0.5f}) {
                const ts::Float3 o{fx * s, fy * s, 0.0f};
                const eng::Hit h = trace(b, o, {0, 0, 1});
                ASSERT_TRUE(h.hit) << "scale " << s << " at " << fx << "," << fy;
                EXPECT_EQ(h.t, s);  // z = s exactly, direction 1
                // A unit-length ray far away misses the tiny patch.
                EXPECT_FALSE(trace(b, {1.0f, 1.0f, 0.0f}, {0, 0, 1}).hit);
            }
    }
}

TEST(Extremes, InfiniteCoordinatesDoNotPoisonTheCluster) {
    std::vector<ts::Float3> pos;
    std::vector<std::array<uint32_t, 3>> tris;
    patch(1.0f, 2.0f, pos, tris);
    pos.push_back({kInf, 0.0f, 2.0f});
    pos.push_back({0.0f, -kInf, 2.0f});
    pos.push_back({5.0f, 5.0f, kInf});
    tris.push_back({9, 10, 11});  // every vertex has an infinite coordinate
    tris.push_back({0, 1, 9});    // one infinite vertex
    const Built b = build(pos, tris, 0);
    ASSERT_TRUE(b.ok) << b.findings_text();
    // The finite triangles still hit at the right distance.
    for (float fx : {-0.5f, 0.5f})
        for (float fy : {-0.5f, 0.5f}) {
            const eng::Hit h = trace(b, {fx, fy, 0}, {0, 0, 1});
            ASSERT_TRUE(h.hit);
            EXPECT_FLOAT_EQ(h.t, 2.0f);
            EXPECT_LT(h.triangle_index, 8u);
            EXPECT_TRUE(std::isfinite(h.u) && std::isfinite(h.v));
        }
    // Wherever the infinite triangles answer, the engine does not crash and reports finite t.
    for (float fx : {3.0f, 50.0f, 1e30f}) {
        const eng::Hit h = trace(b, {fx, 0.25f, 0}, {0, 0, 1});
        if (h.hit) {
            EXPECT_TRUE(std::isfinite(h.t));
        }
    }
}

TEST(Extremes, NaNTrianglesAreNeverHit) {
    std::vector<ts::Float3> pos;
    std::vector<std::array<uint32_t, 3>> tris;
    // A 16x16 grid; every vertex of row 5 and column 9 has a NaN in one coordinate.
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) {
            ts::Float3 p{float(x), float(y), 1.0f};
            if (y == 5) p[(x % 3)] = kNaN;
            if (x == 9) p[(y % 3)] = -kNaN;
            pos.push_back(p);
        }
    for (uint32_t y = 0; y < 15; ++y)
        for (uint32_t x = 0; x < 15 && tris.size() < 256; ++x) {
            tris.push_back({y * 16 + x, y * 16 + x + 1, (y + 1) * 16 + x + 1});
            if (tris.size() < 256)
                tris.push_back({y * 16 + x, (y + 1) * 16 + x + 1, (y + 1) * 16 + x});
        }
    for (unsigned bits : {0u, 8u, 16u}) {
        const Built b = build(pos, tris, bits, 2);
        ASSERT_TRUE(b.ok) << b.findings_text();
        size_t nan_tris = 0, hits_on_nan = 0, hits_on_good = 0, good_tris = 0;
        for (uint32_t t = 0; t < tris.size(); ++t) {
            bool has_nan = false;
            for (uint32_t v : tris[t])
                for (float c : pos[v]) has_nan = has_nan || std::isnan(c);
            // Aim at the triangle's centroid in the plane z = 1 (from the grid coordinates).
            const uint32_t a = tris[t][0], bb = tris[t][1], c = tris[t][2];
            const float cx = float((a % 16) + (bb % 16) + (c % 16)) / 3,
                        cy = float((a / 16) + (bb / 16) + (c / 16)) / 3;
            const eng::Hit h = trace(b, {cx, cy, 0.0f}, {0, 0, 1});
            if (has_nan) {
                ++nan_tris;
                // The ray may land on a good neighbour sharing the point, never on a NaN triangle.
                if (h.hit && h.triangle_index == t) ++hits_on_nan;
                if (h.hit) {
                    for (uint32_t v : tris[h.triangle_index])
                        for (float q : pos[v])
                            ASSERT_FALSE(std::isnan(q)) << "hit NaN triangle " << h.triangle_index;
                }
            } else {
                ++good_tris;
                if (h.hit && h.triangle_index == t) ++hits_on_good;
            }
        }
        EXPECT_GT(nan_tris, 30u);
        EXPECT_EQ(hits_on_nan, 0u);
        EXPECT_EQ(hits_on_good, good_tris) << "truncate " << bits;
    }
    // All-NaN cluster: builds, never hits.
    std::vector<ts::Float3> all_nan(9, {kNaN, kNaN, kNaN});
    const Built b = build(all_nan, {{0, 1, 2}, {3, 4, 5}, {6, 7, 8}}, 0);
    ASSERT_TRUE(b.ok) << b.findings_text();
    EXPECT_FALSE(trace(b, {0, 0, -1}, {0, 0, 1}).hit);
    EXPECT_FALSE(trace(b, {kNaN, 0, -1}, {0, 0, 1}).hit);
}

TEST(Extremes, DegenerateTriangles) {
    std::vector<ts::Float3> pos = {
        {0, 0, 1},  {1, 0, 1},  {2, 0, 1},  // collinear: zero area
        {5, 5, 1},                          // all three corners the same vertex (index 3 thrice)
        {7, 7, 1},  {7, 7, 1},  {7, 7, 1},  // three distinct vertices at one point
        {10, 0, 1}, {20, 0, 1}, {15, 1e-6f, 1},  // sliver: height 1e-6 over a base of 10
    };
    std::vector<std::array<uint32_t, 3>> tris = {{0, 1, 2}, {3, 3, 3}, {4, 5, 6}, {7, 8, 9}};
    const Built b = build(pos, tris, 0);
    ASSERT_TRUE(b.ok) << b.findings_text();
    // Rays straight through the zero-area ones: a zero-area triangle has no inside to hit.
    for (ts::Float3 o :
         {ts::Float3{1, 0, 0}, ts::Float3{0.5f, 0, 0}, ts::Float3{5, 5, 0}, ts::Float3{7, 7, 0}}) {
        const eng::Hit h = trace(b, o, {0, 0, 1});
        EXPECT_FALSE(h.hit && h.triangle_index < 3)
            << "zero-area triangle " << h.triangle_index << " hit";
    }
    // In-plane ray along the collinear triangle's line: no crash, no hit on it.
    EXPECT_FALSE(trace(b, {-1, 0, 1}, {1, 0, 0}).hit &&
                 trace(b, {-1, 0, 1}, {1, 0, 0}).triangle_index < 3);
    // Sliver: rays inside its thin interior hit, just outside miss. Compared with Embree (robust)
    // and, where they differ, with the long-double arbiter (a ray 3e-9 of the height outside an
    // edge is outside: Embree's float test says hit there).
    std::vector<ts::Float3> sp = {pos[7], pos[8], pos[9]};
    const Built sb = build(sp, {{0, 1, 2}}, 0);
    ASSERT_TRUE(sb.ok) << sb.findings_text();
    ts::ClusterScene scene;
    scene.objects.push_back(sb.bytes);
    scene.positions.push_back(sp);
    scene.triangles.push_back({{0, 1, 2}});
    scene.bounds.emplace_back();
    for (const auto& p : sp) scene.bounds[0].extend(p);
    ts::EmbreeReference embree(true);
    ts::add_to_embree(scene, embree);
    std::vector<ts::TestRay> rays;
    for (int i = 1; i < 200; ++i)
        for (float h : {1e-8f, 2e-7f, 5e-7f, 9.9e-7f, 1.01e-6f, -1e-9f}) {
            ts::TestRay r;
            r.origin = {10.0f + 10.0f * i / 200.0f, h, 0};
            r.direction = {0, 0, 1};
            rays.push_back(r);
        }
    const ts::AgreementCounts c = ts::compare_with_embree(scene, embree, rays, 1e-6);
    std::cout << "[sliver] " << c.summary() << "\n";
    for (const auto& e : c.embree_off_examples) std::cout << "    embree-off " << e << "\n";
    EXPECT_EQ(c.disagreements(), 0u) << (c.examples.empty() ? "" : c.examples[0]);
    EXPECT_GT(c.agree_hit, 300u);
}

TEST(Extremes, EveryTruncateBitCountStoresExactlyTruncatedPositions) {
    // Coordinates over many binades and both signs, in one cluster of 64 vertices / 100 triangles.
    std::mt19937 rng(99);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::uniform_int_distribution<int> e(-20, 20);
    std::vector<ts::Float3> pos;
    for (int i = 0; i < 64; ++i) {
        const float s = std::ldexp(1.0f, e(rng) / 4);
        pos.push_back({u(rng) * s, u(rng) * s, u(rng) * s + 3.0f});
    }
    std::vector<std::array<uint32_t, 3>> tris;
    std::uniform_int_distribution<uint32_t> vi(0, 63);
    for (int t = 0; t < 100; ++t) tris.push_back({vi(rng), vi(rng), vi(rng)});

    std::vector<ts::Triangle> tri_list(tris.begin(), tris.end());
    size_t size_at_0 = 0, total_off = 0;
    for (unsigned bits = 0; bits <= 32; ++bits) {
        SCOPED_TRACE("truncate " + std::to_string(bits));
        const Built b = build(pos, tris, bits, 1);
        ASSERT_TRUE(b.ok) << b.findings_text();
        const uint32_t low = bits >= 32 ? 0xFFFFFFFFu : (1u << bits) - 1u;
        const auto stored = stored_triangles(b);
        size_t checked = 0;
        for (const auto& [idx, t] : stored)
            for (int c = 0; c < 3; ++c)
                for (int k = 0; k < 3; ++k) {
                    const uint32_t got = std::bit_cast<uint32_t>(t.v[c][k]);
                    ASSERT_EQ(got & low, 0u);
                    ASSERT_EQ(got, std::bit_cast<uint32_t>(
                                       ts::truncate_float(pos[tris[idx][c]][k], bits)))
                        << "triangle " << idx << " corner " << c << " axis " << k;
                    ++checked;
                }
        // Degenerate triangles may be dropped from the BVH, never the others.
        EXPECT_GE(checked, 9u * 50u);
        // The engine must trace what it stored: compare with Embree on the truncated copy.
        std::vector<ts::Float3> tp;
        for (const auto& p : pos) tp.push_back(ts::truncate_position(p, bits));
        ts::EmbreeReference embree(true);
        embree.add_cluster(tp, tri_list);
        embree.commit();
        ts::ClusterScene scene;
        scene.objects.push_back(b.bytes);
        scene.positions.push_back(tp);
        scene.triangles.push_back(tri_list);
        ts::Bounds bb;
        for (const auto& p : tp) bb.extend(p);
        scene.bounds.push_back(bb);
        const auto rays =
            ts::random_rays(bb.diagonal() < 1e-3f ? ts::Bounds{{{-1, -1, -1}}, {{1, 1, 1}}} : bb,
                            20000, bits);
        const ts::AgreementCounts counts = ts::compare_with_embree(scene, embree, rays, 1e-6);
        EXPECT_EQ(counts.disagreements(), 0u)
            << counts.summary() << "\n"
            << (counts.examples.empty() ? "" : counts.examples[0]);
        total_off += counts.embree_off;
        if (bits == 32) {
            EXPECT_EQ(counts.agree_hit + counts.tie, 0u);
        }  // every position is +0
        if (bits == 0 || bits == 8 || bits == 16 || bits == 24 || bits == 32)
            std::cout << "[truncate " << bits << "] object " << b.bytes.size() << " B; "
                      << counts.summary() << "\n";
        if (bits == 0) size_at_0 = b.bytes.size();
        if (bits == 16) {
            EXPECT_LT(b.bytes.size(), size_at_0) << "16 truncated bits saved no space";
        }
    }
    std::cout << "[truncate 0..32] embree-off (Embree's float t or hit wrong, arbiter sides with "
                 "the engine): "
              << total_off << "\n";
}

TEST(Extremes, TruncateBitCountAbove32IsAFinding) {
    std::vector<ts::Float3> pos;
    std::vector<std::array<uint32_t, 3>> tris;
    patch(1.0f, 1.0f, pos, tris);
    for (unsigned bits : {33u, 40u, 63u}) {
        const Built b = build(pos, tris, bits);
        EXPECT_FALSE(b.findings.empty()) << "truncate " << bits << " accepted silently";
        bool names_field = false;
        for (const auto& f : b.findings)
            names_field =
                names_field || f.rule.find("positionTruncateBitCount") != std::string::npos;
        EXPECT_TRUE(names_field) << b.findings_text();
    }
}

TEST(Extremes, OutOfRangeIndicesAreFindingsAndInactive) {
    std::vector<ts::Float3> pos;
    std::vector<std::array<uint32_t, 3>> tris;
    patch(1.0f, 1.0f, pos, tris);  // 9 vertices, 8 triangles
    for (uint32_t index_bytes : {1u, 2u, 4u}) {
        auto bad = tris;
        bad[2][1] = 9;  // one past the end
        bad[5][0] = index_bytes == 1   ? 255u
                    : index_bytes == 2 ? 65535u
                                       : 0xFFFFFFFFu;  // the type's maximum
        const Built b = build(pos, bad, 0, index_bytes);
        SCOPED_TRACE("index bytes " + std::to_string(index_bytes));
        ASSERT_TRUE(b.ok) << b.findings_text();
        EXPECT_TRUE(eng::has_rule(b.findings, eng::kRuleIndexOutOfRange)) << b.findings_text();
        // One finding per cluster, counting the bad values and naming the first.
        bool counted = false;
        for (const auto& f : b.findings)
            counted = counted || (f.rule == eng::kRuleIndexOutOfRange &&
                                  f.message.find("2 index value") != std::string::npos);
        EXPECT_TRUE(counted) << b.findings_text();
        // Rays at the bad triangles' centroids (computed from the good originals) never report them.
        for (uint32_t t = 0; t < 8; ++t) {
            float cx = 0, cy = 0;
            for (uint32_t v : tris[t]) {
                cx += pos[v][0] / 3;
                cy += pos[v][1] / 3;
            }
            const eng::Hit h = trace(b, {cx, cy, 0}, {0, 0, 1});
            if (t == 2 || t == 5)
                EXPECT_FALSE(h.hit && (h.triangle_index == 2 || h.triangle_index == 5));
            else {
                EXPECT_TRUE(h.hit && h.triangle_index == t) << "good triangle " << t;
            }
        }
    }
    // vertexCount smaller than the indices used: the same finding, never a read past vertexCount.
    const Built b = build(pos, tris, 0, 4, 4);
    ASSERT_TRUE(b.ok) << b.findings_text();
    EXPECT_TRUE(eng::has_rule(b.findings, eng::kRuleIndexOutOfRange)) << b.findings_text();
}

// Every stored triangle keeps its own three local indices, at every triangle count and index
// size, whatever the BVH order; an inactive one (an index >= vertexCount) stores zeros.
TEST(Extremes, StoredIndicesFollowTheirTrianglesAtEveryCount) {
    std::vector<ts::Float3> pos;
    for (int v = 0; v < 256; ++v) pos.push_back({float(v % 16), float((v * 7) % 5), float(v / 16)});
    std::vector<std::array<uint32_t, 3>> all;
    for (uint32_t t = 0; t < 256; ++t) {
        const uint32_t v = (t * 37) % 239;
        all.push_back({v, v + 1, v + 16});
    }
    for (uint32_t index_bytes : {1u, 4u})
        for (uint32_t n = 1; n <= 256; n += (n < 40 ? 1 : 9)) {
            std::vector<std::array<uint32_t, 3>> tris(all.begin(), all.begin() + n);
            if (index_bytes == 4)
                for (uint32_t t = 3; t < n; t += 11) tris[t][t % 3] = 256 + t;  // inactive
            const Built b = build(pos, tris, 0, index_bytes);
            ASSERT_TRUE(b.ok) << b.findings_text();
            const eng::HeaderCheck hc = eng::read_object_header(b.bytes);
            ASSERT_TRUE(hc.header) << hc.error;
            ASSERT_EQ(hc.header->triangle_count, n);
            for (uint32_t i = 0; i < n; ++i) {
                const eng::DecodedTriangle d = eng::decode_triangle(b.bytes, *hc.header, i);
                ASSERT_LT(d.original_index, n);
                const auto& want = tris[d.original_index];
                const bool inactive = want[0] > 255 || want[1] > 255 || want[2] > 255;
                for (int k = 0; k < 3; ++k)
                    EXPECT_EQ(d.local_indices[k], inactive ? 0u : want[k])
                        << "count " << n << ", index bytes " << index_bytes << ", stored " << i;
            }
        }
}

TEST(Extremes, FullClusters256TrianglesAnd256Vertices) {
    // 256 vertices on a wavy 16x16 grid; 256 triangles that together use every vertex.
    std::vector<ts::Float3> pos;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x)
            pos.push_back({float(x), float(y), 0.3f * std::sin(x * 0.7f) * std::cos(y * 0.4f)});
    std::vector<std::array<uint32_t, 3>> tris;
    for (uint32_t i = 0; i < 240; ++i) tris.push_back({i, i + 1, i + 16});
    for (uint32_t i = 0; i < 16; ++i) tris.push_back({i * 15, i * 15 + 17, i * 15 + 16});
    ASSERT_EQ(tris.size(), 256u);
    std::vector<ts::Triangle> tri_list(tris.begin(), tris.end());
    ts::Bounds bb;
    for (const auto& p : pos) bb.extend(p);
    for (uint32_t index_bytes : {1u, 2u, 4u})
        for (unsigned bits : {0u, 12u}) {
            SCOPED_TRACE("index bytes " + std::to_string(index_bytes) + " truncate " +
                         std::to_string(bits));
            const Built b = build(pos, tris, bits, index_bytes);
            ASSERT_TRUE(b.ok) << b.findings_text();
            EXPECT_TRUE(b.findings.empty()) << b.findings_text();
            const auto hc = eng::read_object_header(b.bytes);
            ASSERT_TRUE(hc.header) << hc.error;
            EXPECT_EQ(hc.header->triangle_count, 256u);
            EXPECT_EQ(hc.header->vertex_count, 256u);
            std::vector<ts::Float3> tp;
            for (const auto& p : pos) tp.push_back(ts::truncate_position(p, bits));
            ts::EmbreeReference embree(true);
            embree.add_cluster(tp, tri_list);
            embree.commit();
            ts::ClusterScene scene;
            scene.objects.push_back(b.bytes);
            scene.bounds.push_back(bb);
            scene.positions.push_back(tp);
            scene.triangles.push_back(tri_list);
            const auto counts =
                ts::compare_with_embree(scene, embree, ts::random_rays(bb, 50000, 3), 1e-6);
            EXPECT_EQ(counts.disagreements(), 0u) << counts.summary();
            EXPECT_GT(counts.agree_hit, 10000u);
        }
    // 257 triangles is beyond maxTrianglesPerCluster: a finding naming the VUID, not a crash.
    auto over = tris;
    over.push_back({0, 1, 16});
    const Built b = build(pos, over, 0, 2);
    EXPECT_FALSE(b.findings.empty());
    bool vuid = false;
    for (const auto& f : b.findings)
        vuid = vuid || f.rule.find("triangleCount") != std::string::npos;
    EXPECT_TRUE(vuid) << b.findings_text();
}
