// SPDX-License-Identifier: Apache-2.0
// The four-at-once triangle filter of the NV traversal's leaves (engine/src/geometry/
// triangle4.h) against the exact triangle test it stands in front of: it may drop a triangle
// only where intersect_triangle misses it, in both traversal modes, for rays aimed exactly at
// vertices and edge points (edge functions at or near 0), small triangles seen from far away,
// huge and tiny coordinates, origins that are not floats, and axis-parallel rays; and it must
// drop most misses, or the traversal gains nothing. The float32 mode's four-at-once test
// (triangle4_float32) must give, lane by lane, what intersect_triangle_float32 gives, on the
// same rays, wherever it does not leave the lane to it.
#include "geometry/triangle.h"
#include "geometry/triangle4.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

namespace clastrace::engine::geometry {
namespace {

constexpr TraversalMode kModes[] = {TraversalMode::kDouble, TraversalMode::kFloat32};

struct Tally {
    size_t hits = 0, misses = 0, dropped = 0, wrongly_dropped = 0;
    // triangle4_float32 against the scalar float32 test: lanes it decided, lanes it left to the
    // scalar test, and lanes whose answer differs (hit or miss, t, u, v, uv_error, facing).
    size_t float32_decided = 0, float32_left = 0, float32_different = 0;
};

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// Lane by lane, triangle4_float32 on `group` against intersect_triangle_float32 within
// [r.tmin, tmax].
void check_float32_group(const Triangle4& group, const float tris[4][9], const PreparedRay& r,
                         double tmax, Tally* tally) {
    const Triangle4Ray ray = make_triangle4_ray(r);
    if (!ray.usable) return;
    Triangle4Float32 f;
    triangle4_float32(ray, group, 0xFu, &f);
    for (int k = 0; k < 4; ++k) {
        if (f.fallback >> k & 1) {
            ++tally->float32_left;
            continue;
        }
        ++tally->float32_decided;
        TriangleHit exact;
        const bool hits =
            intersect_triangle_float32(r, tris[k], tris[k] + 3, tris[k] + 6, tmax, &exact);
        const double t = f.t[k];
        const bool lane_hits = (f.hits >> k & 1) && t >= r.tmin && t <= tmax;
        bool same = hits == lane_hits;
        if (same && hits)
            same = same_bits(exact.t, t) && same_bits(exact.u, f.u[k]) &&
                   same_bits(exact.v, f.v[k]) &&
                   same_bits(exact.uv_error,
                             barycentric_float_error(f.unsheared[k], f.sheared[k], f.det[k])) &&
                   exact.front == float_det_front(f.det[k]);
        if (!same && ++tally->float32_different <= 5)
            ADD_FAILURE() << "float32 lane " << k << ": scalar " << (hits ? "hit" : "miss")
                          << " at t=" << exact.t << ", four at once "
                          << (lane_hits ? "hit" : "miss") << " at t=" << t;
    }
}

// The float at or above `t` (what the traversal hands the filter).
float float_up(double t) {
    float f = float(t);
    if (double(f) < t) f = std::nextafter(f, HUGE_VALF);
    return f;
}

// Four triangles through one group and one at a time within [-inf, tmax]: every exact hit must
// be kept.
void check_group(const float tris[4][9], const double o[3], const double d[3], TraversalMode mode,
                 Tally* tally, double tmax = HUGE_VAL) {
    Triangle4 group{};
    for (int k = 0; k < 4; ++k) {
        group.geometry[k] = group.primitive[k] = uint32_t(k);
        for (int c = 0; c < 9; ++c) group.v[c][k] = tris[k][c];
    }
    const PreparedRay r = prepare_ray(o, d, -std::numeric_limits<double>::infinity(), tmax, mode);
    const unsigned kept = triangle4_candidates(make_triangle4_ray(r), group, 0xFu, float_up(tmax));
    for (int k = 0; k < 4; ++k) {
        TriangleHit hit;
        const bool exact = intersect_triangle(r, tris[k], tris[k] + 3, tris[k] + 6, tmax, &hit);
        const bool keeps = kept >> k & 1;
        tally->hits += exact;
        tally->misses += !exact;
        tally->dropped += !keeps;
        if (exact && !keeps && ++tally->wrongly_dropped <= 5)
            ADD_FAILURE() << traversal_mode_name(mode) << ": triangle " << k
                          << " dropped, the exact test hits it at t=" << hit.t;
    }
    if (mode == TraversalMode::kFloat32) check_float32_group(group, tris, r, tmax, tally);
}

// Groups of random triangles of `size` around `center`, each ray from `distance` away aimed at
// a vertex, an edge point or a random point of one of them (or slightly off it); `jitter`:
// origins moved off float values (double mode only sees those).
Tally run(double center, double size, double distance, bool jitter, uint64_t seed,
          int groups = 3000) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    std::uniform_real_distribution<double> weight(0.0, 1.0);
    Tally tally;
    for (int n = 0; n < groups; ++n) {
        float tris[4][9];
        for (auto& t : tris)
            for (int c = 0; c < 9; ++c)
                t[c] = float(center + size * unit(rng) + (c % 3 == 0 ? 0.0 : 0.25 * size));
        // Two triangles share an edge, as in a mesh: a ray through it must hit one of them.
        for (int c = 0; c < 6; ++c) tris[1][c] = tris[0][3 + c];
        const float* aim = tris[n % 4];
        double target[3];
        const double a = weight(rng), b = weight(rng) * (1.0 - a);
        const int kind = n % 5;
        for (int c = 0; c < 3; ++c) {
            const double p0 = aim[c], p1 = aim[3 + c], p2 = aim[6 + c];
            if (kind == 0) target[c] = p0;                                  // a vertex
            if (kind == 1) target[c] = (p0 + p1) * 0.5;                     // an edge point
            if (kind == 2) target[c] = p0 + a * (p1 - p0) + b * (p2 - p0);  // inside
            if (kind == 3) target[c] = p1 + a * (p2 - p1);                  // along an edge
            if (kind == 4) target[c] = p0 + size * 1e-6 * unit(rng);        // near a vertex
        }
        double o[3], d[3];
        const bool axial = n % 7 == 0;
        for (int c = 0; c < 3; ++c) {
            double dir = axial ? (c == n % 3 ? 1.0 : 0.0) : unit(rng);
            o[c] = target[c] - distance * dir;
            if (jitter && !axial) o[c] += std::ldexp(std::fabs(o[c]) + 1.0, -40) * unit(rng);
            d[c] = target[c] - o[c];
            if (axial) d[c] = dir;
        }
        for (const TraversalMode mode : kModes) {
            double fo[3], fd[3];
            for (int c = 0; c < 3; ++c) {
                fo[c] = mode == TraversalMode::kFloat32 ? double(float(o[c])) : o[c];
                fd[c] = mode == TraversalMode::kFloat32 ? double(float(d[c])) : d[c];
            }
            check_group(tris, fo, fd, mode, &tally);
            // tmax exactly at the aimed triangle's hit (kept: the exact test's interval is
            // closed), and a random tmax around it (the hit is at t = 1 unless axial).
            const PreparedRay r = prepare_ray(fo, fd, -HUGE_VAL, HUGE_VAL, mode);
            TriangleHit hit;
            if (intersect_triangle(r, aim, aim + 3, aim + 6, HUGE_VAL, &hit))
                check_group(tris, fo, fd, mode, &tally, hit.t);
            check_group(tris, fo, fd, mode, &tally,
                        axial ? distance * weight(rng) * 2.0 : 0.5 + weight(rng));
        }
    }
    return tally;
}

void expect_sound(const Tally& t, const char* what) {
    EXPECT_EQ(t.wrongly_dropped, 0u) << what;
    EXPECT_GT(t.hits, 1000u) << what << ": the rays must reach the triangles";
    EXPECT_EQ(t.float32_different, 0u) << what << ": of " << t.float32_decided << " lanes";
}

TEST(Triangle4Filter, NeverDropsAHitAtUnitScale) {
    // Many rays: a bound a few times too tight drops about one exact hit in 10^5 tests.
    const Tally t = run(0.0, 1.0, 3.0, false, 1, 200000);
    expect_sound(t, "unit");
    // The point of the filter: nearly every miss dropped four at a time (line misses and hits
    // beyond tmax alike).
    EXPECT_GT(double(t.dropped), 0.8 * double(t.misses)) << t.dropped << " of " << t.misses;
    // The float32 test decides nearly every lane itself; rays aimed exactly at vertices and
    // edges (a fifth and more of these) give the scalar test its zero edge functions.
    EXPECT_GT(t.float32_decided, 10 * t.float32_left) << t.float32_left << " left";
    EXPECT_GT(t.float32_left, 0u);
}

TEST(Triangle4Filter, NeverDropsAHitFromOriginsThatAreNotFloats) {
    expect_sound(run(10.0, 1.0, 3.0, true, 2), "jittered origins");
    expect_sound(run(3e3, 1.0, 50.0, true, 3), "jittered origins far from zero");
}

TEST(Triangle4Filter, NeverDropsAHitOfSmallTrianglesSeenFromFarAway) {
    const Tally t = run(0.0, 1e-3, 4e4, false, 4);
    expect_sound(t, "1e-3 triangles from 4e4");
    // At 4e4 a float step is 0.004: triangles of 0.05 there, seen from non-float origins nearby.
    expect_sound(run(4e4, 0.05, 10.0, true, 5), "0.05 triangles at 4e4");
}

TEST(Triangle4Filter, NeverDropsAHitAtHugeAndTinyCoordinates) {
    expect_sound(run(1e12, 1e12, 3e12, false, 6), "1e12");
    expect_sound(run(0.0, 1e-12, 3e-12, false, 7), "1e-12");
    // Beyond the filter's range it keeps everything; the exact test still answers.
    expect_sound(run(1e18, 1e18, 3e18, false, 8), "1e18");
    expect_sound(run(0.0, 1e-18, 3e-18, false, 9), "1e-18");
}

TEST(Triangle4Filter, KeepsNanAndDegenerateTrianglesForTheExactTest) {
    float tris[4][9] = {};
    for (int c = 0; c < 9; ++c) {
        tris[0][c] = c == 4 ? NAN : float(c % 3 == 1);
        tris[1][c] = 0.5f;                                       // a point
        tris[2][c] = float(c / 3) * (c % 3 == 0 ? 1.0f : 0.0f);  // a segment on the x axis
        tris[3][c] = float(c == 3 || c == 7);
    }
    const double o[3] = {0.25, 0.25, -1.0}, d[3] = {0.0, 0.0, 1.0};
    Triangle4 group{};
    for (int k = 0; k < 4; ++k) {
        group.geometry[k] = group.primitive[k] = uint32_t(k);
        for (int c = 0; c < 9; ++c) group.v[c][k] = tris[k][c];
    }
    const PreparedRay r = prepare_ray(o, d, 0.0, 10.0);
    const unsigned kept = triangle4_candidates(make_triangle4_ray(r), group, 0xFu, 10.0f);
    EXPECT_TRUE(kept & 1) << "a NaN lane is the exact test's to judge";
    Tally tally;
    check_group(tris, o, d, TraversalMode::kDouble, &tally);
    EXPECT_EQ(tally.wrongly_dropped, 0u);
    EXPECT_EQ(tally.hits, 1u);  // triangle 3, the unit right triangle in z = 0
}

// The float32 test leaves to the scalar test every lane with an edge function exactly 0 or not
// finite (a NaN or infinite coordinate, a ray through a vertex), and answers no lane otherwise
// than the scalar test, also where the edge functions are finite but their sum, the
// determinant, overflows (coordinates near 1e19: each edge function ~1e38).
TEST(Triangle4Filter, Float32LeavesZeroAndNonFiniteEdgeFunctionsToTheScalarTest) {
    const float s = 1e19f, inf = HUGE_VALF;
    const float tris[4][9] = {
        {1.0f, 0.0f, 0.0f, NAN, 1.0f, 0.0f, -1.0f, -1.0f, 0.0f},    // a NaN coordinate
        {inf, 0.0f, 0.0f, -1.0f, 1.0f, 0.0f, -1.0f, -1.0f, 0.0f},   // an infinite one
        {0.0f, 0.0f, 0.0f, -1.0f, 1.0f, 0.0f, -1.0f, -1.0f, 0.0f},  // the ray through p0
        {s, 0.0f, 0.0f, -s, s, 0.0f, -s, -s, 0.0f},                 // |det| past FLT_MAX
    };
    Triangle4 group{};
    for (int k = 0; k < 4; ++k) {
        group.geometry[k] = group.primitive[k] = uint32_t(k);
        for (int c = 0; c < 9; ++c) group.v[c][k] = tris[k][c];
    }
    const double o[3] = {0.0, 0.0, -1.0}, d[3] = {0.0, 0.0, 1.0};
    const PreparedRay r = prepare_ray(o, d, 0.0, HUGE_VAL, TraversalMode::kFloat32);
    const Triangle4Ray ray = make_triangle4_ray(r);
    ASSERT_TRUE(ray.usable);
    Triangle4Float32 f;
    triangle4_float32(ray, group, 0xFu, &f);
    EXPECT_EQ(f.fallback & 0x7u, 0x7u) << "NaN, infinite and zero edge functions";
    EXPECT_EQ(f.hits & 0x8u, 0u) << "an overflowing determinant is no hit";
    TriangleHit hit;
    EXPECT_FALSE(intersect_triangle_float32(r, tris[3], tris[3] + 3, tris[3] + 6, HUGE_VAL, &hit));
    EXPECT_TRUE(intersect_triangle_float32(r, tris[2], tris[2] + 3, tris[2] + 6, HUGE_VAL, &hit))
        << "a ray through a vertex hits (the double fallback)";
    Tally tally;
    check_float32_group(group, tris, r, HUGE_VAL, &tally);
    EXPECT_EQ(tally.float32_different, 0u);
}

TEST(Triangle4Filter, LanesPastTheLeafAreNeverCandidates) {
    EXPECT_EQ(group_lanes(0, 1), 0x1u);
    EXPECT_EQ(group_lanes(0, 4), 0xFu);
    EXPECT_EQ(group_lanes(1, 7), 0x7u);
    EXPECT_EQ(group_lanes(1, 8), 0xFu);
    Triangle4 group{};  // all zeros: degenerate triangles at the origin, never sure misses
    const double o[3] = {0.0, 0.0, -1.0}, d[3] = {0.0, 0.0, 1.0};
    const PreparedRay r = prepare_ray(o, d, 0.0, 10.0);
    EXPECT_EQ(triangle4_candidates(make_triangle4_ray(r), group, group_lanes(0, 1), 10.0f), 0x1u);
    EXPECT_EQ(triangle4_candidates(make_triangle4_ray(r), group, group_lanes(0, 3), 10.0f), 0x7u);
}

}  // namespace
}  // namespace clastrace::engine::geometry
