// SPDX-License-Identifier: Apache-2.0
// Four triangles of one traversal leaf side by side (structure of arrays), and a float SIMD
// test that tells, for all four at once, which the exact triangle test (triangle.h) surely
// misses. It decides nothing else: every triangle it keeps goes through intersect_triangle, in
// record order, so hits, t, barycentrics, facing and ties stay exactly what the one-at-a-time
// loop gives, in both traversal modes.
//
// The test runs the watertight test's first half in float on the float ray (origin and shear
// rounded to float): translate, shear, the three edge functions. A triangle is dropped only when
// one edge function is below -err and another above +err, err bounding how far each float
// edge function may lie from the exact one of the ray the exact test uses (derivation at
// edge_error). Then the exact edge functions, and the double or float ones the exact test
// computes (which lie within a fraction of err of them), have opposite signs: the exact test
// rejects the triangle too, in kDouble directly, in kFloat32 directly or through its double
// fallback (a float edge function exactly 0 sends it there, and the double values keep the
// signs). A triangle is also dropped when its hit lies surely beyond tmax (beyond_lanes, the
// same kind of bound on t). NaN anywhere, coordinates outside [2^-30, 2^50] and rays the bounds
// do not cover keep the triangle.
#pragma once

#include "geometry/ray.h"
#include "simd4.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace clastrace::engine::geometry {

// Lane k holds one triangle: its vertices v[3 * vertex + axis][k], its geometry index and its
// primitive index, everything the traversal reads of a triangle it keeps (the record it came
// from is not touched: one cache miss less per hit). Lanes past the leaf's end (geometry
// kNoTriangle) hold zeros; group_lanes leaves them out. Three cache lines, aligned.
inline constexpr uint32_t kNoTriangle = 0xFFFFFFFFu;
struct alignas(64) Triangle4 {
    float v[9][4];
    uint32_t geometry[4];
    uint32_t primitive[4];
};
static_assert(sizeof(Triangle4) == 192);

// Lane k's vertices as the exact tests take them (p0, p1, p2 at out, out + 3, out + 6).
inline void lane_vertices(const Triangle4& t, int k, float out[9]) {
#pragma GCC unroll 9
    for (int c = 0; c < 9; ++c) out[c] = t.v[c][k];
}

// The largest magnitude of lane k's nine coordinates (as the max of lane_vertices' nine).
inline float lane_largest_magnitude(const Triangle4& t, int k) {
    float largest = 0.0f;
#pragma GCC unroll 9
    for (int c = 0; c < 9; ++c) largest = std::max(largest, std::fabs(t.v[c][k]));
    return largest;
}

// The ray in the test's terms, prepared once per traversal of one object.
struct Triangle4Ray {
    bool usable = false;  // false: every triangle is kept
    int kx = 0, ky = 1, kz = 2;
    detail::Float4 origin[3];   // the float origin, every lane
    detail::Float4 sx, sy, sz;  // the float shear
    detail::Float4 abs_sz;      // |sz| (1 + 2^-20)
    detail::Float4 delta2;      // 2 x |o - float(o)|, the largest over the axes
    detail::Float4 delta4;      // 4 x the same
};

// Triangles whose largest translated coordinate lies outside these are all kept: within them
// the bounds (edge_error) stay finite and above 2^-95, far above what a product lost to
// underflow (2^-126 at most, flush-to-zero included) could move an edge function.
inline constexpr float kTriangle4LargestCoordinate = 0x1p50f;
inline constexpr float kTriangle4SmallestCoordinate = 0x1p-30f;

inline Triangle4Ray make_triangle4_ray(const PreparedRay& r) {
    Triangle4Ray t;
    double delta = 0.0;
    for (int a = 0; a < 3; ++a) {
        if (!std::isfinite(r.o[a]) || !std::isfinite(r.d[a])) return t;
        t.origin[a] = detail::splat(r.fo[a]);
        delta = std::max(delta, std::fabs(r.o[a] - double(r.fo[a])));
    }
    // edge_error assumes a float shear within a few float rounding errors of the exact one
    // (d[kx] / d[kz], |.| <= 1 as kz is the largest component): a major component far from
    // float's normal range, or a shear that did not come out that way, keeps every triangle.
    const double dz = std::fabs(r.d[r.kz]);
    if (!(dz >= 0x1p-100 && dz <= 0x1p100)) return t;
    if (!(std::fabs(r.fsx) <= 1.0f + 0x1p-10f && std::fabs(r.fsy) <= 1.0f + 0x1p-10f)) return t;
    if (!(delta <= 0x1p60)) return t;
    t.kx = r.kx;
    t.ky = r.ky;
    t.kz = r.kz;
    t.sx = detail::splat(r.fsx);
    t.sy = detail::splat(r.fsy);
    t.sz = detail::splat(r.fsz);
    t.abs_sz = detail::splat(float(std::fabs(double(r.fsz)) * (1.0 + 0x1p-20)));
    // Rounded up so that the float products below do not round the bound down.
    t.delta2 = detail::splat(float(2.0 * delta * (1.0 + 0x1p-20)));
    t.delta4 = detail::splat(float(4.0 * delta * (1.0 + 0x1p-20)));
    t.usable = true;
    return t;
}

// The bound on |float edge function - exact edge function|, lane by lane. With u = 2^-24, m the
// largest translated coordinate (float, of the nine) and delta the origin's distance from its
// float: each translated coordinate is within E0 = 1.01 u m + delta of the exact one; each
// sheared one (|shear| <= 1 + 3u, the shear itself within 3u relative plus 2^-50) within
// 2 E0 + 6.2 u m <= E1 = 2 delta + 2^-20 m. With ms the largest sheared coordinate (float) and
// ms' = ms + E1 (at least every exact one), an edge function (two products and a difference)
// is within 4 ms' E1 + 4.01 u ms'^2. The exact test's own values lie as far again at most (the
// float ones in kFloat32, computed the same way; the double ones far closer), so the bound used
// is 32 ms' E1 + 2^-19 ms'^2: four times what the two together need. The sheared coordinates
// of a triangle near the ray are small however far it lies along it, which keeps the bound
// small beside its edge functions.
inline detail::Float4 edge_error(const Triangle4Ray& r, detail::Float4 m, detail::Float4 ms) {
    const detail::Float4 e1 = r.delta2 + m * detail::splat(0x1p-20f);
    const detail::Float4 msp = ms + e1;
    return msp * (detail::splat(32.0f) * e1 + detail::splat(0x1p-19f) * msp);
}

namespace detail4 {

using detail::abs4;
using detail::Float4;

// The lanes whose hit lies surely beyond `tmax` (>= 0; float, at or above the exact test's):
// t = T / det with T = u za + v zb + w zc (z = sz a_kz, the test's scaled distances) and
// det = u + v + w. With E the edge functions' bound (edge_error), S = |u| + |v| + |w| and
// m' = m + 4 delta: each float z is within |sz| (2^-20 m' + 2 delta) of the exact one and at
// most 2 |sz| m'; so the float T is within errT = |sz| (8 E m' + S (2^-19 m' + 2 delta)) of the
// exact T (the products' and sums' rounding included) and the float det within
// errD = 3 E + 2^-22 S. A lane is beyond when, with twice those (the exact test's own float
// values may lie as far on the other side), T / det still exceeds tmax by 2^-20 of it (the
// exact test's division and rounding of t): then its t, in either mode, is above tmax.
inline unsigned beyond_lanes(const Triangle4Ray& r, Float4 u, Float4 v, Float4 w, const Float4 z[3],
                             Float4 err, Float4 mp, float tmax) {
    const Float4 t_scaled = (u * z[0] + v * z[1]) + w * z[2];
    const Float4 det = (u + v) + w;
    const Float4 sum = (abs4(u) + abs4(v)) + abs4(w);
    const Float4 err_t2 =
        detail::splat(2.0f) * r.abs_sz *
        (detail::splat(8.0f) * err * mp + sum * (detail::splat(0x1p-19f) * mp + r.delta2));
    const Float4 err_d2 = detail::splat(6.0f) * err + detail::splat(0x1p-21f) * sum;
    const Float4 reach = detail::splat(tmax * (1.0f + 0x1p-20f));
    const Float4 zero = detail::splat(0.0f);
    // det surely > 0: t > tmax when T > tmax det; det surely < 0: when T < tmax det.
    const unsigned positive = ~detail::le_lanes(det - err_d2, zero) & 0xFu;
    const unsigned negative = ~detail::le_lanes(zero, det + err_d2) & 0xFu;
    const unsigned far_positive = detail::le_lanes(reach * (det + err_d2), t_scaled - err_t2);
    const unsigned far_negative = detail::le_lanes(t_scaled + err_t2, reach * (det - err_d2));
    return (positive & far_positive) | (negative & far_negative);
}

}  // namespace detail4

// The lanes (bit k = lane k) a group holds when it is group `g` (from 0) of a leaf of `count`
// triangles: every group is full but the last.
inline unsigned group_lanes(uint32_t g, uint32_t count) {
    const uint32_t left = count - 4 * g;
    return left >= 4 ? 0xFu : (1u << left) - 1u;
}

// The watertight test's first half on a group's four triangles in float: translated to the
// ray's float origin, sheared by its float shear (both modes' filter, and the float32 test,
// whose own arithmetic this is, operation for operation).
struct Triangle4Edges {
    detail::Float4 z[3];     // the scaled distances sz * (v[kz] - o[kz]) of the three vertices
    detail::Float4 u, v, w;  // the edge functions, in the scalar test's order
    detail::Float4 m;        // the largest translated magnitude of the nine coordinates
    detail::Float4 ms;       // the largest sheared magnitude of the six x, y
};

// The three vertices translated to the ray's float origin, sheared (x, y) and scaled (z).
// Unrolled, so that x, y and z stay in registers (the loop stored them: 12% of the filter).
[[gnu::always_inline]] inline void triangle4_shear(const Triangle4Ray& r, const Triangle4& t,
                                                   detail::Float4 x[3], detail::Float4 y[3],
                                                   detail::Float4 z[3]) {
    using detail::Float4;
#pragma GCC unroll 3
    for (int j = 0; j < 3; ++j) {
        const Float4 ax = detail::load4(t.v[3 * j + r.kx]) - r.origin[r.kx];
        const Float4 ay = detail::load4(t.v[3 * j + r.ky]) - r.origin[r.ky];
        const Float4 az = detail::load4(t.v[3 * j + r.kz]) - r.origin[r.kz];
        x[j] = ax - r.sx * az;
        y[j] = ay - r.sy * az;
        z[j] = r.sz * az;
    }
}

// The largest translated magnitude of the nine coordinates, from the same differences as
// triangle4_shear's (inlined beside it, the compiler computes them once). Apart, so that the
// float32 test computes it for its hits only. (A NaN coordinate may not reach it, as maxps
// returns its second operand; it makes the two edge functions of its vertex NaN.)
[[gnu::always_inline]] inline detail::Float4 triangle4_unsheared_magnitude(const Triangle4Ray& r,
                                                                           const Triangle4& t) {
    using detail::Float4;
    Float4 m = detail::splat(0.0f);
#pragma GCC unroll 3
    for (int j = 0; j < 3; ++j) {
        const Float4 ax = detail::load4(t.v[3 * j + r.kx]) - r.origin[r.kx];
        const Float4 ay = detail::load4(t.v[3 * j + r.ky]) - r.origin[r.ky];
        const Float4 az = detail::load4(t.v[3 * j + r.kz]) - r.origin[r.kz];
        m = detail::max4(m, detail::max4(detail::abs4(ax), detail::abs4(ay)));
        m = detail::max4(m, detail::abs4(az));
    }
    return m;
}

// The largest sheared magnitude of the six x, y.
[[gnu::always_inline]] inline detail::Float4 triangle4_sheared_magnitude(
    const detail::Float4 x[3], const detail::Float4 y[3]) {
    detail::Float4 ms = detail::splat(0.0f);
#pragma GCC unroll 3
    for (int j = 0; j < 3; ++j)
        ms = detail::max4(ms, detail::max4(detail::abs4(x[j]), detail::abs4(y[j])));
    return ms;
}

// The edge functions in the scalar test's order: u = cx by - cy bx, v = ax cy - ay cx,
// w = bx ay - by ax.
[[gnu::always_inline]] inline void triangle4_edge_functions(const detail::Float4 x[3],
                                                            const detail::Float4 y[3],
                                                            detail::Float4* u, detail::Float4* v,
                                                            detail::Float4* w) {
    *u = x[2] * y[1] - y[2] * x[1];
    *v = x[0] * y[2] - y[0] * x[2];
    *w = x[1] * y[0] - y[1] * x[0];
}

// Always inlined, so that inside the AVX2 walk it compiles for AVX2 (no fused multiply-adds:
// the engine builds with -ffp-contract=off, so the same bits as the SSE form).
[[gnu::always_inline]] inline Triangle4Edges triangle4_edges(const Triangle4Ray& r,
                                                             const Triangle4& t) {
    using detail::Float4;
    Triangle4Edges e;
    Float4 x[3], y[3];
    triangle4_shear(r, t, x, y, e.z);
    e.m = triangle4_unsheared_magnitude(r, t);
    triangle4_edge_functions(x, y, &e.u, &e.v, &e.w);
    e.ms = triangle4_sheared_magnitude(x, y);
    return e;
}

// Lane mask (bit k = lane k) of the triangles among `used` (group_lanes) the exact test may hit
// within [tmin, tmax] (`tmax` a float at or above the exact test's). Always inlined, so that
// inside the AVX2 walk (nv_trace.cpp's leaf, inlined there) it compiles for AVX2.
[[gnu::always_inline]] inline unsigned triangle4_candidates(const Triangle4Ray& r,
                                                            const Triangle4& t, unsigned used,
                                                            float tmax) {
    using detail::Float4;
    if (!r.usable) return used;
    // (A NaN edge function compares false, so such a triangle is never dropped.)
    const Triangle4Edges e = triangle4_edges(r, t);
    const detail::Mask4 in_range =
        detail::le_mask(e.m, detail::splat(kTriangle4LargestCoordinate)) &
        detail::le_mask(detail::splat(kTriangle4SmallestCoordinate), e.m);
    const Float4 err = edge_error(r, e.m, e.ms);
    const Float4 neg_err = detail::splat(0.0f) - err;
    // One edge function at or below -err and one at or above err, through the least and the
    // greatest of the three (a NaN among them may hide a lane's other two: it keeps the lane,
    // which only costs the exact test). The conditions combined in the lanes: two masks out.
    const unsigned decided = detail::lanes(in_range);
    unsigned missed = detail::lanes(
        in_range & detail::le_mask(detail::min4(detail::min4(e.u, e.v), e.w), neg_err) &
        detail::le_mask(err, detail::max4(detail::max4(e.u, e.v), e.w)));
    // A non-negative finite tmax (NaN and infinity fail this) also drops sure hits beyond it,
    // where a lane is left to decide.
    if ((used & decided & ~missed) != 0 && tmax >= 0.0f && tmax <= 0x1p100f)
        missed |= decided & detail4::beyond_lanes(r, e.u, e.v, e.w, e.z, err, e.m + r.delta4, tmax);
    return used & ~missed;
}

// TraversalMode::kFloat32's triangle test (triangle.h, intersect_triangle_float32) on four
// triangles at once, with the same float operations in the same order, so lane by lane the
// same edge functions, determinant, t and barycentrics: the float32 mode's leaves need no
// filter and no second test. Lanes where an edge function is exactly 0 or not finite (the
// scalar test's fallback to the double test, which keeps shared edges closed) are left to the
// scalar test (`fallback`). For a kFloat32 ray (origin and shear the float ones), usable.
struct Triangle4Float32 {
    unsigned hits = 0;      // lanes hit at t (t not yet held against [tmin, tmax])
    unsigned fallback = 0;  // lanes the scalar test decides
    // Per lane: t, the barycentrics of p1 and p2, the determinant, and the largest translated
    // and sheared magnitudes (what barycentric_float_error takes).
    alignas(16) float t[4], u[4], v[4], det[4], unsheared[4], sheared[4];
};

[[gnu::always_inline]] inline void triangle4_float32(const Triangle4Ray& r, const Triangle4& t,
                                                     unsigned used, Triangle4Float32* out) {
    using detail::Float4;
    Float4 x[3], y[3], z[3], u, v, w;
    triangle4_shear(r, t, x, y, z);
    triangle4_edge_functions(x, y, &u, &v, &w);
    const Float4 zero = detail::splat(0.0f);
    // The conditions combined in the lanes and moved out as two masks (one a condition: 13).
    // The scalar test's double fallback takes the lanes with an edge function exactly 0 or not
    // finite: |u| + |v| + |w| is finite only where all three are (NaN and infinity carry through
    // the sum), and the least of |u|, |v|, |w| is 0 only where one is. (A finite sum past FLT_MAX
    // sends its lane there too, where the scalar test misses it as the lanes would: its edge
    // functions are of mixed signs or their sum, the determinant, overflows.)
    const Float4 abs_u = detail::abs4(u), abs_v = detail::abs4(v), abs_w = detail::abs4(w);
    const detail::Mask4 plain =
        detail::le_mask((abs_u + abs_v) + abs_w, detail::splat(std::numeric_limits<float>::max())) &
        detail::lt_mask(zero, detail::min4(detail::min4(abs_u, abs_v), abs_w));
    // A hit: all three of one sign and a finite determinant. A finite determinant has no NaN or
    // infinity among its terms, and all three strictly of one sign are none 0 and sum to no 0:
    // such lanes are plain, with a determinant neither 0 nor infinite (no test of those apart).
    const detail::Mask4 one_sign = detail::lt_mask(zero, detail::min4(detail::min4(u, v), w)) |
                                   detail::lt_mask(detail::max4(detail::max4(u, v), w), zero);
    const Float4 det = (u + v) + w;
    out->fallback = used & ~detail::lanes(plain);
    out->hits = used & detail::lanes(one_sign & detail::finite_mask(det));
    if (out->hits == 0) return;
    // Only hits need t, the barycentrics and the magnitudes (the error of the barycentrics):
    // most groups a ray enters have none (2.85 groups, 0.88 hits a ray).
    const Float4 t_scaled = (u * z[0] + v * z[1]) + w * z[2];
    const Float4 rcp_det = detail::splat(1.0f) / det;
    detail::store4(out->t, t_scaled * rcp_det);
    detail::store4(out->u, v * rcp_det);
    detail::store4(out->v, w * rcp_det);
    detail::store4(out->det, det);
    detail::store4(out->unsheared, triangle4_unsheared_magnitude(r, t));
    detail::store4(out->sheared, triangle4_sheared_magnitude(x, y));
}

}  // namespace clastrace::engine::geometry
