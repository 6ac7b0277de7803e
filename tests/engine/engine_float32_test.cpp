// SPDX-License-Identifier: Apache-2.0
// TraversalMode::kFloat32 against kDouble on one CLAS: where they must agree (ordinary rays),
// the extremes (1e30 and 1e-30 coordinates, a 1e-3 triangle seen from 4e4, NaN and
// degenerate triangles) and watertightness: a ray through a shared edge or vertex hits at
// least one of the triangles there, never none.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/traversal.h"

#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>
#include <random>
#include <utility>
#include <vector>

namespace clastrace::engine {
namespace {

constexpr TraversalMode kF32 = TraversalMode::kFloat32;
constexpr TraversalMode kF64 = TraversalMode::kDouble;

std::vector<std::byte> build(const std::vector<float>& pos, const std::vector<uint32_t>& idx) {
    ClusterBuilder b;
    std::vector<std::byte> out;
    std::vector<Finding> f;
    EXPECT_TRUE(b.build_from_arrays(3, pos, idx, 0, 0, {}, out, f));
    return out;
}

// An n x n grid of quads in z = 0 over [-s, s]^2, two triangles each.
std::vector<std::byte> grid(uint32_t n, float s, float z = 0.0f) {
    std::vector<float> pos;
    std::vector<uint32_t> idx;
    for (uint32_t y = 0; y <= n; ++y)
        for (uint32_t x = 0; x <= n; ++x) {
            pos.push_back(-s + 2 * s * float(x) / float(n));
            pos.push_back(-s + 2 * s * float(y) / float(n));
            pos.push_back(z);
        }
    for (uint32_t y = 0; y < n; ++y)
        for (uint32_t x = 0; x < n; ++x) {
            const uint32_t a = y * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
            idx.insert(idx.end(), {a, b, d, a, d, c});
        }
    return build(pos, idx);
}

TEST(Float32Traversal, AgreesWithDoubleOnOrdinaryRays) {
    const auto clas = grid(8, 1.0f);
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(-1.2f, 1.2f);
    int hits = 0;
    for (int i = 0; i < 4000; ++i) {
        const Ray r{{u(rng), u(rng), -3.0f}, 0.0f, {0.1f * u(rng), 0.1f * u(rng), 1.0f}, 100.0f};
        const Hit a = trace_closest(clas, r, 0, kF64), b = trace_closest(clas, r, 0, kF32);
        // Within 1e-4 of an edge the modes may pick either neighbour; elsewhere the same.
        if (a.hit && std::min({a.u, a.v, 1 - a.u - a.v}) < 1e-4f) continue;
        ASSERT_EQ(a.hit, b.hit) << i;
        if (!a.hit) continue;
        ++hits;
        EXPECT_EQ(a.triangle_index, b.triangle_index) << i;
        EXPECT_NEAR(a.t, b.t, 1e-5f * a.t) << i;
        EXPECT_NEAR(a.u, b.u, 1e-5f) << i;
        EXPECT_EQ(a.front_face, b.front_face) << i;
    }
    EXPECT_GT(hits, 2000);
}

// Rays exactly through the grid's shared edges and vertices: watertight in both modes.
TEST(Float32Traversal, SharedEdgesAndVerticesNeverLeak) {
    const auto clas = grid(4, 1.0f);
    int rays = 0;
    for (const TraversalMode mode : {kF64, kF32})
        for (int y = -8; y <= 8; ++y)
            for (int x = -8; x <= 8; ++x) {
                // x, y on quarter steps: vertices, edges, diagonals (x == y) and quad centers.
                const Ray r{{x * 0.125f, y * 0.125f, -1.0f}, 0.0f, {0.0f, 0.0f, 1.0f}, 10.0f};
                EXPECT_TRUE(trace_any(clas, r, 0, mode)) << traversal_mode_name(mode) << x << y;
                // A slanted ray crossing the diagonal x == y from far away.
                const Ray s{{x * 0.125f - 1e3f, y * 0.125f - 1e3f, -1e3f},
                            0.0f,
                            {1.0f, 1.0f, 1.0f},
                            1e4f};
                EXPECT_TRUE(trace_any(clas, s, 0, mode)) << traversal_mode_name(mode) << x << y;
                rays += 2;
            }
    EXPECT_EQ(rays, 2 * 2 * 17 * 17);
}

TEST(Float32Traversal, HugeAndTinyCoordinates) {
    for (const float s : {1e30f, 1e-30f}) {
        const auto clas = grid(2, s, 0.5f * s);
        const Ray r{{0.3f * s, 0.2f * s, -s}, 0.0f, {0.0f, 0.0f, 1.0f}, 1e38f};
        for (const TraversalMode mode : {kF64, kF32}) {
            const Hit h = trace_closest(clas, r, 0, mode);
            ASSERT_TRUE(h.hit) << s << traversal_mode_name(mode);
            EXPECT_NEAR(h.t, 1.5f * s, 1e-5f * s) << s << traversal_mode_name(mode);
        }
    }
}

// A 1e-3 triangle seen from 4e4: both modes hit it at the same t; the barycentrics are float
// noise in float32, and the hit says so (uv_error).
TEST(Float32Traversal, TinyTriangleFarAway) {
    const auto clas = build({0, 0, 0, 1e-3f, 0, 0, 0, 1e-3f, 0}, {0, 1, 2});
    const Ray r{{2.5e-4f, 2.5e-4f, -4e4f}, 0.0f, {0.0f, 0.0f, 1.0f}, 1e5f};
    const Hit a = trace_closest(clas, r, 0, kF64), b = trace_closest(clas, r, 0, kF32);
    ASSERT_TRUE(a.hit);
    ASSERT_TRUE(b.hit);
    EXPECT_NEAR(a.t, b.t, 8 * FLT_EPSILON * a.t);
    EXPECT_NEAR(a.u, 0.25f, 1e-4f);  // double: exact
    EXPECT_GT(b.uv_error, 1e-3f);    // float32: shear of 4e4-sized coordinates
    EXPECT_NEAR(b.u, a.u, b.uv_error);
    // Off the axis the shear mixes 4e4 into x and y: the float answer is noise, still a hit.
    const Ray slanted{{2.5e-4f - 4e3f, 2.5e-4f, -4e4f}, 0.0f, {0.1f, 0.0f, 1.0f}, 1e5f};
    EXPECT_TRUE(trace_any(clas, slanted, 0, kF64));
}

// The float determinant of the watertight test as a float32 pipeline computes it (the
// dimension permutation, the shear and the edge functions in float, tests/engine's own copy
// of the arithmetic): its sign is the facing such a pipeline reports.
float float_determinant(const Ray& r, const float* p0, const float* p1, const float* p2) {
    int kz = 0;
    if (std::fabs(r.direction[1]) > std::fabs(r.direction[kz])) kz = 1;
    if (std::fabs(r.direction[2]) > std::fabs(r.direction[kz])) kz = 2;
    int kx = (kz + 1) % 3, ky = (kx + 1) % 3;
    if (r.direction[kz] < 0.0f) std::swap(kx, ky);
    const float sx = r.direction[kx] / r.direction[kz], sy = r.direction[ky] / r.direction[kz];
    const float* p[3] = {p0, p1, p2};
    float x[3], y[3];
    for (int i = 0; i < 3; ++i) {
        const float a[3] = {p[i][0] - r.origin[0], p[i][1] - r.origin[1], p[i][2] - r.origin[2]};
        x[i] = a[kx] - sx * a[kz];
        y[i] = a[ky] - sy * a[kz];
    }
    const float u = x[2] * y[1] - y[2] * x[1], v = x[0] * y[2] - y[0] * x[2],
                w = x[1] * y[0] - y[1] * x[0];
    return u + v + w;
}

// Nearly edge-on slivers 1e3 away: the ray lies almost in the triangle's plane, the float
// determinant's rounding decides the facing. float32 reports that facing (the driver's),
// double the exact winding; some slivers must tell the two apart, or nothing was tested.
TEST(Float32Traversal, NearlyEdgeOnFacingFollowsTheFloatDeterminant) {
    std::mt19937 rng(31);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int float_hits = 0, flipped = 0;
    for (int i = 0; i < 4000; ++i) {
        const float c[3] = {700.0f + 300.0f * u(rng), 700.0f + 300.0f * u(rng), 700.0f * u(rng)};
        const Ray r{{3.1f * u(rng), 2.7f * u(rng), 1.3f * u(rng)}, 0.0f, {0, 0, 0}, 1e5f};
        double d[3], len = 0;
        for (int k = 0; k < 3; ++k) {
            d[k] = double(c[k]) - r.origin[k];
            len += d[k] * d[k];
        }
        Ray ray = r;
        for (int k = 0; k < 3; ++k) ray.direction[k] = float(d[k] / std::sqrt(len));
        // e1, e2: unit vectors across the ray; the sliver spans e1 and the ray, tilted by
        // `tilt` along e2 (1e-6 to 1e-3 of its size), so seen along the ray it is that thin.
        const double n0[3] = {-d[1], d[0], 0.0};
        const double l0 = std::sqrt(n0[0] * n0[0] + n0[1] * n0[1]);
        const double e1[3] = {n0[0] / l0, n0[1] / l0, 0.0};
        const double dn[3] = {d[0] / std::sqrt(len), d[1] / std::sqrt(len), d[2] / std::sqrt(len)};
        const double e2[3] = {dn[1] * e1[2] - dn[2] * e1[1], dn[2] * e1[0] - dn[0] * e1[2],
                              dn[0] * e1[1] - dn[1] * e1[0]};
        const double tilt = std::pow(10.0, -6.0 + 3.0 * (0.5 + 0.5 * u(rng)));
        const double side = u(rng) < 0 ? -1.0 : 1.0;
        std::vector<float> pos(9);
        const double k0[3] = {1.0, -1.0, 0.0}, kd[3] = {-1.0, -1.0, 1.0}, kt[3] = {-0.5, -0.5, 1.0};
        for (int v = 0; v < 3; ++v)
            for (int k = 0; k < 3; ++k)
                pos[3 * v + k] =
                    float(c[k] + e1[k] * k0[v] + dn[k] * kd[v] + side * e2[k] * tilt * kt[v]);
        const auto clas = build(pos, {0, 1, 2});
        const Hit f = trace_closest(clas, ray, 0, kF32), x = trace_closest(clas, ray, 0, kF64);
        if (!f.hit) continue;
        const float det = float_determinant(ray, &pos[0], &pos[3], &pos[6]);
        if (det == 0.0f) continue;  // the double fallback decides those
        ++float_hits;
        EXPECT_EQ(f.front_face, det > 0.0f) << i << " det " << det;
        if (x.hit && x.front_face != f.front_face) ++flipped;
    }
    EXPECT_GT(float_hits, 1000);
    EXPECT_GT(flipped, 0);
}

TEST(Float32Traversal, NanAndDegenerateTrianglesNeverHit) {
    const float nan = std::nanf("");
    // Triangle 0 NaN, 1 degenerate (collinear), 2 a point, 3 a real one behind them.
    const auto clas = build({nan, 0,  0, 1, 0,  0, 0, 1, 0,  //
                             -1,  -1, 1, 1, 1,  1, 0, 0, 1,  //
                             0,   0,  2, 0, 0,  2, 0, 0, 2,  //
                             -1,  -1, 3, 1, -1, 3, 0, 1, 3},
                            {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11});
    for (const TraversalMode mode : {kF64, kF32}) {
        const Ray r{{0.0f, 0.0f, -1.0f}, 0.0f, {0.0f, 0.0f, 1.0f}, 10.0f};
        const Hit h = trace_closest(clas, r, 0, mode);
        ASSERT_TRUE(h.hit) << traversal_mode_name(mode);
        EXPECT_EQ(h.triangle_index, 3u) << traversal_mode_name(mode);
        EXPECT_FLOAT_EQ(h.t, 4.0f) << traversal_mode_name(mode);
    }
}

}  // namespace
}  // namespace clastrace::engine
