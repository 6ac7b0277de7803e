// SPDX-License-Identifier: Apache-2.0
// Traversal: agreement with an independent brute-force reference, watertightness on
// closed meshes (also truncated), facing and culling flags, opacity, extremes, NaN
// inactivity, position independence.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <map>
#include <limits>
#include <random>

namespace clastrace::engine {
namespace {

using test::Arena;

std::vector<std::byte> build(const std::vector<float>& pos, const std::vector<uint32_t>& idx,
                             uint32_t bits = 0, uint32_t base_gif = 0,
                             const std::vector<uint32_t>& gif = {}) {
    ClusterBuilder b;
    std::vector<std::byte> out;
    std::vector<Finding> f;
    EXPECT_TRUE(b.build_from_arrays(3, pos, idx, bits, base_gif, gif, out, f));
    return out;
}

// Reference: Moeller-Trumbore in long double over every triangle, returning the
// barycentric margin so that near-edge rays can be skipped in the comparison.
struct RefHit {
    bool hit = false;
    long double t = 0;
    uint32_t tri = 0;
    long double margin = 0;
};
RefHit reference(const std::vector<std::byte>& bytes, const Ray& r) {
    const auto h = read_object_header(bytes).header;
    RefHit best;
    for (uint32_t i = 0; i < h->triangle_count; ++i) {
        const DecodedTriangle d = decode_triangle(bytes, *h, i);
        bool nan = false;
        for (auto& v : d.v)
            for (float c : v) nan |= std::isnan(c);
        if (nan) continue;
        long double e1[3], e2[3], p[3], s[3], q[3];
        for (int k = 0; k < 3; ++k) {
            e1[k] = (long double)d.v[1][k] - d.v[0][k];
            e2[k] = (long double)d.v[2][k] - d.v[0][k];
            s[k] = (long double)r.origin[k] - d.v[0][k];
        }
        const long double* dir = nullptr;
        long double D[3] = {r.direction[0], r.direction[1], r.direction[2]};
        dir = D;
        p[0] = dir[1] * e2[2] - dir[2] * e2[1];
        p[1] = dir[2] * e2[0] - dir[0] * e2[2];
        p[2] = dir[0] * e2[1] - dir[1] * e2[0];
        const long double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
        if (det == 0) continue;
        const long double u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) / det;
        q[0] = s[1] * e1[2] - s[2] * e1[1];
        q[1] = s[2] * e1[0] - s[0] * e1[2];
        q[2] = s[0] * e1[1] - s[1] * e1[0];
        const long double v = (dir[0] * q[0] + dir[1] * q[1] + dir[2] * q[2]) / det;
        const long double t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det;
        const long double margin = std::min({u, v, 1 - u - v});
        if (margin < 0 || t < r.tmin || t > r.tmax) continue;
        if (!best.hit || t < best.t) best = {true, t, d.original_index, margin};
    }
    return best;
}

TEST(Traversal, AgreesWithBruteForceReference) {
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> U(-1.0f, 1.0f);
    uint64_t compared = 0;
    for (int cluster = 0; cluster < 40; ++cluster) {
        std::vector<float> pos;
        std::vector<uint32_t> idx;
        const uint32_t V = 3 + rng() % 254, T = 1 + rng() % 256;
        const float spread = cluster % 2 ? 10.0f : 1.0f;
        for (uint32_t v = 0; v < V; ++v)
            pos.insert(pos.end(), {U(rng) * spread, U(rng) * spread, U(rng) * spread});
        for (uint32_t t = 0; t < T; ++t)
            idx.insert(idx.end(), {uint32_t(rng() % V), uint32_t(rng() % V), uint32_t(rng() % V)});
        const uint32_t bits = cluster % 3 == 0 ? 0 : rng() % 24;
        const auto bytes = build(pos, idx, bits);
        const auto view = open_clas(bytes);
        ASSERT_TRUE(view);
        for (int k = 0; k < 300; ++k) {
            Ray r{{U(rng) * 2 * spread, U(rng) * 2 * spread, U(rng) * 2 * spread},
                  0.0f,
                  {U(rng), U(rng), U(rng)},
                  1e30f};
            if (k % 5 == 0) r.tmax = std::fabs(U(rng)) * spread;
            const RefHit ref = reference(bytes, r);
            if (ref.hit && ref.margin < 1e-5) continue;  // edge cases are the watertight tests' job
            const Hit hit = trace_closest(*view, r, 0);
            ASSERT_EQ(hit.hit, ref.hit) << "cluster " << cluster << " ray " << k;
            EXPECT_EQ(trace_any(*view, r, 0), ref.hit);
            if (!ref.hit) continue;
            EXPECT_NEAR(hit.t, double(ref.t), 1e-6 * std::fabs(double(ref.t)) + 1e-30)
                << "cluster " << cluster << " ray " << k;
            // Coinciding triangles (random soups repeat vertices) may be picked either way at
            // equal t; otherwise it is the same triangle.
            if (hit.triangle_index != ref.tri) {
                EXPECT_NEAR(hit.t, double(ref.t), 1e-7 * std::fabs(double(ref.t)))
                    << "different triangle at a different t";
            }
            ++compared;
        }
    }
    EXPECT_GT(compared, 1000u);
}

// A closed, subdivided octahedron with shared vertices.
test::Mesh octahedron(int subdiv, float scale, float jitter_seed) {
    test::Mesh m;
    const float P[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    const int F[8][3] = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                         {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
    std::mt19937 rng(uint32_t(jitter_seed * 1000));
    std::uniform_real_distribution<float> J(0.9f, 1.1f);
    std::map<std::array<int, 3>, uint32_t> ids;  // lattice key -> vertex
    const int n = 1 << subdiv;
    auto vertex = [&](int f, int i, int j) {
        const int k = n - i - j;
        float p[3];
        int key[3];
        for (int c = 0; c < 3; ++c) {
            const float x = (P[F[f][0]][c] * i + P[F[f][1]][c] * j + P[F[f][2]][c] * k) / float(n);
            p[c] = x;
            key[c] = int(std::lround(x * n));
        }
        auto [it, fresh] =
            ids.try_emplace({key[0], key[1], key[2]}, uint32_t(m.positions.size() / 3));
        if (fresh) {
            const float s = J(rng) * scale;
            m.positions.insert(m.positions.end(), {p[0] * s, p[1] * s, p[2] * s});
        }
        return it->second;
    };
    for (int f = 0; f < 8; ++f)
        for (int i = 0; i < n; ++i)
            for (int j = 0; i + j < n; ++j) {
                const uint32_t a = vertex(f, i, j), b = vertex(f, i + 1, j),
                               c = vertex(f, i, j + 1);
                m.indices.insert(m.indices.end(), {a, b, c});
                if (i + j + 1 < n) {
                    const uint32_t d = vertex(f, i + 1, j + 1);
                    m.indices.insert(m.indices.end(), {b, d, c});
                }
            }
    return m;
}

TEST(Traversal, ClosedMeshNeverLeaksThroughEdgesOrVertices) {
    uint64_t rays = 0;
    for (uint32_t bits : {0u, 4u, 12u, 18u}) {
        for (float scale : {1.0f, 1000.0f, 1e-3f, 3e30f}) {
            const test::Mesh m =
                octahedron(2, scale, float(bits) + 1.0f);  // 8 * 16 = 128 triangles
            ASSERT_LE(m.indices.size() / 3, 256u);
            const auto bytes = build(m.positions, m.indices, bits);
            const auto view = open_clas(bytes);
            ASSERT_TRUE(view);
            const auto h = view->header;
            // Targets: every stored vertex and every edge midpoint (in stored, truncated positions).
            std::vector<std::array<float, 3>> targets;
            for (uint32_t v = 0; v < h.vertex_count; ++v) {
                float p[3];
                decode_position(bytes, h, v, p);
                targets.push_back({p[0], p[1], p[2]});
            }
            for (uint32_t i = 0; i < h.triangle_count; ++i) {
                const DecodedTriangle d = decode_triangle(bytes, h, i);
                for (int e = 0; e < 3; ++e) {
                    const float* a = d.v[e];
                    const float* b = d.v[(e + 1) % 3];
                    targets.push_back({a[0] * 0.5f + b[0] * 0.5f, a[1] * 0.5f + b[1] * 0.5f,
                                       a[2] * 0.5f + b[2] * 0.5f});
                }
            }
            // From the centre outwards, and from outside inwards through the centre: every ray
            // must hit (the mesh encloses the centre).
            std::mt19937 rng(bits);
            std::uniform_real_distribution<float> J(-0.01f, 0.01f);
            for (size_t ti = 0; ti < targets.size(); ++ti) {
                const auto& t = targets[ti];
                // Even targets: from the exact centre, so the ray passes exactly through the
                // vertex (direction == target); odd targets: from a jittered centre.
                const float jitter = ti % 2 ? scale : 0.0f;
                const float c[3] = {J(rng) * jitter, J(rng) * jitter, J(rng) * jitter};
                Ray out{{c[0], c[1], c[2]}, 0.0f, {t[0] - c[0], t[1] - c[1], t[2] - c[2]}, 1e38f};
                EXPECT_TRUE(trace_any(*view, out, 0))
                    << "leak outwards, bits " << bits << " scale " << scale;
                const Hit h1 = trace_closest(*view, out, 0);
                EXPECT_TRUE(h1.hit);
                EXPECT_FALSE(h1.front_face)
                    << "from inside, the outward-wound surface is seen from its back";
                Ray in{{c[0] - 3 * out.direction[0], c[1] - 3 * out.direction[1],
                        c[2] - 3 * out.direction[2]},
                       0.0f,
                       {out.direction[0], out.direction[1], out.direction[2]},
                       1e38f};
                EXPECT_TRUE(trace_any(*view, in, 0))
                    << "leak inwards, bits " << bits << " scale " << scale;
                rays += 2;
            }
        }
    }
    EXPECT_GT(rays, 2000u);
}

TEST(Traversal, FrontFaceIsClockwiseFromTheRayOrigin) {
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> U(-1.0f, 1.0f);
    int checked = 0;
    for (int i = 0; i < 500; ++i) {
        std::vector<float> pos;
        for (int k = 0; k < 9; ++k) pos.push_back(U(rng));
        const auto bytes = build(pos, {0, 1, 2});
        const float c[3] = {(pos[0] + pos[3] + pos[6]) / 3, (pos[1] + pos[4] + pos[7]) / 3,
                            (pos[2] + pos[5] + pos[8]) / 3};
        Ray r{{U(rng) * 3, U(rng) * 3, U(rng) * 3}, 0.0f, {}, 1e30f};
        for (int k = 0; k < 3; ++k) r.direction[k] = c[k] - r.origin[k];
        const Hit h = trace_closest(bytes, r, 0);
        if (!h.hit) continue;
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) {
            e1[k] = double(pos[3 + k]) - pos[k];
            e2[k] = double(pos[6 + k]) - pos[k];
        }
        const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                             e1[0] * e2[1] - e1[1] * e2[0]};
        const double dn = n[0] * r.direction[0] + n[1] * r.direction[1] + n[2] * r.direction[2];
        EXPECT_EQ(h.front_face, dn < 0) << "dot(d, n) = " << dn;
        EXPECT_EQ(trace_closest(bytes, r, kRayFlagCullBackFacingTriangles).hit, h.front_face);
        EXPECT_EQ(trace_closest(bytes, r, kRayFlagCullFrontFacingTriangles).hit, !h.front_face);
        ++checked;
    }
    EXPECT_GT(checked, 400);
    // A fixed case: looking down -z at a triangle that is counter-clockwise in the xy plane
    // (normal +z, towards the viewer): front-facing in Vulkan's default.
    const auto ccw = build({0, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 2});
    Ray down{{0.25f, 0.25f, 1}, 0, {0, 0, -1}, 10};
    EXPECT_TRUE(trace_closest(ccw, down, 0).front_face);
}

TEST(Traversal, CullDisableGeometryFlagAndOpacity) {
    const uint32_t opaque = uint32_t(VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV)
                            << 29;
    const uint32_t cull_disable =
        uint32_t(VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_CULL_DISABLE_BIT_NV) << 29;
    const std::vector<float> pos = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    Ray up{{0.25f, 0.25f, -1}, 0, {0, 0, 1}, 10};  // sees the back of the CCW triangle
    const auto plain = build(pos, {0, 1, 2}, 0, opaque | 5);
    const Hit h = trace_closest(plain, up, 0);
    ASSERT_TRUE(h.hit);
    EXPECT_FALSE(h.front_face);
    EXPECT_TRUE(h.opaque);
    EXPECT_EQ(h.geometry_index, 5u);
    EXPECT_FALSE(trace_closest(plain, up, kRayFlagCullBackFacingTriangles).hit);
    const auto nocull = build(pos, {0, 1, 2}, 0, opaque | cull_disable);
    EXPECT_TRUE(trace_closest(nocull, up, kRayFlagCullBackFacingTriangles).hit);
    EXPECT_FALSE(trace_closest(plain, up, kRayFlagCullOpaque).hit);
    EXPECT_TRUE(trace_closest(plain, up, kRayFlagCullNoOpaque).hit);
    EXPECT_TRUE(trace_closest(plain, up, kRayFlagNoOpaque | kRayFlagCullOpaque).hit)
        << "NoOpaque makes it non-opaque";
    EXPECT_FALSE(trace_closest(plain, up, kRayFlagNoOpaque | kRayFlagCullNoOpaque).hit);
    const auto translucent = build(pos, {0, 1, 2}, 0, 0);
    EXPECT_FALSE(trace_closest(translucent, up, 0).opaque);
    EXPECT_TRUE(trace_closest(translucent, up, kRayFlagOpaque).opaque);
    EXPECT_FALSE(trace_closest(translucent, up, kRayFlagOpaque | kRayFlagCullOpaque).hit);
}

TEST(Traversal, IntervalIsClosedAndClosestWins) {
    // Two parallel triangles at z = 1 and z = 2.
    const auto bytes =
        build({0, 0, 1, 4, 0, 1, 0, 4, 1, 0, 0, 2, 4, 0, 2, 0, 4, 2}, {0, 1, 2, 3, 4, 5});
    Ray r{{0.5f, 0.5f, 0}, 0, {0, 0, 1}, 10};
    Hit h = trace_closest(bytes, r, 0);
    ASSERT_TRUE(h.hit);
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_EQ(h.triangle_index, 0u);
    EXPECT_FLOAT_EQ(h.u, 0.125f);
    EXPECT_FLOAT_EQ(h.v, 0.125f);
    r.tmax = 1.0f;
    EXPECT_TRUE(trace_closest(bytes, r, 0).hit) << "t == tmax is inside";
    r.tmax = 0.99999f;
    EXPECT_FALSE(trace_any(bytes, r, 0));
    r.tmin = 1.5f;
    r.tmax = 2.0f;
    h = trace_closest(bytes, r, 0);
    EXPECT_EQ(h.triangle_index, 1u);
    r.tmin = 2.0f;
    EXPECT_TRUE(trace_closest(bytes, r, 0).hit) << "t == tmin is inside";
    r.tmin = 3.0f;
    r.tmax = 1.0f;
    EXPECT_FALSE(trace_any(bytes, r, 0));
    Ray first{{0.5f, 0.5f, 0}, 0, {0, 0, 1}, 10};
    EXPECT_TRUE(trace_closest(bytes, first, kRayFlagTerminateOnFirstHit).hit);
}

TEST(Traversal, NaNTrianglesAreInactive) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    // Triangle 0 has a NaN vertex; triangle 1 is fine and behind it.
    const auto bytes =
        build({0, 0, 1, 4, 0, 1, 0, 4, nan, 0, 0, 2, 4, 0, 2, 0, 4, 2}, {0, 1, 2, 3, 4, 5});
    const auto h = read_object_header(bytes).header;
    EXPECT_TRUE(h->header_flags & kHasNaNTriangles);
    EXPECT_EQ(h->bounds_min[2], 2.0f) << "bounds cover active triangles only";
    Ray r{{0.5f, 0.5f, 0}, 0, {0, 0, 1}, 10};
    const Hit hit = trace_closest(bytes, r, 0);
    ASSERT_TRUE(hit.hit);
    EXPECT_EQ(hit.triangle_index, 1u);
    // All NaN: nothing to hit, and still a valid object.
    const auto none = build({nan, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 2});
    EXPECT_TRUE(open_clas(none));
    EXPECT_FALSE(trace_any(none, r, 0));
    // Truncation can turn a NaN into an infinity (mantissa bits cleared): then it is active.
    const float snan_low = std::bit_cast<float>(0x7F800001u);
    const auto truncated = build({0, 0, 1, 4, 0, 1, 0, 4, snan_low}, {0, 1, 2}, 1);
    EXPECT_FALSE(read_object_header(truncated).header->header_flags & kHasNaNTriangles);
}

TEST(Traversal, Extremes) {
    const float big = 3.0e38f, tiny = 1e-38f, denorm = 1e-44f,
                inf = std::numeric_limits<float>::infinity();
    // Huge triangle spanning almost the whole float range.
    const auto huge = build({-big, -big, 0, big, -big, 0, 0, big, 0}, {0, 1, 2});
    Ray r{{1e37f, -1e37f, big}, 0, {0, 0, -1}, inf};
    Hit h = trace_closest(huge, r, 0);
    ASSERT_TRUE(h.hit);
    EXPECT_EQ(h.t, big);
    // Tiny triangle near 1e-38 and a denormal one.
    const auto small = build({0, 0, 0, tiny, 0, 0, 0, tiny, 0}, {0, 1, 2});
    Ray rs{{tiny / 4, tiny / 4, 1}, 0, {0, 0, -1}, 2};
    EXPECT_TRUE(trace_any(small, rs, 0));
    const auto den = build({0, 0, 0, denorm, 0, 0, 0, denorm, 0}, {0, 1, 2});
    Ray rd{{denorm / 4, denorm / 4, 1}, 0, {0, 0, -1}, 2};
    EXPECT_TRUE(trace_any(den, rd, 0));
    // An infinite vertex: active (only NaN is inactive), node boxes become unbounded.
    const auto with_inf =
        build({0, 0, 0, 1, 0, 0, 0, 1, inf, 5, 5, 1, 6, 5, 1, 5, 6, 1}, {0, 1, 2, 3, 4, 5});
    EXPECT_TRUE(read_object_header(with_inf).header->header_flags & kUnboundedNodes);
    Ray ri{{5.2f, 5.2f, 3}, 0, {0, 0, -1}, 10};
    EXPECT_TRUE(trace_any(with_inf, ri, 0));
    // Zero-area, sliver and all-identical triangles: no hit, no crash.
    const auto degenerate =
        build({1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 2, 2, 0, 1, 1, 0}, {0, 1, 2, 3, 4, 5});
    Ray rz{{1, 1, 2}, 0, {0, 0, -1}, 10};
    EXPECT_FALSE(trace_any(degenerate, rz, 0));
    const auto sliver = build({0, 0, 0, 1, 0, 0, 0.5f, 1e-30f, 0}, {0, 1, 2});
    Ray rv{{0.5f, 1e-31f, 1}, 0, {0, 0, -1}, 10};
    EXPECT_TRUE(trace_any(sliver, rv, 0));
    // Truncation 32: every position is +0: everything degenerate.
    const auto flat = build({0, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 2}, 32);
    EXPECT_FALSE(trace_any(flat, Ray{{0.1f, 0.1f, 1}, 0, {0, 0, -1}, 10}, 0));
    // Degenerate rays.
    const auto tri = build({0, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 2});
    EXPECT_FALSE(trace_any(tri, Ray{{0.1f, 0.1f, 1}, 0, {0, 0, 0}, 10}, 0));
    EXPECT_FALSE(trace_any(tri, Ray{{std::nanf(""), 0.1f, 1}, 0, {0, 0, -1}, 10}, 0));
    EXPECT_TRUE(trace_any(tri, Ray{{0.1f, 0.1f, 1}, 0, {0, 0, -denorm}, inf}, 0));
}

TEST(Traversal, PositionIndependentCopyTracesIdentically) {
    const test::Mesh m = test::grid(10, 0.7f, 4);  // 200 triangles
    Arena arena;
    auto info = test::cluster_info(arena, m);
    info.positionTruncateBitCount = 9;
    const auto o =
        build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
    ASSERT_TRUE(o.ok);
    // Write it to device memory, then copy it elsewhere with a plain byte copy (odd offset).
    const uint64_t a = arena.put(o.bytes.data(), o.bytes.size(), 128);
    const uint64_t b = arena.alloc(o.bytes.size() + 3, 128) + 3;
    const auto src = arena.memory.read_bytes(a, o.bytes.size(), {"copy", 0});
    std::vector<std::byte> tmp(src.begin(), src.end());
    std::memcpy(arena.memory.write_bytes(b, tmp.size(), {"copy", 0}).data(), tmp.data(),
                tmp.size());
    const auto moved =
        arena.memory.read_bytes(b,
                                object_size_from_header(arena.memory.read_bytes(b, 96, {"h", 0})),
                                {"m", 0});
    ASSERT_EQ(moved.size(), o.bytes.size());
    const auto v1 = open_clas(o.bytes);
    const auto v2 = open_clas(moved);
    ASSERT_TRUE(v1 && v2);
    std::mt19937 rng(8);
    std::uniform_real_distribution<float> U(-1.0f, 8.0f);
    int hits = 0;
    for (int k = 0; k < 2000; ++k) {
        Ray r{{U(rng), U(rng), 3.0f}, 0.0f, {U(rng) * 0.1f, U(rng) * 0.1f, -1.0f}, 100.0f};
        const Hit h1 = trace_closest(*v1, r, 0), h2 = trace_closest(*v2, r, 0);
        ASSERT_EQ(h1.hit, h2.hit);
        hits += h1.hit;
        EXPECT_EQ(h1.t, h2.t);
        EXPECT_EQ(h1.triangle_index, h2.triangle_index);
        EXPECT_EQ(h1.u, h2.u);
    }
    EXPECT_GT(hits, 1000);
}

TEST(Traversal, CorruptObjectsAreRejectedOrTracedSafely) {
    // Deterministic random mutation: every mutated object either fails the header check
    // or traces without reading outside itself (run under ASan/UBSan in CI).
    const test::Mesh m = test::grid(9, 1.0f, 2);
    std::vector<uint32_t> gif(m.indices.size() / 3);
    for (size_t i = 0; i < gif.size(); ++i) gif[i] = uint32_t(i % 4);
    const auto good = build(m.positions, m.indices, 7, 0, gif);
    std::mt19937 rng(1234);
    int rejected = 0, traced = 0;
    for (int trial = 0; trial < 3000; ++trial) {
        std::vector<std::byte> bad = good;
        const int flips = 1 + rng() % 4;
        for (int f = 0; f < flips; ++f) {
            const size_t at = trial % 3 == 0 ? rng() % 96 : rng() % bad.size();  // the header often
            bad[at] = std::byte(rng());
        }
        if (trial % 7 == 0) bad.resize(rng() % bad.size());
        std::string error;
        const auto view = open_clas(bad, &error);
        if (!view) {
            EXPECT_FALSE(error.empty());
            ++rejected;
            continue;
        }
        for (int k = 0; k < 4; ++k) {
            Ray r{{float(rng() % 9), float(rng() % 9), 2.0f}, 0.0f, {0.01f, 0.02f, -1.0f}, 10.0f};
            (void)trace_closest(*view, r, rng());
        }
        ++traced;
    }
    EXPECT_GT(rejected, 100);
    EXPECT_GT(traced, 100);
}

}  // namespace
}  // namespace clastrace::engine
